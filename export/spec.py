"""The sequence spec: its schema, and the checks that refuse a bad one before any work.

Every problem is a :class:`SpecError` naming the file and the key
(``spec.json: camera.dolly: expected a finite number, found nan``).
"""
from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path

from converters.model import DirectionalLight, PointLight, Scene
from core.errors import SpecError
from core.json_input import JSONInputError, json_kind, read_json, shown

# Limits: Mitsuba indexes one render's samples with 32-bit integers
MAX_SIDE = 16384
MAX_SAMPLES_PER_RENDER = 2 ** 31
MAX_FRAMES = 100_000
MAX_SPP = 1 << 20
MAX_BOUNCES = 64
#: the largest spec file read, in bytes
MAX_SPEC_BYTES = 1 << 20


def _key_in(source: str, key: str) -> str:
    """Where a problem is: ``source: key`` (the key alone without a source)."""
    return f"{source}: {key}" if source else key


#: an object's or light's index as a key: one spelling per index ("00" and "01" would name 0 and 1 twice)
INDEX = r"0|[1-9]\d{0,8}"


def _int(value, name: str, source: str, low: int, high: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise SpecError(f"{_key_in(source, name)}: expected an integer, found {shown(value)}")
    if not low <= value <= high:
        raise SpecError(f"{_key_in(source, name)}: expected {low}..{high}, found {value}")
    return value


def _number(value, name: str, source: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
            or abs(value) > 1e30:
        raise SpecError(f"{_key_in(source, name)}: expected a finite number of magnitude at most 1e30, "
                        f"found {shown(value)}")
    return float(value)


def _vector(value, name: str, source: str) -> list[float]:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise SpecError(f"{_key_in(source, name)}: expected [x, y, z], found {shown(value)}")
    return [_number(v, f"{name}[{k}]", source) for k, v in enumerate(value)]


def _bool(value, name: str, source: str) -> bool:
    if not isinstance(value, bool):
        raise SpecError(f"{_key_in(source, name)}: expected true or false, found {shown(value)}")
    return value


def _keys(value, name: str, source: str, known: set[str]) -> dict:
    if not isinstance(value, dict):
        raise SpecError(f"{_key_in(source, name)}: expected an object, found {shown(value)}")
    unknown = set(value) - known
    if unknown:
        raise SpecError(f"{_key_in(source, name)}: unknown keys {', '.join(map(shown, sorted(unknown)))} "
                        f"(known: {', '.join(sorted(known))})")
    return value


#: a rotation axis is normalised in float64 and its matrix rounded to float32: beyond these
#: lengths its square underflows or overflows (an axis of 1e-320 gave NaN frames)
MIN_AXIS_LENGTH, MAX_AXIS_LENGTH = 1e-100, 1e100


def usable_axis(axis: list[float]) -> bool:
    length = math.sqrt(sum(a * a for a in axis))
    return MIN_AXIS_LENGTH <= length <= MAX_AXIS_LENGTH


def _check_rotation(value, name: str, source: str) -> None:
    """``{"axis": [x, y, z], "degrees": d}`` with a usable axis (:func:`usable_axis`)."""
    rotate = _keys(value, name, source, {"axis", "degrees"})
    if "axis" not in rotate or "degrees" not in rotate:
        raise SpecError(f"{_key_in(source, name)}: expected \"axis\" and \"degrees\"")
    if not usable_axis(_vector(rotate["axis"], f"{name}.axis", source)):
        raise SpecError(f"{_key_in(source, name + '.axis')}: expected an axis of length "
                        f"{MIN_AXIS_LENGTH:g} to {MAX_AXIS_LENGTH:g}")
    _number(rotate["degrees"], f"{name}.degrees", source)

#: a scene by name (``box``, ``scene06``); anything else is a ``.txt`` scene file
SCENE_NAME = r"\w[\w.-]*"
#: the flags of ``python -m export`` that replace a spec's key: key -> (flag, low, high)
OVERRIDES = {"frames": ("--frames", 1, MAX_FRAMES), "spp": ("--spp", 1, MAX_SPP),
             "reference_spp": ("--reference-spp", 2, MAX_SPP), "size": ("--size", 1, MAX_SIDE)}


def check_override(key: str, value) -> None:
    """A flag's value for the spec's ``key``, checked and named as the flag (``--reference-spp: ...``)."""
    if key not in OVERRIDES:
        raise SpecError(f"{key}: not a key a flag replaces (known: {', '.join(OVERRIDES)})")
    flag, low, high = OVERRIDES[key]
    if key == "size":
        if not isinstance(value, (list, tuple)) or len(value) != 2:
            raise SpecError(f"{flag}: expected W H, found {value!r}")
        for name, side in zip(("W", "H"), value):
            _int(side, f"{flag} {name}", "", low, high)
        return
    _int(value, flag, "", low, high)
    if key == "reference_spp" and value % 2:
        raise SpecError(f"{flag}: expected an even number (two equal halves estimate the reference's noise), "
                        f"found {value}")


@dataclasses.dataclass(frozen=True)
class Spec:
    scene: str
    frames: int = 8
    size: tuple[int, int] = (1280, 720)
    spp: int = 1
    reference_spp: int = 256
    bounces: int = 3
    shadows: bool = True
    jitter: bool = True  # sub-pixel sample positions (false: pixel centres, like the G-buffers)
    seed: int = 0
    camera: dict = dataclasses.field(default_factory=dict)
    objects: dict = dataclasses.field(default_factory=dict)
    lights: dict = dataclasses.field(default_factory=dict)
    #: the file :meth:`load` read (not a field: no key of the JSON); messages name it
    source = None

    @staticmethod
    def load(path: Path, **overrides) -> Spec:
        """The spec in ``path`` with ``overrides`` (None: keep), checked (:class:`SpecError`)."""
        path = Path(path)
        try:
            data = read_json(path, MAX_SPEC_BYTES)
        except JSONInputError as error:
            raise SpecError(str(error)) from None
        if not isinstance(data, dict):
            raise SpecError(f"{path}: expected a JSON object, found {json_kind(data)}")
        Spec.from_dict(data, str(path))  # the spec as written: a flag does not hide a damaged key
        given = {k: v for k, v in overrides.items() if v is not None}
        for key, value in given.items():
            check_override(key, value)
        try:
            spec = Spec.from_dict({**data, **given}, str(path))
        except SpecError as error:  # sound as written: the flags made it so, and the line says which
            flags = " ".join(f"{OVERRIDES[k][0]} {' '.join(map(str, v)) if k == 'size' else v}"
                             for k, v in given.items())
            raise SpecError(f"{error} (with {flags})") from None
        object.__setattr__(spec, "source", str(path))  # frozen; not a field
        return spec

    @staticmethod
    def from_dict(data: dict, source: str = "spec") -> Spec:
        if not isinstance(data, dict):
            raise SpecError(f"{source}: expected an object, found {shown(data)}")
        known = {f.name for f in dataclasses.fields(Spec)}
        unknown = set(data) - known
        if unknown:
            raise SpecError(f"{source}: unknown keys {', '.join(map(shown, sorted(unknown)))} "
                            f"(known: {', '.join(sorted(known))})")
        if "scene" not in data:
            raise SpecError(f"{source}: no \"scene\" (a scene name or .txt path)")
        data = dict(data)
        if "size" in data:
            size = data["size"]
            if not isinstance(size, (list, tuple)) or len(size) != 2:
                raise SpecError(f"{_key_in(source, 'size')}: expected [width, height], found {shown(size)}")
            data["size"] = tuple(size)
        spec = Spec(**data)
        spec.check(source)
        return spec

    def check(self, source: str = "spec") -> None:
        """Raises :class:`SpecError` for anything out of range, before any work."""
        if not isinstance(self.scene, str) or not (self.scene.endswith(".txt") or re.fullmatch(SCENE_NAME, self.scene)):
            raise SpecError(f"{_key_in(source, 'scene')}: expected a scene name (box, scene06) or a .txt scene "
                            f"file, found {shown(self.scene)}")
        _int(self.frames, "frames", source, 1, MAX_FRAMES)
        if not isinstance(self.size, (list, tuple)) or len(self.size) != 2:
            raise SpecError(f"{_key_in(source, 'size')}: expected [width, height], found {shown(self.size)}")
        width = _int(self.size[0], "size[0] (width)", source, 1, MAX_SIDE)
        height = _int(self.size[1], "size[1] (height)", source, 1, MAX_SIDE)
        spp = _int(self.spp, "spp", source, 1, MAX_SPP)
        reference = _int(self.reference_spp, "reference_spp", source, 2, MAX_SPP)
        if reference % 2:
            raise SpecError(f"{_key_in(source, 'reference_spp')}: expected an even number (two equal halves "
                            f"estimate the reference's noise), found {reference}")
        if width * height * spp > MAX_SAMPLES_PER_RENDER:
            raise SpecError(f"{_key_in(source, 'spp')}: {width}x{height} at {spp} spp is more than "
                            f"{MAX_SAMPLES_PER_RENDER} samples in one render")
        _int(self.bounces, "bounces", source, 0, MAX_BOUNCES)
        _bool(self.shadows, "shadows", source)
        _bool(self.jitter, "jitter", source)
        _int(self.seed, "seed", source, 0, 2 ** 31 - 1)
        camera = _keys(self.camera, "camera", source, {"orbit", "dolly", "pan"})
        if "orbit" in camera:
            orbit = _keys(camera["orbit"], "camera.orbit", source, {"center", "degrees"})
            if "degrees" not in orbit:
                raise SpecError(f"{_key_in(source, 'camera.orbit')}: no \"degrees\"")
            _number(orbit["degrees"], "camera.orbit.degrees", source)
            if "center" in orbit:
                _vector(orbit["center"], "camera.orbit.center", source)
        if "dolly" in camera:
            _number(camera["dolly"], "camera.dolly", source)
        if "pan" in camera:
            _vector(camera["pan"], "camera.pan", source)
        if not isinstance(self.objects, dict):
            raise SpecError(f"{_key_in(source, 'objects')}: expected an object, found {shown(self.objects)}")
        for key, move in self.objects.items():
            name = f"objects.{key}"
            if not re.fullmatch(INDEX, str(key)):
                raise SpecError(f"{_key_in(source, name)}: expected an object index (0, 1, ...), found {shown(key)}")
            move = _keys(move, name, source, {"translate", "rotate"})
            if "translate" in move:
                _vector(move["translate"], f"{name}.translate", source)
            if "rotate" in move:
                _check_rotation(move["rotate"], f"{name}.rotate", source)

        self._check_lights(source)

    def _check_lights(self, source: str) -> None:
        if not isinstance(self.lights, dict):
            raise SpecError(f"{_key_in(source, 'lights')}: expected an object, found {shown(self.lights)}")
        for key, change in self.lights.items():
            name = f"lights.{key}"
            if not re.fullmatch(INDEX, str(key)):
                raise SpecError(f"{_key_in(source, name)}: expected a light index (0, 1, ...), found {shown(key)}")
            change = _keys(change, name, source, {"translate", "rotate", "scale", "frames"})
            if not set(change) - {"frames"}:
                raise SpecError(f"{_key_in(source, name)}: changes nothing; give translate, rotate or scale")
            if "translate" in change:
                _vector(change["translate"], f"{name}.translate", source)
            if "rotate" in change:
                _check_rotation(change["rotate"], f"{name}.rotate", source)
            if "scale" in change and _number(change["scale"], f"{name}.scale", source) < 0:
                raise SpecError(f"{_key_in(source, name + '.scale')}: expected a factor >= 0 for the light's "
                                f"colour, found {change['scale']}")
            if "frames" in change:
                frames = change["frames"]
                if not isinstance(frames, (list, tuple)) or len(frames) != 2:
                    raise SpecError(f"{_key_in(source, name + '.frames')}: expected [first, last], "
                                    f"found {shown(frames)}")
                last = self.frames - 1
                first = _int(frames[0], f"{name}.frames[0]", source, 0, last)
                end = _int(frames[1], f"{name}.frames[1]", source, 0, last)
                if end <= first:
                    raise SpecError(f"{_key_in(source, name + '.frames')}: expected a first frame before the "
                                    f"last, found {list(frames)}")

    def check_scene(self, scene: Scene, source: str = "spec") -> None:
        """The object and light indices the spec moves exist in ``scene``, and
        each light's change suits its kind (a point light moves, a directional one turns)."""
        for key in self.objects:
            if int(key) >= len(scene.objects):
                raise SpecError(f"{_key_in(source, f'objects.{key}')}: object {int(key)} does not exist "
                                f"(the scene has {len(scene.objects)}: 0..{len(scene.objects) - 1})")
        for key, change in self.lights.items():
            k = int(key)
            if k >= len(scene.lights):
                have = f"0..{len(scene.lights) - 1}" if scene.lights else "no lights"
                raise SpecError(f"{_key_in(source, f'lights.{key}')}: light {k} does not exist "
                                f"(the scene has {len(scene.lights)}: {have})")
            light = scene.lights[k]
            if "translate" in change and not isinstance(light, PointLight):
                raise SpecError(f"{_key_in(source, f'lights.{key}.translate')}: light {k} is a directional light, "
                                f"which has no position (turn it with \"rotate\")")
            if "rotate" in change and not isinstance(light, DirectionalLight):
                raise SpecError(f"{_key_in(source, f'lights.{key}.rotate')}: light {k} is a point light, "
                                f"which has no direction (move it with \"translate\")")

    def as_json(self) -> dict:
        """The spec as recorded in ``sequence.json`` (and hashed into the seeds):
        without ``lights`` when no light changes, as before lights could."""
        data = dataclasses.asdict(self)
        data["size"] = list(self.size)
        if not data["lights"]:
            del data["lights"]
        return data
