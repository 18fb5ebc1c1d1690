"""Parser for the course's scene text format into :mod:`converters.model`.

The grammar (keywords are case-sensitive, ``#`` starts a comment, braces may
touch their neighbours as in ``shininess 20}``)::

    scene      := section*
    section    := PerspectiveCamera { center V direction V up V angle F }
                | Lights { numLights N light* }
                | Background { [color V] [ambientLight V] [cubeMap PATH] }
                | Materials { numMaterials N material* }
                | Group
    light      := DirectionalLight { direction V color V }
                | PointLight { position V color V [falloff F] }
    material   := (Material | PhongMaterial) { [diffuseColor V] [specularColor V] [shininess F] }
    Group      := Group { numObjects N (MaterialIndex N | object)* }
    object     := Group | Sphere { center V radius F } | Plane { normal V offset F }
                | Triangle { vertex0 V vertex1 V vertex2 V } | TriangleMesh { obj_file PATH }
                | Transform { transform* object }
    transform  := Scale V | UniformScale F | Translate V | XRotate F | YRotate F | ZRotate F
                | Rotate { V F } | Matrix4f { F*16 }

Semantics follow the course's reference solution: inside a ``Transform`` each
listed transform multiplies the running matrix on the right (the first listed
is applied last to the object), except ``Matrix4f``, whose 16 numbers are read
column by column and multiply on the left. ``MaterialIndex`` is a global state
that ignores the group hierarchy. Paths are relative to the scene file.
Every problem is a :class:`SceneError` at ``file:line:col``.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from core.errors import SceneError
from core.inputs import NotAnInputFile, read_input
from imaging.image_io import CUBE_FACES, read_cube_map
from mi_plugins.camera_basis import course_camera_basis

from . import transforms
from .model import (
    Background,
    Camera,
    DirectionalLight,
    Material,
    Plane,
    PointLight,
    Scene,
    Sphere,
    Triangle,
    TriangleMesh,
)
from .obj import read_obj
from .tokens import FLOAT32_MAX, Token, TokenReader, tokenize

#: Rendered scenes are float32 (Mitsuba's rays, hits and offsets): a scene scaled
#: uniformly renders the same only within a range of sizes (docs/validation.md,
#: the scale stress cases). So world coordinates are at most MAX_COORDINATE in
#: magnitude, and a scene (camera and objects) spans at least MIN_SCENE_SIZE.
MAX_COORDINATE = 1e12
MIN_SCENE_SIZE = 1e-10

#: Deepest nesting of Group and Transform blocks (scenes nest a handful; the
#: limit keeps the recursive parser far from Python's recursion limit)
MAX_NESTING = 200


#: Lengths of direction vectors whose float32 square is a normal, finite number
#: (Mitsuba normalises them in float32: outside this, a normalised direction is 0 or NaN)
FLOAT32_LENGTHS = (float(np.sqrt(np.finfo(np.float32).tiny)) * 1.01, float(np.sqrt(FLOAT32_MAX)) * 0.99)


def _length_fits_float32(vector) -> bool:
    length = float(np.linalg.norm(np.asarray(vector, np.float64)))
    return FLOAT32_LENGTHS[0] <= length <= FLOAT32_LENGTHS[1]


def _camera_fits_float32(direction: np.ndarray, up: np.ndarray, angle: float) -> bool:
    """The course camera's basis (:func:`mi_plugins.camera_basis.course_camera_basis`,
    which the sensor rounds to float32) is finite and non-zero in float32: the
    forward vector, the horizontal, and the corner ray forward + horizontal + up."""
    if not (_length_fits_float32(direction) and _length_fits_float32(up)):
        return False
    try:
        basis = course_camera_basis(direction, up, angle)
    except ValueError:
        return False
    with np.errstate(all="ignore"):
        vectors = np.stack([basis.forward, basis.horizontal, basis.forward + basis.horizontal + basis.up])
        rounded = vectors.astype(np.float32)
        lengths = np.sqrt(np.sum(rounded * rounded, axis=1, dtype=np.float32))
    return bool(basis.tan_half_fov > 0 and np.all(np.isfinite(rounded)) and np.all(np.isfinite(lengths))
                and np.all(lengths > np.finfo(np.float32).tiny))


class _Parser(TokenReader):
    """The grammar: sections, lights, materials, groups, objects and transforms."""

    def __init__(self, path: Path, text: str):
        super().__init__(path, text)
        self.materials: list[Material] = []
        self.material_index: int | None = None
        self.objects = []
        self.mesh_cache: dict[Path, tuple[np.ndarray, np.ndarray]] = {}
        self.bounds: list[tuple[np.ndarray, np.ndarray]] = []  # of each bounded object's world points
        self.camera_token: Token | None = None
        self.nesting = 0  # Group and Transform blocks open around the current token

    # -- sections -----------------------------------------------------------
    def scene(self) -> Scene:
        camera = lights = background = None
        seen: set[str] = set()
        while self.peek().text is not None:
            token = self.next()
            if token.text in seen and token.text != "Group":
                raise self.error(token, f"one {token.text} section, but it is repeated")
            seen.add(token.text)
            if token.text == "PerspectiveCamera":
                camera = self.camera()
            elif token.text == "Lights":
                lights = self.lights()
            elif token.text == "Background":
                background = self.background()
            elif token.text == "Materials":
                self.materials = self.material_list()
            elif token.text == "Group":
                self.group(np.eye(4))
            else:
                raise self.error(token, "a section (PerspectiveCamera, Lights, Background, Materials, Group)")
        if camera is None:
            raise self.error(self.end, "a PerspectiveCamera section")
        if self.bounds:
            corners = np.array([corner for bound in self.bounds for corner in bound] + [camera.center])
            size = float(np.linalg.norm(corners.max(axis=0) - corners.min(axis=0)))
            if size < MIN_SCENE_SIZE:
                token = self.camera_token
                raise SceneError(self.path, token.line, token.col,
                                 f"expected a scene (camera and objects) at least {MIN_SCENE_SIZE:g} across "
                                 f"(float32 rendering is exact enough only above that), found {size:g}")
        return Scene(path=self.path, camera=camera, lights=lights or [],
                     background=background or Background(), materials=self.materials,
                     objects=self.objects)

    def camera(self) -> Camera:
        start = self.peek()
        values, _ = self.fields({"center": self.vector, "direction": self.vector, "up": self.vector,
                                 "angle": self.number}, {"center", "direction", "up", "angle"})
        direction, up, angle = np.array(values["direction"]), np.array(values["up"]), values["angle"]
        if not 0.0 < angle < 180.0:
            raise SceneError(self.path, start.line, start.col,
                             f"expected an angle in (0, 180) degrees, found {angle:g}")
        if np.linalg.norm(direction) == 0.0:
            raise SceneError(self.path, start.line, start.col, "expected a non-zero camera direction, found 0 0 0")
        if np.linalg.norm(np.cross(direction, up)) <= 1e-12 * np.linalg.norm(direction) * np.linalg.norm(up):
            raise SceneError(self.path, start.line, start.col,
                             "expected a camera up vector not parallel to its direction, found a parallel one")
        if not _camera_fits_float32(direction, up, angle):
            raise SceneError(self.path, start.line, start.col,
                             "expected a camera whose direction, up and angle give finite float32 rays "
                             f"(lengths {FLOAT32_LENGTHS[0]:g}..{FLOAT32_LENGTHS[1]:g}, angle not tiny), found "
                             f"|direction| {np.linalg.norm(direction):g}, |up| {np.linalg.norm(up):g}, "
                             f"angle {angle:g}")
        self.within_range(start, "a camera center", values["center"])
        self.camera_token = start
        return Camera(values["center"], values["direction"], values["up"], angle)

    def counted(self, count_key: str, item) -> list:
        """``{ countKey N item*N }``: exactly N items."""
        self.expect("{")
        token = self.next()
        if token.text != count_key:
            raise self.error(token, repr(count_key))
        count = self.integer()
        items = []
        while self.peek().text != "}":
            if len(items) == count:
                raise self.error(self.peek(), f"'}}' after {count} items ({count_key} {count})")
            items.append(item())
        if len(items) != count:
            raise self.error(self.peek(), f"{count} items ({count_key} {count}) but found {len(items)}, then")
        self.next()
        return items

    def lights(self):
        def light():
            token = self.next()
            if token.text == "DirectionalLight":
                values, end = self.fields({"direction": self.vector, "color": self.vector}, {"direction", "color"})
                if not any(values["direction"]):
                    raise SceneError(self.path, token.line, token.col,
                                     "expected a non-zero light direction, found 0 0 0")
                if not _length_fits_float32(values["direction"]):
                    raise SceneError(self.path, token.line, token.col,
                                     f"expected a light direction of length {FLOAT32_LENGTHS[0]:g}.."
                                     f"{FLOAT32_LENGTHS[1]:g} (float32 squares it), "
                                     f"found {np.linalg.norm(values['direction']):g}")
                # the converter multiplies by pi (see converters.description)
                self.finite32(token, "a light irradiance (color * pi)", np.asarray(values["color"]) * math.pi)
                return DirectionalLight(values["direction"], values["color"])
            if token.text == "PointLight":
                values, end = self.fields({"position": self.vector, "color": self.vector, "falloff": self.number},
                                          {"position", "color"})
                falloff = values.get("falloff", 1.0)
                if falloff <= 0.0:  # the intensity is color / (falloff * d^2)
                    raise SceneError(self.path, token.line, token.col,
                                     f"expected a falloff > 0, found {falloff:g}")
                self.finite32(token, "a light intensity (color * pi / falloff)",
                              np.asarray(values["color"]) * (math.pi / falloff))
                self.within_range(token, "a light position", values["position"])
                return PointLight(values["position"], values["color"], falloff)
            raise self.error(token, "DirectionalLight or PointLight")
        return self.counted("numLights", light)

    def background(self) -> Background:
        start = self.peek()
        values, _ = self.fields({"color": self.vector, "ambientLight": self.vector, "cubeMap": self.path_value},
                                set())
        folder = values.get("cubeMap")
        if folder is not None:
            missing = [f for f in CUBE_FACES if not (folder / f"{f}.png").is_file()]
            if missing:
                raise SceneError(self.path, start.line, start.col,
                                 f"expected cube-map faces {', '.join(f + '.png' for f in missing)} in {folder}, "
                                 "found none")
            # decoded now (and cached for the renderer), so that a damaged or
            # non-square face is a located error before any work starts
            read_cube_map(folder)
        return Background(values.get("color", (0.0, 0.0, 0.0)), values.get("ambientLight", (0.0, 0.0, 0.0)),
                          values.get("cubeMap"))

    def material_list(self) -> list[Material]:
        def material():
            token = self.next()
            if token.text not in ("Material", "PhongMaterial"):
                raise self.error(token, "Material or PhongMaterial")
            values, _ = self.fields({"diffuseColor": self.vector, "specularColor": self.vector,
                                     "shininess": self.number}, set())
            if values.get("shininess", 0.0) < 0.0:
                raise SceneError(self.path, token.line, token.col,
                                 f"expected a shininess >= 0, found {values['shininess']:g}")
            return Material(values.get("diffuseColor", (1.0, 1.0, 1.0)),
                            values.get("specularColor", (0.0, 0.0, 0.0)), values.get("shininess", 0.0))
        return self.counted("numMaterials", material)

    # -- objects ------------------------------------------------------------
    def in_world(self, token: Token, to_world: np.ndarray, points, bounded: bool = True) -> None:
        """An object's points, moved into the world, must stay float32 numbers."""
        points = np.asarray(points, np.float64).reshape(-1, 3)
        with np.errstate(over="ignore", invalid="ignore"):
            world = points @ to_world[:3, :3].T + to_world[:3, 3]
        self.finite32(token, "the object's world-space coordinates", world)
        self.within_range(token, "the object's world-space coordinates", world)
        if bounded:  # (a plane's point is any of its points: no size)
            self.bounds.append((world.min(axis=0), world.max(axis=0)))

    def within_range(self, token: Token, what: str, points) -> None:
        largest = float(np.abs(np.asarray(points, np.float64)).max(initial=0.0))
        if largest > MAX_COORDINATE:
            raise SceneError(self.path, token.line, token.col,
                             f"expected {what} of magnitude at most {MAX_COORDINATE:g} (float32 rendering "
                             f"is exact enough only within that), found {largest:g}")

    def enter(self, token: Token) -> None:
        self.nesting += 1
        if self.nesting > MAX_NESTING:
            raise SceneError(self.path, token.line, token.col,
                             f"expected at most {MAX_NESTING} nested groups and transforms, found more")

    def group(self, to_world: np.ndarray) -> None:
        self.enter(self.peek())
        self.expect("{")
        token = self.next()
        if token.text != "numObjects":
            raise self.error(token, "'numObjects'")
        count, found = self.integer(), 0
        while self.peek().text != "}":
            token = self.peek()
            if token.text == "MaterialIndex":
                self.next()
                index_token = self.peek()
                index = self.integer()
                if index >= len(self.materials) and not self.materials:
                    raise SceneError(self.path, index_token.line, index_token.col,
                                     f"found MaterialIndex {index}, but the scene declares no materials "
                                     "(numMaterials 0)")
                if index >= len(self.materials):
                    raise self.error(index_token, f"a material index in 0..{len(self.materials) - 1}")
                self.material_index = index
                continue
            if found == count:
                raise self.error(token, f"'}}' after {count} objects (numObjects {count})")
            self.object(to_world)
            found += 1
        if found != count:
            raise self.error(self.peek(), f"{count} objects (numObjects {count}) but found {found}, then")
        self.next()
        self.nesting -= 1

    def object(self, to_world: np.ndarray) -> None:
        token = self.next()
        kind = token.text
        if kind == "Group":
            return self.group(to_world)
        if kind == "Transform":
            return self.transform(to_world)
        if kind not in ("Sphere", "Plane", "Triangle", "TriangleMesh"):
            raise self.error(token, "an object (Group, Transform, Sphere, Plane, Triangle, TriangleMesh)")
        if self.material_index is None:
            raise SceneError(self.path, token.line, token.col,
                             f"expected a MaterialIndex before the first object, found {kind}")
        common = dict(material=self.material_index, to_world=to_world)
        if kind == "Sphere":
            values, _ = self.fields({"center": self.vector, "radius": self.number}, {"center", "radius"})
            if values["radius"] <= 0.0:
                raise SceneError(self.path, token.line, token.col,
                                 f"expected a sphere radius > 0, found {values['radius']:g}")
            corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float64)
            self.in_world(token, to_world, np.asarray(values["center"]) + values["radius"] * corners)
            self.objects.append(Sphere(**common, center=values["center"], radius=values["radius"]))
        elif kind == "Plane":
            values, _ = self.fields({"normal": self.vector, "offset": self.number}, {"normal", "offset"})
            if not any(values["normal"]):
                raise SceneError(self.path, token.line, token.col, "expected a non-zero plane normal, found 0 0 0")
            normal = np.asarray(values["normal"], np.float64)
            self.in_world(token, to_world, [normal / np.linalg.norm(normal) * values["offset"]], bounded=False)
            self.objects.append(Plane(**common, normal=values["normal"], offset=values["offset"]))
        elif kind == "Triangle":
            values, _ = self.fields({"vertex0": self.vector, "vertex1": self.vector, "vertex2": self.vector},
                                    {"vertex0", "vertex1", "vertex2"})
            vertices = (values["vertex0"], values["vertex1"], values["vertex2"])
            self.in_world(token, to_world, vertices)
            self.objects.append(Triangle(**common, vertices=vertices))
        else:
            values, _ = self.fields({"obj_file": self.path_value}, {"obj_file"})
            path = values["obj_file"]
            if path not in self.mesh_cache:
                self.mesh_cache[path] = read_obj(path)
            positions, faces = self.mesh_cache[path]
            self.in_world(token, to_world, positions)
            self.objects.append(TriangleMesh(**common, path=path, positions=positions, faces=faces))

    def transform(self, to_world: np.ndarray) -> None:
        start = self.peek()
        self.enter(start)
        self.expect("{")
        matrix = np.eye(4)
        unary = {"XRotate": transforms.rotate_x, "YRotate": transforms.rotate_y, "ZRotate": transforms.rotate_z,
                 "UniformScale": transforms.uniform_scale}
        vector = {"Scale": transforms.scale, "Translate": transforms.translate}
        while True:
            token = self.peek()
            if token.text in unary:
                self.next()
                matrix = matrix @ unary[token.text](self.number())
            elif token.text in vector:
                self.next()
                matrix = matrix @ vector[token.text](self.vector())
            elif token.text == "Rotate":
                self.next()
                self.expect("{")
                axis, degrees = self.vector(), self.number()
                if not any(axis):
                    raise SceneError(self.path, token.line, token.col, "expected a non-zero rotation axis, found 0 0 0")
                self.expect("}")
                matrix = matrix @ transforms.rotate(axis, degrees)
            elif token.text == "Matrix4f":
                self.next()
                self.expect("{")
                columns = [self.number() for _ in range(16)]
                self.expect("}")
                given = np.array(columns, np.float64).reshape(4, 4).T
                if not np.array_equal(given[3], [0.0, 0.0, 0.0, 1.0]):
                    # a ray tracer's transforms are affine; a projective last row has no meaning for
                    # spheres and normals (and a zero one cannot be inverted)
                    raise SceneError(self.path, token.line, token.col,
                                     "expected an affine Matrix4f, whose last row (the 4th number of each "
                                     f"column) is 0 0 0 1, found {' '.join(f'{v:g}' for v in given[3])}")
                matrix = given @ matrix
            else:
                break
        with np.errstate(over="ignore", invalid="ignore"):
            world = to_world @ matrix
        self.finite32(start, "a transform matrix", world)
        linear = world[:3, :3]
        scale = np.abs(linear).max()
        if not np.all(np.isfinite(world)) or scale == 0.0 or abs(np.linalg.det(linear / scale)) < 1e-12:
            raise SceneError(self.path, start.line, start.col,
                             "expected an invertible transform, found a singular one (a scale of 0?)")
        # Mitsuba keeps the inverse too, in float32: a scale of 1e-39 inverts to infinity
        try:
            inverse = np.linalg.inv(world)
        except np.linalg.LinAlgError:
            raise SceneError(self.path, start.line, start.col,
                             "expected an invertible transform, found a singular one") from None
        self.finite32(start, "an inverse transform matrix", inverse)
        self.object(world)
        self.expect("}")
        self.nesting -= 1


def parse_scene(text: str, path: str | Path = "<string>") -> Scene:
    """Parses scene text; relative paths inside it resolve against ``path``'s folder."""
    return _Parser(Path(path), text).scene()


def referenced_files(path: str | Path) -> list[Path]:
    """The files a scene file reads besides itself: its meshes and cube-map
    faces, found by a scan of its words (no parsing: a damaged scene stays the
    parser's to report). Unreadable scenes name none."""
    path = Path(path)
    try:
        text = read_input(path).decode("utf-8-sig")
    except (OSError, NotAnInputFile, UnicodeDecodeError):
        return []
    words = [token.text for token in tokenize(text)]
    files = []
    for key, value in zip(words, words[1:]):
        if key == "obj_file":
            files.append(path.parent / value)
        elif key == "cubeMap":
            files.extend(path.parent / value / f"{face}.png" for face in CUBE_FACES)
    return files


def load_scene(path: str | Path) -> Scene:
    """Reads and parses a scene file."""
    path = Path(path)
    try:
        data = read_input(path)
    except OSError as error:
        raise SceneError(path, 1, 1, f"cannot read scene: {error.strerror or error}") from None
    except NotAnInputFile as error:
        raise SceneError(path, 1, 1, f"cannot read scene: {error}") from None
    try:
        text = data.decode("utf-8-sig")  # a byte-order mark (Windows editors) is not text
    except UnicodeDecodeError as error:
        line = data[: error.start].count(b"\n") + 1
        raise SceneError(path, line, 1, "expected scene text, found binary data") from None
    if "\0" in text:
        line = text[: text.index("\0")].count("\n") + 1
        raise SceneError(path, line, 1, "expected scene text, found binary data")
    return parse_scene(text, path)
