"""A sequence's motion: the course scene at a time ``t`` in [0, 1] of its spec.

Every change is linear in time from the first frame (``t = 0``) to the last
(``t = 1``), a light's between the frames its ``frames`` names; objects turn
about the centre of their bounding box.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from converters import transforms
from converters.model import DirectionalLight, PointLight, Scene, Sphere, Triangle, TriangleMesh
from core.errors import SpecError

from .spec import Spec


def _centre(obj) -> np.ndarray:
    m = obj.to_world
    if isinstance(obj, Sphere):
        local = np.asarray([obj.center], np.float64)
    elif isinstance(obj, Triangle):
        local = np.asarray(obj.vertices, np.float64)
    elif isinstance(obj, TriangleMesh):
        local = obj.positions
    else:
        return np.zeros(3)
    points = local @ m[:3, :3].T + m[:3, 3]
    return (points.min(0) + points.max(0)) / 2


def animate(scene: Scene, spec: Spec, t: float) -> Scene:
    """The scene at time ``t`` in [0, 1]."""
    camera = scene.camera
    center = np.asarray(camera.center, np.float64)
    direction = np.asarray(camera.direction, np.float64)
    motion = spec.camera
    if "orbit" in motion:
        pivot = np.asarray(motion["orbit"].get("center", [0, 0, 0]), np.float64)
        turn = transforms.rotate_y(motion["orbit"]["degrees"] * t)[:3, :3]
        center = pivot + turn @ (center - pivot)
        direction = turn @ direction
    if "dolly" in motion:
        center = center + motion["dolly"] * t * direction / np.linalg.norm(direction)
    if "pan" in motion:
        center = center + np.asarray(motion["pan"], np.float64) * t
    camera = dataclasses.replace(camera, center=tuple(center), direction=tuple(direction))
    objects = list(scene.objects)
    for key, move in spec.objects.items():
        k = int(key)
        if not 0 <= k < len(objects):
            raise SpecError(f"spec: object {k} does not exist (the scene has {len(objects)})")
        obj = objects[k]
        c = _centre(obj)
        m = transforms.translate(np.asarray(move.get("translate", [0, 0, 0]), np.float64) * t)
        if "rotate" in move:
            r = move["rotate"]
            m = m @ transforms.translate(c) @ transforms.rotate(r["axis"], r["degrees"] * t) @ transforms.translate(-c)
        objects[k] = dataclasses.replace(obj, to_world=m @ obj.to_world)
    lights = list(scene.lights)
    for key, change in spec.lights.items():
        k = int(key)
        if not 0 <= k < len(lights):
            raise SpecError(f"spec: light {k} does not exist (the scene has {len(lights)})")
        lights[k] = animate_light(lights[k], change, light_progress(change, t, spec.frames))
    return dataclasses.replace(scene, camera=camera, objects=objects, lights=lights)


def light_progress(change: dict, t: float, frames: int) -> float:
    """How far a light's change has run at time ``t``: 0 before its first
    frame, 1 from its last on, linear between (the whole sequence without ``frames``)."""
    if "frames" not in change:
        return t
    first, last = change["frames"]
    frame = t * max(frames - 1, 1)
    return min(max((frame - first) / (last - first), 0.0), 1.0)


def animate_light(light: PointLight | DirectionalLight, change: dict, progress: float):
    """``light`` with ``progress`` (0..1) of its change: a point light moved by
    ``translate``, a directional light turned by ``rotate``, the colour scaled
    from 1 to ``scale``."""
    replace = {}
    if "translate" in change:
        replace["position"] = tuple(np.asarray(light.position, np.float64)
                                    + np.asarray(change["translate"], np.float64) * progress)
    if "rotate" in change:
        turn = transforms.rotate(change["rotate"]["axis"], change["rotate"]["degrees"] * progress)[:3, :3]
        replace["direction"] = tuple(turn @ np.asarray(light.direction, np.float64))
    if "scale" in change:
        factor = 1.0 + (float(change["scale"]) - 1.0) * progress
        replace["color"] = tuple(np.asarray(light.color, np.float64) * factor)
    return dataclasses.replace(light, **replace)
