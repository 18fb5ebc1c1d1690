"""The stress cases' common ground: the base scene they vary, and the case type.

A :class:`Case` is a scene text with what must happen to it (see
:mod:`validation.stress_cases`); the case modules (``stress_cases*``) build
them from :func:`scene`, and import nothing of each other.
"""
from __future__ import annotations

from dataclasses import dataclass, field

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
