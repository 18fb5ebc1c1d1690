"""Stress suite: how a named case is checked, and the fuzzers.

:func:`run_case` checks one case of :mod:`validation.stress_cases` (its stated
behaviour: a finite image equal to its equivalent, or one located error);
:func:`fuzz` fuzzes the parser and converter with hypothesis (mutated scenes,
token soup, raw bytes as scene and as OBJ files: only :class:`SceneError`,
with ``file:line:col``, may come out) and :func:`fuzz_cli` the command line.
``python -m benchmarks.stress`` runs them all and reports.
"""
from __future__ import annotations

import dataclasses
import os
import re
import tempfile
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
from imaging.image_io import CUBE_FACES
from imaging.metrics import TOLERANCE, bad_fraction
from renderer.job import split_layers
from validation.reference_tracer import ReferenceTracer
from validation.stress_cases_inputs import contract_problems, run_render_cli
from validation.stress_scene import DEFAULTS, Case, scene as base_scene

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


def run_case(case: Case) -> tuple[bool, str]:
    """(passed, what happened) for one case."""
    if hasattr(case, "check"):  # a command-line case (validation.stress_cases_inputs.CliCase)
        return case.check()

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


# -- fuzzing ---------------------------------------------------------------------
VOCABULARY = ["{", "}", "PerspectiveCamera", "Lights", "Background", "Materials", "Group", "Transform",
              "Sphere", "Plane", "Triangle", "TriangleMesh", "Material", "PhongMaterial", "PointLight",
              "DirectionalLight", "MaterialIndex", "numObjects", "numLights", "numMaterials", "center", "radius",
              "normal", "offset", "vertex0", "vertex1", "vertex2", "obj_file", "cubeMap", "color", "ambientLight",
              "diffuseColor", "specularColor", "shininess", "direction", "up", "angle", "position", "falloff",
              "Scale", "UniformScale", "Translate", "XRotate", "YRotate", "ZRotate", "Rotate", "Matrix4f",
              "0", "1", "-1", "2", "0.5", "1e-30", "1e30", "1e400", "nan", "inf", "-inf", "-0", "3",
              "mesh.obj", "sky", "#", "\n", "\x00", "é", "1e", "--1", ".", "0x10"]


def fuzz(examples: int, seed: int = 0) -> int:
    """Runs the three fuzzers; returns how many inputs were tried. Raises on the first escape."""
    from hypothesis import HealthCheck, given, settings, strategies as st  # noqa: PLC0415  hypothesis loads on use: --help and the paths without it stay quick

    count = 0
    folder = Path(tempfile.mkdtemp(prefix="stress-fuzz-"))
    (folder / "mesh.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    for face in CUBE_FACES:
        (folder / "sky").mkdir(exist_ok=True)
        (folder / "sky" / f"{face}.png").write_bytes(b"not a png")
    valid = base_scene(num_objects=4,
                       objects=DEFAULTS["objects"] + " MaterialIndex 0 TriangleMesh { obj_file mesh.obj }")
    valid_tokens = re.findall(r"[{}]|[^\s{}]+", valid)

    def check(text: str) -> None:
        nonlocal count
        count += 1
        try:
            scene_dict(parse_scene(text, folder / "fuzz.txt"))
        except SceneError as error:
            assert LOCATED.match(str(error)), str(error)

    common = settings(max_examples=examples, deadline=None, database=None, derandomize=True,
                      suppress_health_check=list(HealthCheck))

    @common
    @given(st.lists(st.tuples(st.integers(0, len(valid_tokens)), st.sampled_from(["replace", "delete", "insert"]),
                              st.sampled_from(VOCABULARY)), min_size=1, max_size=6))
    def mutated(edits):
        tokens = list(valid_tokens)
        for position, action, token in edits:
            position = min(position, len(tokens) - 1)
            if action == "replace":
                tokens[position] = token
            elif action == "delete" and len(tokens) > 1:
                del tokens[position]
            else:
                tokens.insert(position, token)
        check(" ".join(tokens))

    @common
    @given(st.lists(st.sampled_from(VOCABULARY), max_size=80))
    def soup(tokens):
        check(" ".join(tokens))

    @common
    @given(st.binary(max_size=600), st.booleans())
    def raw(data, as_obj):
        nonlocal count
        count += 1
        target = folder / ("mesh.obj" if as_obj else "fuzz.txt")
        target.write_bytes(data)
        try:
            scene_dict(load_scene(folder / "fuzz.txt") if not as_obj else parse_scene(valid, folder / "fuzz.txt"))
        except SceneError as error:
            assert LOCATED.match(str(error)), str(error)
        finally:
            (folder / "mesh.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")

    mutated()
    soup()
    raw()
    return count


#: Words the command-line fuzzer draws from: every flag, numbers that are fine, odd or absurd,
#: and paths that are fine, missing, duplicated, of unknown format, read-only or through links
CLI_VOCABULARY = ["-input", "-size", "-output", "-normals", "-depth", "-bounces", "-shadows", "-jitter", "-filter",
                  "--exr", "--png", "--spp", "--out", "--stats", "--data", "--variant", "--batch",
                  "0", "1", "2", "3", "7", "-1", "1e3", "nan", "x", "", "1000000000", "4294967296", "300000",
                  "s.txt", "bad.txt", "missing.txt", "missing/s.txt", "showcase", "a.png", "a.png", "b.exr",
                  "c.jpg", "dir", "dir/x.png", "new/y.bmp", "ro.png", "link.png", "notes.txt/x.png", "b.sh",
                  "nope_rgb", "scalar_spectral", "é.png", "-", "--", "-size=4", "empty.sh", "linkdir/x.png",
                  "dangling.png", "-bounces", "1000"]
SHELL_VOCABULARY = ["-h", "--help", "a2", "${BIN}", "python3", "render.py", "clear", "echo", "mkdir", "-p", "cd", "#",
                    "\\", "'", '"', ";", "&&", "|"]


def fuzz_cli(examples: int, seed: int = 0) -> int:
    """Random ``render.py`` argument lists and ``--batch`` files, run in-process
    in a scratch folder: each must end in exit 0, or exit 2 with one
    ``render.py: error:`` line (per bad batch line), never a traceback or another
    exception. Returns how many inputs were tried; raises on the first escape."""
    from hypothesis import HealthCheck, given, settings, strategies as st  # noqa: PLC0415  hypothesis loads on use: --help and the paths without it stay quick


    folder = Path(tempfile.mkdtemp(prefix="stress-cli-"))
    (folder / "s.txt").write_text(base_scene())
    (folder / "bad.txt").write_text("PerspectiveCamera { center 0 0 1 }")
    (folder / "dir").mkdir()
    (folder / "notes.txt").write_text("x")
    (folder / "ro.png").write_text("old")
    (folder / "ro.png").chmod(0o444)
    os.symlink("a.png", folder / "link.png")
    (folder / "b.sh").write_text("a2 -input s.txt -size 4 3 -output batch.png\nclear\n")
    (folder / "empty.sh").write_text("# nothing to render\n")
    (folder / "real" / "deep").mkdir(parents=True)
    os.symlink("real/deep", folder / "linkdir")
    os.symlink("gone/d.png", folder / "dangling.png")
    count = 0

    def check(argv: list[str], batch: bool) -> None:
        nonlocal count
        count += 1
        try:
            code, text = run_render_cli(folder, argv)
        except SystemExit as stop:  # argparse's own exits (none expected: its errors are UsageErrors)
            code, text = stop.code, ""
        problems = contract_problems(code, text, batch or "--batch" in argv)
        assert not problems, f"{argv}: {problems}: {text[-500:]}"

    common = settings(max_examples=examples, deadline=None, database=None, derandomize=True,
                      suppress_health_check=list(HealthCheck))

    @common
    @given(st.lists(st.sampled_from(CLI_VOCABULARY), max_size=10))
    def arguments(words):
        # a small default size first, so that what renders renders fast; later words may override it
        check(["-size", "6", "4", "--quiet", *words], batch=False)

    @common
    @given(st.lists(st.lists(st.sampled_from(CLI_VOCABULARY + SHELL_VOCABULARY), max_size=8), min_size=1, max_size=4))
    def batches(lines):
        text = "\n".join(" ".join(["-size", "5", "3", *words] if words and words[0] == "-input" else words)
                         for words in lines)
        (folder / "fuzz.sh").write_text(text + "\n")
        check(["--batch", "fuzz.sh", "--quiet"], batch=True)

    arguments()
    batches()
    return count
