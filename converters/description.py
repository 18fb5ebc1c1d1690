"""From the scene model to the scene description: what to render, as plain data.

The description is a ``mi.load_dict``-shaped dict of numbers, lists and NumPy
arrays, so it pickles and needs no Mitsuba variant (this module does not
import Mitsuba). It names each course object once, in the form that keeps the
course's geometry: ``"mesh_data"`` (a triangle mesh in memory), ``"plane_tiles"``
(an infinite plane as rectangle tiles), ``"ellipsoids"`` (the arrays of one
transformed sphere) or a ``"sphere"``. :func:`converters.lowering.lower` is the
one place that turns these into Mitsuba plugins; :func:`converters.to_mitsuba.load_scene_dict`
(a Mitsuba scene) and :func:`converters.xml_writer.write_xml` (XML) both read
its result. Validation variants (the path tracer, no ambient, ...) are
functions over the description, in :mod:`converters.scene_variants`.

Only what the scene uses is written: materials that some object uses, a
``constant`` emitter only for a non-black background colour, the cube map only
when there is one, and the integrator's AOVs only when asked for.

Lights carry a factor pi because the ``phong`` BSDF is normalised like a
physical BSDF (its diffuse lobe is k_d / pi); the product then equals the
course's shading formula.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import numpy as np
from drjit.scalar import Matrix3f64

from .model import DirectionalLight, Plane, PointLight, Scene, Sphere, Triangle, TriangleMesh

#: Half-size of an infinite plane, in multiples of the camera's distance to it
#: or to the objects (whichever is larger)
PLANE_EXTENT = 1e5

#: A transformed sphere is a Mitsuba ellipsoid (exact) only where those work:
#: longest to shortest axis at most this ratio,
MAX_ELLIPSOID_ANISOTROPY = 10.0
#: shortest axis at least this long, in scene units (measured: axes of 0.0035
#: miss rays, 0.035 do not; the failure does not scale with the scene),
MIN_ELLIPSOID_AXIS = 0.1
#: and the camera outside, by this fraction of the radius; else a fine mesh
ELLIPSOID_CAMERA_MARGIN = 1e-3

#: Secondary rays leaving an object skip hits closer than this fraction of
#: the object's size (see :func:`object_sizes`); for planes, of the camera's
#: distance to the plane. The course's solution uses one fixed distance; these
#: fractions match its images of scenes 06 and 07 (where the distance shows),
#: and keep every image independent of the scene's scale, of lights and of
#: far-away objects
RAY_EPSILON_FRACTION = 3.4e-3
PLANE_RAY_EPSILON_FRACTION = 1.2e-3


@dataclass(frozen=True)
class RenderOptions:
    """The course binary's rendering flags, plus the AOVs to export, the seed and ray counting."""
    width: int = 800
    height: int = 800
    bounces: int = 0
    shadows: bool = False
    spp: int = 1
    jitter: bool = False  # sub-pixel sample positions instead of pixel centres
    aovs: tuple[str, ...] = ()
    seed: int = 0
    stats: bool = False  # count the traced rays (whitted's "stats")


def _rgb(value) -> dict:
    return {"type": "rgb", "value": [float(v) for v in value]}


def _frame_to_world(normal: np.ndarray) -> np.ndarray:
    """A rotation taking +z to ``normal`` (unit)."""
    n = normal / np.linalg.norm(normal)
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    s = np.cross(helper, n)
    s /= np.linalg.norm(s)
    t = np.cross(n, s)
    return np.column_stack([s, t, n])


def _world_points(obj) -> np.ndarray | None:
    """Points whose bounding box is the object's (None for a plane)."""
    m = obj.to_world
    if isinstance(obj, Sphere):
        corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
        local = np.asarray(obj.center) + obj.radius * corners
    elif isinstance(obj, Triangle):
        local = np.asarray(obj.vertices, np.float64)
    elif isinstance(obj, TriangleMesh):
        local = obj.positions
    else:
        return None
    return np.atleast_2d(local) @ m[:3, :3].T + m[:3, 3]


def _plane(obj: Plane) -> tuple[np.ndarray, np.ndarray]:
    """(a point, the unit normal) of a plane in world space."""
    normal = np.asarray(obj.normal, np.float64)
    unit = normal / np.linalg.norm(normal)
    point = _transform_points(obj.to_world, np.asarray([unit * obj.offset]))[0]
    world_normal = np.linalg.inv(obj.to_world[:3, :3]).T @ unit
    return point, world_normal / np.linalg.norm(world_normal)


def view_scale(scene: Scene) -> float:
    """How far the camera looks: the median distance from the camera to the
    bounded objects' centres (1 without any). One object far away does not change it."""
    camera = np.asarray(scene.camera.center, np.float64)
    distances = [float(np.linalg.norm((p.min(axis=0) + p.max(axis=0)) / 2 - camera))
                 for p in map(_world_points, scene.objects) if p is not None]
    # the lower median: with two objects, the nearer one
    scale = sorted(distances)[(len(distances) - 1) // 2] if distances else 0.0
    return scale if scale > 0.0 else 1.0


def object_sizes(scene: Scene) -> list[float]:
    """The size of each object that its secondary-ray epsilon is a fraction of.

    A bounded object's size is the radius of its bounding box's sphere. An
    infinite plane has none; its size is the camera's distance to it (what
    the camera sees of the plane scales with it), or, for a camera in the
    plane, the view scale. Lights and other objects change no object's size.
    """
    camera = np.asarray(scene.camera.center, np.float64)
    sizes = []
    for obj in scene.objects:
        points = _world_points(obj)
        if points is not None:
            size = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0))) / 2
        else:
            point, normal = _plane(obj)
            size = abs(float(np.dot(camera - point, normal))) or view_scale(scene)
        sizes.append(max(size, 1e-30))
    return sizes


def ray_epsilons(scene: Scene) -> list[float]:
    """Per object: secondary rays leaving it skip hits closer than this."""
    return [(PLANE_RAY_EPSILON_FRACTION if isinstance(obj, Plane) else RAY_EPSILON_FRACTION) * size
            for obj, size in zip(scene.objects, object_sizes(scene))]


def plane_tiles(frame: np.ndarray, foot: np.ndarray, inner: float, outer: float) -> list[np.ndarray]:
    """Rectangles (to-world matrices) tiling a square of half-size ``outer``.

    A single huge rectangle loses the hit point's position in its plane
    (Mitsuba rebuilds it from local coordinates: error ~1e-7 of the size), so
    the plane is a centre tile of half-size ``inner`` and rings of 4 tiles
    growing 8x each: every tile is at most ~8x larger than its distance to
    the centre. Neighbours overlap a little so that no ray slips between them.
    """
    def tile(x0, x1, y0, y1):
        # the overlap also covers the rounding of the tile's float32 world coordinates
        reach = float(np.abs(foot).max()) + max(abs(x0), abs(x1), abs(y0), abs(y1))
        grow = max(1e-4 * max(x1 - x0, y1 - y0), 2.0 ** -20 * reach)
        m = np.eye(4)
        m[:3, :3] = frame @ np.diag([(x1 - x0) / 2 + grow, (y1 - y0) / 2 + grow, 1.0])
        m[:3, 3] = foot + frame @ np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0])
        return m

    tiles = [tile(-inner, inner, -inner, inner)]
    a = inner
    while a < outer:
        b = 8.0 * a
        tiles += [tile(-b, b, a, b), tile(-b, b, -b, -a), tile(-b, -a, -a, a), tile(a, b, -a, a)]
        a = b
    return tiles


def unit_sphere_mesh(rings: int = 128, segments: int = 256) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(positions, normals, faces) of a latitude-longitude unit sphere, faces outwards."""
    theta = np.linspace(0.0, np.pi, rings + 1)
    phi = np.linspace(0.0, 2.0 * np.pi, segments, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    positions = np.stack([np.sin(t) * np.cos(p), np.cos(t), np.sin(t) * np.sin(p)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(rings), np.arange(segments), indexing="ij")
    a, b = i * segments + j, i * segments + (j + 1) % segments
    c, d = a + segments, b + segments
    faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([b, d, c], -1).reshape(-1, 3)])
    # drop the degenerate triangles at the poles
    area = np.linalg.norm(np.cross(positions[faces[:, 1]] - positions[faces[:, 0]],
                                   positions[faces[:, 2]] - positions[faces[:, 0]]), axis=1)
    return positions, positions.copy(), faces[area > 1e-12].astype(np.uint32)


def smooth_normals(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Per-vertex normals as the course computes them: the normalised sum of
    the unit normals of the faces around each vertex (degenerate faces add
    nothing; a vertex with none keeps a zero normal)."""
    p0, p1, p2 = (positions[faces[:, k]] for k in range(3))
    face_normals = np.cross(p1 - p0, p2 - p0)
    length = np.linalg.norm(face_normals, axis=1, keepdims=True)
    face_normals = np.divide(face_normals, length, out=np.zeros_like(face_normals), where=length > 0)
    normals = np.zeros_like(positions)
    for k in range(3):
        np.add.at(normals, faces[:, k], face_normals)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)


def _mesh(positions: np.ndarray, faces: np.ndarray) -> dict:
    # "mesh_data" is not a Mitsuba plugin: lower() makes it a "ply" shape
    # whose file is in memory (flat shading: no normals)
    return {"type": "mesh_data", "positions": np.asarray(positions, np.float64),
            "faces": np.asarray(faces, np.uint32)}


def _smooth_mesh(m: np.ndarray, positions: np.ndarray, faces: np.ndarray) -> dict:
    """A mesh with the course's normals: averaged in object space, carried to
    world space by the inverse transpose and left unnormalised, so that their
    interpolation (normalised per hit) is the course's exactly."""
    normals = smooth_normals(positions, faces) @ np.linalg.inv(m[:3, :3])
    return dict(_mesh(_transform_points(m, positions), faces), normals=normals)


def _transform_points(m: np.ndarray, points: np.ndarray) -> np.ndarray:
    return points @ m[:3, :3].T + m[:3, 3]


def _outside(offset: np.ndarray, linear: np.ndarray) -> bool:
    """A point ``offset`` from the centre of the ellipsoid ``linear`` (unit sphere) lies clearly outside it."""
    return float(np.linalg.norm(np.linalg.solve(linear, offset))) > 1.0 + ELLIPSOID_CAMERA_MARGIN


def object_dict(scene: Scene, index: int) -> dict:
    """The shape of object ``index``, world transform applied."""
    obj = scene.objects[index]
    m = obj.to_world
    if isinstance(obj, Sphere):
        linear = m[:3, :3] * obj.radius
        center = _transform_points(m, np.asarray([obj.center], np.float64))[0]
        u, sigma, vt = np.linalg.svd(linear)
        if sigma[0] - sigma[2] <= 1e-9 * sigma[0]:
            return {"type": "sphere", "center": center.tolist(), "radius": float(sigma[0])}
        if sigma[0] <= MAX_ELLIPSOID_ANISOTROPY * sigma[2] and sigma[2] >= MIN_ELLIPSOID_AXIS \
                and _outside(np.asarray(scene.camera.center, np.float64) - center, linear):
            if np.linalg.det(u) < 0:
                u[:, 2] = -u[:, 2]
            # The image of the unit sphere under U diag(sigma) V^T is U diag(sigma) (sphere)
            quat = _quaternion_xyzw(u)
            return {"type": "ellipsoids", "extent": 1.0,
                    "centers": np.asarray([center], np.float32),
                    "scales": np.asarray([sigma], np.float32),
                    "quaternions": np.asarray([quat], np.float32)}
        # Elsewhere Mitsuba's ellipsoids fail (measured): they miss about half the
        # rays once the axes differ ~100x, miss rays when small (white speckles
        # at 1e-4, nothing at 1e-5) and report no hit from inside. There a
        # transformed sphere is a fine mesh with the exact normals of the ellipsoid.
        positions, normals, faces = unit_sphere_mesh()
        return dict(_mesh(positions @ linear.T + center, faces), normals=normals @ np.linalg.inv(linear))
    if isinstance(obj, Plane):
        point, normal = _plane(obj)
        camera = np.asarray(scene.camera.center, np.float64)
        height = abs(float(np.dot(camera - point, normal)))
        foot = camera - np.dot(camera - point, normal) * normal
        # tiles centred below the camera, the centre tile as large as the camera's height
        # (a thousandth of its distance to the objects if it lies in the plane), out far
        # enough to pass the horizon and every object; far objects only add rings
        view = view_scale(scene)
        inner = max(height, 1e-3 * view)
        reach = max([float(np.abs(p - foot).max()) for p in map(_world_points, scene.objects)
                     if p is not None] + [0.0])
        return {"type": "plane_tiles", "to_world": plane_tiles(_frame_to_world(normal), foot, inner,
                                                               max(PLANE_EXTENT * max(height, view), 8.0 * reach))}
    if isinstance(obj, Triangle):
        positions = _transform_points(m, np.asarray(obj.vertices, np.float64))
        return _mesh(positions, np.array([[0, 1, 2]], np.uint32))
    if isinstance(obj, TriangleMesh):
        return _smooth_mesh(m, obj.positions, obj.faces)
    raise TypeError(f"unknown object type {type(obj).__name__}")


def _quaternion_xyzw(r: np.ndarray) -> list[float]:
    """Unit quaternion (x, y, z, w) of a rotation matrix (Dr.Jit's conversion)."""
    q = dr.matrix_to_quat(Matrix3f64(np.asarray(r, np.float64).tolist()))
    return [float(q[0]), float(q[1]), float(q[2]), float(q[3])]


def scene_dict(scene: Scene, options: RenderOptions = RenderOptions()) -> dict:
    """The description of ``scene`` rendered with ``options`` (see the module's docstring)."""
    camera = scene.camera
    integrator: dict = {"type": "whitted", "bounces": int(options.bounces), "shadows": bool(options.shadows)}
    if any(v != 0.0 for v in scene.background.ambient):
        integrator["ambient"] = _rgb(scene.background.ambient)
    epsilons = ",".join(f"{e:.9g}" for e in ray_epsilons(scene))
    if epsilons:
        integrator["ray_epsilons"] = epsilons
    if options.aovs:
        integrator["aovs"] = ",".join(options.aovs)
    if options.stats:
        integrator["stats"] = True
    result: dict = {
        "type": "scene",
        "integrator": integrator,
        "sensor": {
            "type": "course_camera",
            "origin": list(map(float, camera.center)),
            "direction": list(map(float, camera.direction)),
            "up": list(map(float, camera.up)),
            "fov": float(camera.angle),
            "pixel_centers": not options.jitter,
            "film": {"type": "hdrfilm", "width": int(options.width), "height": int(options.height),
                     "pixel_format": "rgb", "component_format": "float32", "rfilter": {"type": "box"}},
            "sampler": {"type": "independent", "sample_count": int(options.spp), "seed": int(options.seed)},
        },
    }

    used = sorted({obj.material for obj in scene.objects})
    for index in used:
        material = scene.materials[index]
        bsdf = {"type": "phong", "id": f"material_{index}", "diffuse_reflectance": _rgb(material.diffuse)}
        if material.reflective:
            bsdf["specular_reflectance"] = _rgb(material.specular)
            bsdf["exponent"] = float(material.shininess)
        result[f"material_{index}"] = bsdf

    for k, light in enumerate(scene.lights):
        if isinstance(light, PointLight):
            result[f"light_{k}"] = {"type": "point", "position": list(map(float, light.position)),
                                    "intensity": _rgb(np.asarray(light.color) * (math.pi / light.falloff))}
        elif isinstance(light, DirectionalLight):
            result[f"light_{k}"] = {"type": "directional", "direction": list(map(float, light.direction)),
                                    "irradiance": _rgb(np.asarray(light.color) * math.pi)}

    background = scene.background
    if background.cube_map is not None:
        result["background"] = {"type": "course_cubemap", "folder": str(background.cube_map)}
    elif any(v != 0.0 for v in background.color):
        result["background"] = {"type": "constant", "radiance": _rgb(background.color)}

    for index, obj in enumerate(scene.objects):
        shape = object_dict(scene, index)
        shape["bsdf"] = {"type": "ref", "id": f"material_{obj.material}"}
        result[f"object_{index}"] = shape
    return result
