"""Stress cases for scale: far lights, far objects, mixed scales, many lights.

The image of a scene must not change when a light is moved far away with its
brightness kept (a sun-like point light equals a directional light), when an
object is added far out of view, or when a small scene shares the world with
a large far object; and many lights must give the reference tracer's image.
Secondary-ray offsets that grew with the scene's radius (lights and far
objects included) failed every one of these: shadows vanished.
"""
from __future__ import annotations

import numpy as np

from validation.stress.scene import DEFAULTS, Case, scene

NEAR_LIGHT = "PointLight { position 1 3 2 color 1 1 1 falloff 0.2 }"
DIRECTIONAL_SUN = "DirectionalLight { direction -1 -3 -2 color 0.7 0.7 0.7 }"
#: Looking down: no horizon in view, where the floor is as far away as a near "sun"
DOWN = "0 -0.5 -1"


def sun(distance: float, direction=(1.0, 3.0, 2.0)) -> str:
    """A point light ``distance`` away, as bright at the origin as a directional light of 0.7."""
    position = np.asarray(direction, np.float64) / np.linalg.norm(direction) * distance
    falloff = 1.0 / (0.7 * float(position @ position))
    return "PointLight {{ position {:.9g} {:.9g} {:.9g} color 1 1 1 falloff {:.9g} }}".format(*position, falloff)


#: The default objects with the small sphere squashed to an ellipsoid
ELLIPSOID_OBJECTS = DEFAULTS["objects"].replace("Scale 0.6 0.6 0.6", "Scale 0.6 0.35 0.8")
assert ELLIPSOID_OBJECTS != DEFAULTS["objects"]


def inside(transform: str) -> str:
    """A large sphere around the camera (which sees its inside) under ``transform``."""
    return f"MaterialIndex 0 Transform {{ {transform} Sphere {{ center 0 0 0 radius 1 }} }}"


def with_objects(extra: str, count: int = 1) -> str:
    return scene(num_objects=3 + count, objects=DEFAULTS["objects"] + " " + extra)


def many_lights(count: int) -> str:
    rng = np.random.default_rng(count)
    lights = " ".join(
        f"PointLight {{ position {x:.3f} {3 + y:.3f} {z:.3f} color 0.3 0.3 0.3 falloff {0.5 * count:g} }}" if k % 2
        else f"DirectionalLight {{ direction {x:.3f} -1 {z:.3f} color {0.5 / count:g} {0.5 / count:g} 0.01 }}"
        for k, (x, y, z) in enumerate(rng.uniform(-2, 2, (count, 3))))
    return scene(num_lights=count, lights=lights)


def scale_cases() -> list[Case]:
    directional = scene(direction=DOWN, lights=f"{DIRECTIONAL_SUN} {NEAR_LIGHT}")
    return [
        Case("point light 3742 away = directional light", scene(direction=DOWN, lights=f"{sun(3742)} {NEAR_LIGHT}"),
             "render", match=directional),
        Case("point light 1e7 away = directional light", scene(direction=DOWN, lights=f"{sun(1e7)} {NEAR_LIGHT}"),
             "render", match=directional),
        Case("point light 1e4 away behind the camera",
             scene(direction=DOWN, lights=f"{sun(1e4, (0.2, 1.0, 3.0))} {NEAR_LIGHT}"), "render",
             match=scene(direction=DOWN, lights=f"DirectionalLight {{ direction -0.2 -1 -3 color 0.7 0.7 0.7 }} "
                                                f"{NEAR_LIGHT}")),
        Case("small sphere 1e4 away", with_objects("MaterialIndex 0 Sphere { center 10000 0 0 radius 0.1 }"),
             "render", match=scene()),
        Case("triangle 1e6 away", with_objects("Triangle { vertex0 1e6 0 0 vertex1 1e6 1 0 vertex2 1e6 0 1 }"),
             "render", match=scene()),
        Case("large sphere 1e4 under the floor",
             with_objects("MaterialIndex 1 Sphere { center 0 -10000 0 radius 100 }"), "render", match=scene()),
        Case("scene with a far object, scaled by 1e-3",
             with_objects("MaterialIndex 1 Sphere { center 0 -10000 0 radius 100 }"), "render", scale=1e-3),
        Case("scene with a far light, scaled by 1e3", scene(lights=f"{sun(1e5)} {NEAR_LIGHT}"), "render",
             scale=1e3),
        Case("20 lights (a symbolic loop)", many_lights(20), "render", reference=True),
        # float32 rendering: uniformly scaled scenes render the same within the
        # parser's limits (converters.course_scene.MAX_COORDINATE, MIN_SCENE_SIZE), and
        # beyond them are refused (a sphere at 1e18 removed a shadow; a scene scaled to
        # 1e18 or 1e-30 rendered empty, with exit 0)
        Case("scene scaled by 1e-10", scene(), "render", scale=1e-10),
        Case("scene scaled by 1e11", scene(), "render", scale=1e11),
        Case("sphere 1e18 away is refused", with_objects("MaterialIndex 0 Sphere { center 1e18 0 0 radius 1 }"),
             "error", expect="magnitude at most 1e+12"),
        Case("camera 1e13 away is refused", scene(center="0 1 1e13"), "error", expect="camera center"),
        Case("point light 1e13 away is refused",
             scene(lights="PointLight { position 1 3 1e13 color 1 1 1 falloff 1e-26 }"), "error",
             expect="light position"),
        Case("scene 1e-11 across is refused",
             scene(center="0 1e-12 6e-12", num_objects=1,
                   objects="MaterialIndex 0 Sphere { center 0 0 0 radius 1e-12 }"),
             "error", expect="at least 1e-10 across"),
        Case("camera in an infinite plane (no size to refuse)",
             scene(center="0 0 0", direction="1 -0.2 0", num_objects=1,
                   objects="MaterialIndex 0 Plane { normal 0 1 0 offset 0 }"), "render"),
        # Non-uniformly scaled spheres were Mitsuba ellipsoids, which miss rays
        # at small sizes (speckles at 1e-4, nothing at 1e-5) and from inside
        Case("scene with an ellipsoid, scaled by 1e-2", scene(objects=ELLIPSOID_OBJECTS), "render", scale=1e-2),
        Case("scene with an ellipsoid, scaled by 1e-5", scene(objects=ELLIPSOID_OBJECTS), "render", scale=1e-5),
        Case("camera inside an ellipsoid = inside a sphere",
             scene(center="0 0.5 0", num_objects=1, objects=inside("Scale 20 20 20.02")), "render",
             match=scene(center="0 0.5 0", num_objects=1, objects=inside("UniformScale 20"))),
    ]
