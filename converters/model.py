"""Typed model of a scene in the course's text format.

The parser (:mod:`converters.course_scene`) produces a :class:`Scene`; the
scene description (:mod:`converters.description`) consumes it. Groups and
transforms are flattened by the parser: every object carries its own
object-to-world matrix and material, and its index in ``Scene.objects`` is its
object id (the ``id`` AOV).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class Camera:
    center: Vec3
    direction: Vec3
    up: Vec3
    angle: float  # full field of view in degrees, the same on both image axes


@dataclass(frozen=True)
class DirectionalLight:
    direction: Vec3  # direction the light travels in
    color: Vec3


@dataclass(frozen=True)
class PointLight:
    position: Vec3
    color: Vec3
    falloff: float  # intensity at distance d is color / (falloff * d^2)


@dataclass(frozen=True)
class Background:
    color: Vec3 = (0.0, 0.0, 0.0)
    ambient: Vec3 = (0.0, 0.0, 0.0)
    cube_map: Path | None = None  # folder with {left,right,up,down,front,back}.png


@dataclass(frozen=True)
class Material:
    diffuse: Vec3 = (1.0, 1.0, 1.0)
    specular: Vec3 = (0.0, 0.0, 0.0)
    shininess: float = 0.0

    @property
    def reflective(self) -> bool:
        return max(self.specular) > 0.0


@dataclass(frozen=True, eq=False)
class SceneObject:
    material: int
    to_world: np.ndarray  # 4x4 float64, column-vector convention


@dataclass(frozen=True, eq=False)
class Sphere(SceneObject):
    center: Vec3 = (0.0, 0.0, 0.0)
    radius: float = 1.0


@dataclass(frozen=True, eq=False)
class Plane(SceneObject):
    normal: Vec3 = (0.0, 1.0, 0.0)
    offset: float = 0.0  # the plane is {x : dot(normalize(normal), x) = offset}


@dataclass(frozen=True, eq=False)
class Triangle(SceneObject):
    vertices: tuple[Vec3, Vec3, Vec3] = ((0, 0, 0), (1, 0, 0), (0, 1, 0))


@dataclass(frozen=True, eq=False)
class TriangleMesh(SceneObject):
    path: Path = Path()
    positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (V, 3) float64
    faces: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.uint32))  # (F, 3)


@dataclass(frozen=True, eq=False)
class Scene:
    path: Path
    camera: Camera
    lights: list[DirectionalLight | PointLight]
    background: Background
    materials: list[Material]
    objects: list[SceneObject]

    @property
    def has_reflective_objects(self) -> bool:
        used = {o.material for o in self.objects}
        return any(self.materials[m].reflective for m in used)
