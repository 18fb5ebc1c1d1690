"""The renderer's stress cases: the base scene they vary, the case type and its check.

A :class:`Case` is a scene text with what must happen to it (the tables in
:mod:`validation.stress.cases_renderer` and the other ``cases_*`` modules,
built from :func:`scene`); :meth:`Case.check` renders it
(:func:`check_scene`): a finite image equal to its equivalent (or to the
NumPy reference tracer, or to itself scaled and moved), or one located error.
"""
from __future__ import annotations

import dataclasses
import re
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import mitsuba as mi
import numpy as np

from converters import transforms
from converters.course_scene import load_scene, parse_scene
from converters.description import RenderOptions, scene_dict
from converters.model import PointLight
from converters.to_mitsuba import load_scene_dict
from core.errors import SceneError
from imaging.colour import to_course_8bit
from imaging.metrics import TOLERANCE, bad_fraction
from renderer.job import split_layers
from validation.reference_tracer import ReferenceTracer

#: A small well-conditioned scene; {materials}, {lights}, {objects} and the
#: other fields are filled in per case.
BASE = """PerspectiveCamera {{ center {center} direction {direction} up {up} angle {angle} }}
Lights {{ numLights {num_lights} {lights} }}
Background {{ color 0.1 0.2 0.3 ambientLight 0.1 0.1 0.1 {background} }}
Materials {{ numMaterials {num_materials} {materials} }}
Group {{ numObjects {num_objects} {objects} }}
"""
DEFAULTS = dict(
    center="0 1 6", direction="0 -0.1 -1", up="0 1 0", angle="40", background="",
    num_lights=2, lights="DirectionalLight { direction -0.3 -1 -0.5 color 0.7 0.7 0.7 } "
                         "PointLight { position 1 3 2 color 1 1 1 falloff 0.2 }",
    num_materials=2, materials="Material { diffuseColor 0.8 0.3 0.2 specularColor 0.5 0.5 0.5 shininess 20 } "
                               "Material { diffuseColor 0.6 0.6 0.6 }",
    num_objects=3, objects="MaterialIndex 1 Plane { normal 0 1 0 offset 0 } "
                           "MaterialIndex 0 Sphere { center -0.8 0.8 0 radius 0.8 } "
                           "Transform { Translate 1 0.6 -0.5 Scale 0.6 0.6 0.6 Sphere { center 0 0 0 radius 1 } }",
)


def scene(**changes) -> str:
    return BASE.format(**{**DEFAULTS, **changes})


def material(shininess="20", diffuse="0.8 0.3 0.2", specular="0.5 0.5 0.5") -> str:
    return (f"Material {{ diffuseColor {diffuse} specularColor {specular} shininess {shininess} }} "
            "Material { diffuseColor 0.6 0.6 0.6 }")


@dataclass(frozen=True)
class Case:
    name: str
    text: str
    kind: str  # "render" or "error"
    expect: str = ""  # error: a piece of the message
    match: str | None = None  # render: a well-conditioned equivalent scene text
    reference: bool = False  # render: compare with the NumPy reference tracer
    flags: dict = field(default_factory=lambda: dict(bounces=2, shadows=True))
    scale: float | None = None  # render: the scene scaled by this factor about the origin ...
    offset: float = 0.0  # ... and moved this far along (1, 1, 1)/sqrt(3)
    # render: at most this fraction of pixels may differ by more than 2/255, and none by more than
    # max_difference/255 (a self-shadowing speckle or a light leak differs by far more)
    tolerance: float = 0.005
    max_difference: int = 255
    files: dict = field(default_factory=dict)  # extra files beside the scene: name -> bytes
    fast: bool = True  # part of the CI subset

    def check(self) -> tuple[bool, str]:
        return check_scene(self)


#: "file:line:col: message", one line
LOCATED = re.compile(r"^[^\n]+:\d+:\d+: [^\n]+$")
SIZE = (48, 36)


def _write(folder: Path, case: Case) -> Path:
    path = folder / "scene.txt"
    try:  # latin-1 writes the raw-byte cases (binary garbage) byte for byte ...
        data = case.text.encode("latin-1")
    except UnicodeEncodeError:  # ... and text beyond it is a UTF-8 file, as an editor saves it
        data = case.text.encode("utf-8")
    path.write_bytes(data)
    for name, data in case.files.items():
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_bytes(data)
    return path


def scaled(scene, scale: float, offset: float):
    """The same scene scaled about the origin by ``scale``, then moved by
    ``offset`` along (1, 1, 1)/sqrt(3); point lights keep their effect."""
    move = transforms.translate(np.full(3, offset / np.sqrt(3.0))) @ transforms.uniform_scale(scale)

    def point(p):
        return tuple((move @ np.append(np.asarray(p, np.float64), 1.0))[:3])

    camera = dataclasses.replace(scene.camera, center=point(scene.camera.center))
    lights = [dataclasses.replace(light, position=point(light.position), falloff=light.falloff / scale ** 2)
              if isinstance(light, PointLight) else light for light in scene.lights]
    objects = [dataclasses.replace(o, to_world=move @ o.to_world) for o in scene.objects]
    return dataclasses.replace(scene, camera=camera, lights=lights, objects=objects)


def _layers(scene, flags: dict) -> dict:
    width, height = flags.get("size", SIZE)
    options = RenderOptions(width=width, height=height, bounces=flags["bounces"], shadows=flags["shadows"],
                            aovs=("depth", "normal", "position", "albedo", "id"))
    image = np.array(mi.render(load_scene_dict(scene_dict(scene, options))), np.float32)
    return split_layers(image, options.aovs)


def _compare(a: np.ndarray, b: np.ndarray, case: Case, what: str) -> tuple[bool, str]:
    """The course's tolerance (or the case's): fraction of pixels over 2/255, and the largest difference."""
    a, b = to_course_8bit(a), to_course_8bit(b)
    bad, worst = bad_fraction(a, b, TOLERANCE), int(np.abs(a.astype(int) - b.astype(int)).max())
    passed = bad <= case.tolerance and worst <= case.max_difference
    return passed, f"{100 * bad:.3f}% of pixels differ from {what} (largest difference {worst}/255)"


def check_scene(case: Case) -> tuple[bool, str]:
    """(passed, what happened) for one scene case: its stated behaviour, a
    finite image equal to its equivalent, or one located error."""
    with tempfile.TemporaryDirectory() as tmp:
        path = _write(Path(tmp), case)
        try:
            scene = load_scene(path)
            scene_dict(scene)
        except SceneError as error:
            message = str(error)
            if case.kind != "error":
                return False, f"unexpected error: {message}"
            ok = bool(LOCATED.match(message)) and case.expect in message
            return ok, message
        except Exception as error:  # anything else is a failure whatever the case expects
            return False, f"{type(error).__name__}: {error}"
        if case.kind == "error":
            return False, "no error"

        layers = _layers(scene, case.flags)
        finite = all(np.all(np.isfinite(v)) for v in layers.values())
        if not finite:
            return False, "non-finite output"
        if case.scale is not None:
            moved = _layers(scaled(scene, case.scale, case.offset), case.flags)
            return _compare(moved[""], layers[""], case, "the unscaled render")
        if case.match is not None:
            other = _layers(parse_scene(case.match, path), case.flags)
            return _compare(layers[""], other[""], case, "the equivalent")
        if case.reference:
            width, height = case.flags.get("size", SIZE)
            beauty, _, _ = ReferenceTracer(scene).render(width, height, case.flags["bounces"], case.flags["shadows"])
            return _compare(layers[""], beauty, case, "the NumPy reference")
        return True, "finite"
