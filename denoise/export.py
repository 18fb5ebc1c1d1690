"""Rendering animated sequences into frame folders, with their ground truth.

    python -m denoise.export SPEC.json... OUT [--frames N] [--size W H] [--spp K]
                             [--reference-spp R] [--batch-spp B] [--whitted] [--data DIR]
                             [--variant V] [--force]
                             [--local | --workers N | --scheduler ADDRESS]

The spec is JSON::

    {
      "scene": "showcase",              # a scene name or .txt path (as render.py finds them)
      "frames": 8, "size": [1280, 720],
      "spp": 1, "reference_spp": 256,   # noisy input, converged ground truth (even: two halves)
      "bounces": 3, "shadows": true,    # path depth beyond direct light; shadow rays
      "jitter": true,                   # sub-pixel positions for the noisy input and the truth
      "seed": 0,                        # another value draws another realisation of the noise
      "camera": {"orbit": {"center": [0, 1, 0], "degrees": 20},   # about the vertical axis
                 "dolly": 1.5,          # along the view direction
                 "pan": [0.5, 0, 0]},   # a translation
      "objects": {"2": {"translate": [0.8, 0, 0],
                        "rotate": {"axis": [0, 1, 0], "degrees": 45}}}   # about its centre
    }

Every motion is linear in time from frame 0 to the last frame. One spec
writes the frame folder ``OUT`` and its ground truth ``OUT_reference``;
several specs (a dataset) write ``OUT/<spec name>`` and
``OUT/<spec name>_reference`` each, and ``OUT/dataset.json`` lists them all.

Per frame the Mitsuba scene is loaded once and every pass rendered from it:
the G-buffers (whitted's AOVs through the pixel centres), the noisy beauty
(Mitsuba's path tracer at ``spp``, or whitted with ``--whitted``) and the
ground truth, which is split into sample batches of ``--batch-spp`` samples,
each with its own seed. The batches form two halves of ``reference_spp / 2``
samples each; ``OUT_reference`` holds their means ``half_a_i.exr`` and
``half_b_i.exr`` and the full reference ``beauty_i.exr`` = (a + b) / 2, so the
reference's own noise is estimated as relMSE(half_a, half_b) / 4.

Seeds come from a hash of the sequence (its spec and settings), the frame, the
pass and the batch, and batches are summed in a fixed order, so a frame's
bytes do not depend on how many workers rendered it or in which order tasks
finished; every render runs on one Dr.Jit thread (whose count would change
the sums' rounding), parallel across processes. The folder records its spec and settings in ``sequence.json``; an
interrupted export resumes with only the missing frames and batches (finished
batches wait in ``OUT_reference/.batches``), and one made with other settings
is refused (``--force`` starts it over).

By default the tasks run on a Dask ``LocalCluster`` with one worker process
per core; ``--scheduler ADDRESS`` runs them on an existing Dask cluster (see
:mod:`denoise.dataset`), ``--local`` in this process without Dask.
"""
from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import math
import os
import re
import shutil
import sys
import time
from collections import OrderedDict
from pathlib import Path
from typing import Callable

if __name__ == "__main__":  # started by a Python without the project's packages: use ./.venv's
    from core.launcher import use_project_python
    use_project_python("python -m denoise.export", "denoise.export")

import numpy as np

from converters import transforms
from converters.model import Scene, Sphere, Triangle, TriangleMesh
from core.entry import ArgumentParser
from core.numbers import ascii_int
from core.errors import SpecError

from .frames import BUFFERS, FrameData, camera_matrices, depth_range, write_frame

#: the layers the G-buffer pass writes (whitted's AOVs at pixel centres)
GBUFFER_AOVS = ("depth", "normal", "position", "id", "albedo")
#: bump when the way frames are rendered changes (seeds, batching, passes)
EXPORT_FORMAT = 2
DEFAULT_BATCH_SPP = 64
# Limits: Mitsuba indexes one render's samples with 32-bit integers
MAX_SIDE = 16384
MAX_SAMPLES_PER_RENDER = 2 ** 31
MAX_FRAMES = 100_000
MAX_SPP = 1 << 20
MAX_BOUNCES = 64


# -- the spec ---------------------------------------------------------------------
def _where(source: str, key: str) -> str:
    return f"{source}: {key}" if source else key


def _int(value, name: str, source: str, low: int, high: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise SpecError(f"{_where(source, name)}: expected an integer, found {value!r}")
    if not low <= value <= high:
        raise SpecError(f"{_where(source, name)}: expected {low}..{high}, found {value}")
    return value


def _number(value, name: str, source: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
            or abs(value) > 1e30:
        raise SpecError(f"{_where(source, name)}: expected a finite number, found {value!r}")
    return float(value)


def _vector(value, name: str, source: str) -> list[float]:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise SpecError(f"{_where(source, name)}: expected [x, y, z], found {value!r}")
    return [_number(v, f"{name}[{k}]", source) for k, v in enumerate(value)]


def _bool(value, name: str, source: str) -> bool:
    if not isinstance(value, bool):
        raise SpecError(f"{_where(source, name)}: expected true or false, found {value!r}")
    return value


def _keys(value, name: str, source: str, known: set[str]) -> dict:
    if not isinstance(value, dict):
        raise SpecError(f"{_where(source, name)}: expected an object, found {value!r}")
    unknown = set(value) - known
    if unknown:
        raise SpecError(f"{_where(source, name)}: unknown keys {', '.join(sorted(unknown))} "
                        f"(known: {', '.join(sorted(known))})")
    return value


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

    @staticmethod
    def load(path: Path, **overrides) -> "Spec":
        """The spec in ``path`` with ``overrides`` (None: keep), checked (:class:`SpecError`)."""
        path = Path(path)
        try:
            data = json.loads(path.read_text())
        except json.JSONDecodeError as error:
            raise SpecError(f"{path}:{error.lineno}:{error.colno}: {error.msg}") from None
        if not isinstance(data, dict):
            raise SpecError(f"{path}: expected a JSON object, found {type(data).__name__}")
        data.update({k: v for k, v in overrides.items() if v is not None})
        return Spec.from_dict(data, str(path))

    @staticmethod
    def from_dict(data: dict, source: str = "spec") -> "Spec":
        if not isinstance(data, dict):
            raise SpecError(f"{source}: expected an object, found {data!r}")
        known = {f.name for f in dataclasses.fields(Spec)}
        unknown = set(data) - known
        if unknown:
            raise SpecError(f"{source}: unknown keys {', '.join(sorted(unknown))} (known: {', '.join(sorted(known))})")
        if "scene" not in data:
            raise SpecError(f"{source}: no \"scene\" (a scene name or .txt path)")
        data = dict(data)
        if "size" in data:
            size = data["size"]
            if not isinstance(size, (list, tuple)) or len(size) != 2:
                raise SpecError(f"{_where(source, 'size')}: expected [width, height], found {size!r}")
            data["size"] = tuple(size)
        spec = Spec(**data)
        spec.check(source)
        return spec

    def check(self, source: str = "spec") -> None:
        """Raises :class:`SpecError` for anything out of range, before any work."""
        if not isinstance(self.scene, str) or not self.scene:
            raise SpecError(f"{_where(source, 'scene')}: expected a scene name or path, found {self.scene!r}")
        _int(self.frames, "frames", source, 1, MAX_FRAMES)
        if not isinstance(self.size, (list, tuple)) or len(self.size) != 2:
            raise SpecError(f"{_where(source, 'size')}: expected [width, height], found {self.size!r}")
        width = _int(self.size[0], "size[0] (width)", source, 1, MAX_SIDE)
        height = _int(self.size[1], "size[1] (height)", source, 1, MAX_SIDE)
        spp = _int(self.spp, "spp", source, 1, MAX_SPP)
        reference = _int(self.reference_spp, "reference_spp", source, 2, MAX_SPP)
        if reference % 2:
            raise SpecError(f"{_where(source, 'reference_spp')}: expected an even number (two equal halves "
                            f"estimate the reference's noise), found {reference}")
        if width * height * spp > MAX_SAMPLES_PER_RENDER:
            raise SpecError(f"{_where(source, 'spp')}: {width}x{height} at {spp} spp is more than "
                            f"{MAX_SAMPLES_PER_RENDER} samples in one render")
        _int(self.bounces, "bounces", source, 0, MAX_BOUNCES)
        _bool(self.shadows, "shadows", source)
        _bool(self.jitter, "jitter", source)
        _int(self.seed, "seed", source, 0, 2 ** 31 - 1)
        camera = _keys(self.camera, "camera", source, {"orbit", "dolly", "pan"})
        if "orbit" in camera:
            orbit = _keys(camera["orbit"], "camera.orbit", source, {"center", "degrees"})
            if "degrees" not in orbit:
                raise SpecError(f"{_where(source, 'camera.orbit')}: no \"degrees\"")
            _number(orbit["degrees"], "camera.orbit.degrees", source)
            if "center" in orbit:
                _vector(orbit["center"], "camera.orbit.center", source)
        if "dolly" in camera:
            _number(camera["dolly"], "camera.dolly", source)
        if "pan" in camera:
            _vector(camera["pan"], "camera.pan", source)
        if not isinstance(self.objects, dict):
            raise SpecError(f"{_where(source, 'objects')}: expected an object, found {self.objects!r}")
        for key, move in self.objects.items():
            name = f"objects.{key}"
            if not re.fullmatch(r"\d{1,9}", str(key)):
                raise SpecError(f"{_where(source, name)}: expected an object index (0, 1, ...), found {key!r}")
            move = _keys(move, name, source, {"translate", "rotate"})
            if "translate" in move:
                _vector(move["translate"], f"{name}.translate", source)
            if "rotate" in move:
                rotate = _keys(move["rotate"], f"{name}.rotate", source, {"axis", "degrees"})
                if "axis" not in rotate or "degrees" not in rotate:
                    raise SpecError(f"{_where(source, name + '.rotate')}: expected \"axis\" and \"degrees\"")
                if not any(_vector(rotate["axis"], f"{name}.rotate.axis", source)):
                    raise SpecError(f"{_where(source, name + '.rotate.axis')}: expected a non-zero axis")
                _number(rotate["degrees"], f"{name}.rotate.degrees", source)

    def check_scene(self, scene: Scene, source: str = "spec") -> None:
        """The object indices the spec moves exist in ``scene``."""
        for key in self.objects:
            if int(key) >= len(scene.objects):
                raise SpecError(f"{_where(source, f'objects.{key}')}: object {int(key)} does not exist "
                                f"(the scene has {len(scene.objects)}: 0..{len(scene.objects) - 1})")

    def as_json(self) -> dict:
        data = dataclasses.asdict(self)
        data["size"] = list(self.size)
        return data


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
    return dataclasses.replace(scene, camera=camera, objects=objects)


# -- settings, batches, seeds -------------------------------------------------------
def versions() -> dict:
    from importlib.metadata import version

    return {name: version(name) for name in ("mitsuba", "drjit", "numpy", "OpenEXR")}


@dataclasses.dataclass(frozen=True)
class Sequence:
    """One sequence of a dataset: what to render and where. Everything in
    :meth:`settings` decides the bytes; it goes into ``sequence.json``."""
    name: str
    spec: Spec
    scene_path: str  # resolved, absolute
    target: str  # the frame folder
    batch_spp: int = DEFAULT_BATCH_SPP
    whitted: bool = False
    variant: str = "llvm_ad_rgb"

    @property
    def reference(self) -> Path:
        return reference_folder(Path(self.target))

    def settings(self) -> dict:
        width, height = self.spec.size
        return {"format": EXPORT_FORMAT, "spec": self.spec.as_json(), "scene_file": self.scene_path,
                "size": [width, height], "spp": self.spec.spp, "reference_spp": self.spec.reference_spp,
                "batch_spp": self.batch_spp, "batches": [spp for _, spp in self.batches()],
                "noisy_integrator": "whitted" if self.whitted else "path", "gbuffer": "whitted AOVs at pixel centres",
                "variant": self.variant, "versions": versions(), "render_threads": RENDER_THREADS,
                "seeds": "sha256(key/frame/pass/batch) -> uint31; key = sha256 of this file's other settings",
                "scene_sha256": hashlib.sha256(Path(self.scene_path).read_bytes()).hexdigest()}

    @property
    def key(self) -> str:
        """A hash of the sequence's settings: the root of its seeds."""
        settings = self.settings()
        settings.pop("versions")
        settings.pop("seeds")
        settings.pop("scene_file")  # the same scene moved elsewhere renders the same noise
        settings.pop("scene_sha256")  # (recorded after the first folders were made: not part of their seeds)
        return hashlib.sha256(json.dumps(settings, sort_keys=True).encode()).hexdigest()

    def batches(self) -> list[tuple[str, int]]:
        """(half, spp) of each reference batch: half "a" first, then "b"; each half
        is ``reference_spp / 2`` samples in batches of ``batch_spp`` (the last smaller)."""
        half = self.spec.reference_spp // 2
        sizes = [self.batch_spp] * (half // self.batch_spp) + ([half % self.batch_spp] if half % self.batch_spp else [])
        return [("a", s) for s in sizes] + [("b", s) for s in sizes]


def seed(key: str, frame: int, stream: str, batch: int = 0) -> int:
    """A sampler seed from the sequence key, the frame, the pass and the batch."""
    digest = hashlib.sha256(f"{key}/{frame}/{stream}/{batch}".encode()).digest()
    return int.from_bytes(digest[:4], "little") & 0x7FFFFFFF


def reference_folder(target: Path) -> Path:
    target = Path(target)
    return target.parent / f"{target.name}_reference"


def batch_path(sequence: Sequence, frame: int, batch: int) -> Path:
    return sequence.reference / ".batches" / f"{frame}" / f"batch_{batch}.npy"


def frame_done(target: Path, index: int) -> bool:
    """The frame's buffers are written (not its reference)."""
    files = [target / f"{name}_{index}.exr" for name in BUFFERS] + [target / f"matrix_{index}.mat",
                                                                   target / f"albedo_{index}.exr"]
    return all(f.exists() for f in files)


REFERENCE_FILES = ("beauty", "half_a", "half_b")


def reference_done(target: Path, index: int) -> bool:
    return all((reference_folder(target) / f"{name}_{index}.exr").exists() for name in REFERENCE_FILES)


# -- the tasks (run on Dask workers or in this process) ------------------------------
@dataclasses.dataclass(frozen=True)
class Task:
    """One unit of work: ``kind`` "frame" (G-buffers and noisy beauty) or
    "batch" (``spp`` reference samples with ``seed``)."""
    sequence: Sequence
    frame: int
    kind: str
    batch: int = 0
    spp: int = 0
    seed: int = 0
    threads: int | None = None  # Dr.Jit threads in the process that runs it

    @property
    def name(self) -> str:
        tail = "frame" if self.kind == "frame" else f"batch{self.batch}"
        return f"{self.sequence.name}-{self.sequence.key[:8]}-{self.frame}-{tail}"


# The loaded Mitsuba scenes of the last frames this process rendered: a frame's
# batches that land on one worker load its scene once.
_LOADED: OrderedDict = OrderedDict()
_COURSE_SCENES: dict = {}


def _prepare(variant: str, threads: int | None) -> None:
    import drjit as dr
    import mitsuba as mi

    if mi.variant() != variant:
        from renderer.variants import set_variant

        set_variant(variant, quiet=True)
    if threads and dr.thread_count() != threads:
        dr.set_thread_count(threads)


def _course_scene(path: str) -> Scene:
    from converters.course_scene import load_scene

    stamp = os.stat(path).st_mtime_ns
    if _COURSE_SCENES.get(path, (None,))[0] != stamp:
        _COURSE_SCENES[path] = (stamp, load_scene(Path(path)))
    return _COURSE_SCENES[path][1]


def loaded_frame(sequence: Sequence, frame: int):
    """(Mitsuba scene, noisy-pass integrator, animated course scene) of one
    frame, loaded once: the G-buffer integrator (whitted with AOVs) is the
    scene's own, the sensor ``sensor`` shoots through pixel centres and
    ``sensor_jittered`` at sub-pixel positions."""
    import mitsuba as mi

    from converters.description import RenderOptions, scene_dict
    from converters.scene_variants import with_path_tracer, without_ambient
    from converters.to_mitsuba import load_scene_dict

    cache_key = (sequence.key, sequence.scene_path, frame)
    if cache_key in _LOADED:
        _LOADED.move_to_end(cache_key)
        return _LOADED[cache_key]
    spec = sequence.spec
    width, height = spec.size
    scene = animate(_course_scene(sequence.scene_path), spec, frame / max(spec.frames - 1, 1))
    description = scene_dict(scene, RenderOptions(width=width, height=height, aovs=GBUFFER_AOVS))
    description["sensor_jittered"] = dict(description["sensor"], pixel_centers=False)
    noisy = scene_dict(scene, RenderOptions(width=width, height=height, jitter=spec.jitter, bounces=spec.bounces,
                                            shadows=spec.shadows))
    if not sequence.whitted:
        noisy = without_ambient(with_path_tracer(noisy))
    integrator = mi.load_dict(noisy["integrator"])
    loaded = (load_scene_dict(description), integrator, scene)
    _LOADED[cache_key] = loaded
    while len(_LOADED) > 2:
        _LOADED.popitem(last=False)
    return loaded


def _sensor(mi_scene, jitter: bool):
    wanted = "sensor_jittered" if jitter else "sensor"
    return next(s for s in mi_scene.sensors() if s.id() == wanted)


def _where_run() -> str:
    try:
        from distributed import get_worker

        return get_worker().address
    except (ImportError, ValueError):
        return "local"


#: Dr.Jit threads per render. Its film sums a pixel's samples in an order that
#: follows the thread count (1, 2, 4, 8, 16, 48, 63 spp all gave other bytes on
#: 1 and 2 threads at 160x120 or 320x180 with Dr.Jit 1.5 / Mitsuba 3.9.1), so
#: every pass renders on one thread and parallelism comes from processes: the
#: LocalCluster runs one worker per core.
RENDER_THREADS = 1


def run_task(task: Task) -> tuple[object, dict]:
    """Renders one task on :data:`RENDER_THREADS` Dr.Jit threads (the
    process's count restored after); returns (its result, its timing)."""
    import drjit as dr

    _prepare(task.sequence.variant, task.threads)
    threads = dr.thread_count()
    pinned = RENDER_THREADS is not None and threads != RENDER_THREADS
    if pinned:
        dr.set_thread_count(RENDER_THREADS)
    try:
        return _render_task(dataclasses.replace(task, threads=None))  # keeps the pinned count
    finally:
        if pinned:
            dr.set_thread_count(threads)


def _render_task(task: Task) -> tuple[object, dict]:
    """Renders one task; returns (its result, its timing)."""
    import mitsuba as mi

    from renderer.job import split_layers

    start = time.perf_counter()
    sequence = task.sequence
    _prepare(sequence.variant, task.threads)
    mi_scene, integrator, scene = loaded_frame(sequence, task.frame)
    loaded = time.perf_counter()
    jittered = _sensor(mi_scene, sequence.spec.jitter)
    if task.kind == "frame":
        width, height = sequence.spec.size
        image = np.array(mi.render(mi_scene, sensor=_sensor(mi_scene, False), spp=1, seed=0), np.float32)
        layers = split_layers(image, GBUFFER_AOVS)
        beauty = np.array(mi.render(mi_scene, integrator=integrator, sensor=jittered, spp=task.spp,
                                    seed=task.seed), np.float32)[..., :3]
        world_to_camera, world_to_screen = camera_matrices(scene.camera, width, height, *depth_range(
            scene.camera, layers["position"][layers["id"] >= 0]))
        result = FrameData(beauty, layers["normal"], layers["position"], layers["depth"],
                           layers["id"].astype(np.int32), [o.to_world for o in scene.objects], world_to_camera,
                           world_to_screen)
        result.albedo = layers["albedo"]  # not in the course's layout; OIDN uses it
    elif task.kind == "batch":
        result = np.array(mi.render(mi_scene, integrator=integrator, sensor=jittered, spp=task.spp,
                                    seed=task.seed), np.float32)[..., :3]
    else:
        raise ValueError(f"unknown task kind {task.kind!r}")
    end = time.perf_counter()
    return result, {"kind": task.kind, "batch": task.batch, "seconds": round(end - start, 4),
                    "load_s": round(loaded - start, 4), "worker": _where_run()}


# -- planning, writing results, resuming -----------------------------------------------
def _json_bytes(data) -> bytes:
    return (json.dumps(data, indent=2, sort_keys=True) + "\n").encode()


def write_json(path: Path, data) -> None:
    from imaging.image_io import atomic_path

    with atomic_path(path, ".json") as tmp:
        tmp.write_bytes(_json_bytes(data))


def _our_files(sequence: Sequence) -> list[Path]:
    target, reference = Path(sequence.target), sequence.reference
    names = "|".join(BUFFERS + ("albedo",))
    found = []
    if target.is_dir():
        found += [p for p in target.iterdir() if re.fullmatch(rf"(?:{names})_\d+\.exr|matrix_\d+\.mat", p.name)]
    if reference.is_dir():
        found += [p for p in reference.iterdir() if re.fullmatch(r"(?:beauty|half_a|half_b)_\d+\.exr", p.name)]
    return found


def start_over(sequence: Sequence) -> None:
    """``--force``: removes what an earlier export wrote (only files we name)."""
    for path in _our_files(sequence):
        path.unlink()
    shutil.rmtree(sequence.reference / ".batches", ignore_errors=True)
    (Path(sequence.target) / "sequence.json").unlink(missing_ok=True)


def _differences(old: dict, new: dict, prefix: str = "") -> list[str]:
    found = []
    for key in sorted(set(old) | set(new)):
        a, b = old.get(key), new.get(key)
        if isinstance(a, dict) and isinstance(b, dict):
            found += _differences(a, b, f"{prefix}{key}.")
        elif a != b:
            found.append(f"{prefix}{key} {json.dumps(a)} -> {json.dumps(b)}")
    return found


def _comparable(settings: dict, other: dict) -> dict:
    """``settings`` as compared with ``other``: without the scene's path (a
    checkout elsewhere, e.g. another git worktree, holds the same scene under
    another path) but with its content's hash where both record one."""
    settings = {k: v for k, v in settings.items() if k != "scene_file"}
    if "scene_sha256" not in other:
        settings.pop("scene_sha256", None)
    return settings


def claim_folder(sequence: Sequence, force: bool = False) -> None:
    """Checks that ``sequence`` may write into its folders (the same settings
    as before, or a fresh folder) and records its settings there."""
    target = Path(sequence.target)
    record = target / "sequence.json"
    if force:
        start_over(sequence)
    settings = sequence.settings()
    if record.exists():
        try:
            old = json.loads(record.read_text())
        except json.JSONDecodeError:
            old = {"unreadable": True}
        if _comparable(old, settings) != _comparable(settings, old):
            changed = _differences(_comparable(old, settings), _comparable(settings, old))
            raise SpecError(f"{target}: made with other settings ({'; '.join(changed[:4])}"
                            f"{'; ...' if len(changed) > 4 else ''}); use --force to start over, or another folder")
    elif _our_files(sequence):
        raise SpecError(f"{target}: holds frames without a sequence.json (made by an older export or by hand); "
                        f"use --force to start over, or another folder")
    target.mkdir(parents=True, exist_ok=True)
    if not record.exists():
        write_json(record, settings)


def plan(sequence: Sequence, threads: int | None = None) -> list[Task]:
    """The tasks still to do for ``sequence``, frame by frame."""
    target = Path(sequence.target)
    tasks = []
    key = sequence.key
    for frame in range(sequence.spec.frames):
        if not frame_done(target, frame):
            tasks.append(Task(sequence, frame, "frame", spp=sequence.spec.spp, seed=seed(key, frame, "noisy"),
                              threads=threads))
        if reference_done(target, frame):
            continue
        for batch, (_, spp) in enumerate(sequence.batches()):
            if not batch_path(sequence, frame, batch).exists():
                tasks.append(Task(sequence, frame, "batch", batch, spp, seed(key, frame, "reference", batch), threads))
    return tasks


def save_batch(path: Path, image: np.ndarray) -> None:
    from imaging.image_io import atomic_path

    with atomic_path(path, ".npy") as tmp:
        with open(tmp, "wb") as file:
            np.save(file, np.ascontiguousarray(image, np.float32))


def assemble_reference(sequence: Sequence, frame: int) -> bool:
    """Sums a frame's batches (all present) into its halves and reference, in
    batch order; removes the batches. False when a batch is still missing."""
    from imaging.image_io import write_exr

    paths = [batch_path(sequence, frame, b) for b in range(len(sequence.batches()))]
    if not all(p.exists() for p in paths):
        return False
    half_spp = sequence.spec.reference_spp // 2
    halves = {}
    for (half, spp), path in zip(sequence.batches(), paths):
        image = np.load(path).astype(np.float64) * (spp / half_spp)
        halves[half] = image if half not in halves else halves[half] + image
    folder = sequence.reference
    write_exr(folder / f"half_a_{frame}.exr", {"": halves["a"].astype(np.float32)})
    write_exr(folder / f"half_b_{frame}.exr", {"": halves["b"].astype(np.float32)})
    write_exr(folder / f"beauty_{frame}.exr", {"": ((halves["a"] + halves["b"]) / 2).astype(np.float32)})
    shutil.rmtree(paths[0].parent, ignore_errors=True)
    try:
        paths[0].parent.parent.rmdir()  # .batches, once no frame waits
    except OSError:
        pass
    return True


class Recorder:
    """Writes task results as they come (atomically) and keeps the manifest."""

    def __init__(self, sequences: list[Sequence], manifest: Path | None):
        self.sequences = {s.name: s for s in sequences}
        self.manifest = manifest
        self.run_id = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
        self.timings: dict[tuple[str, int], list[dict]] = {}
        self.rendered: dict[str, set[int]] = {s.name: set() for s in sequences}
        self.record_s: list[float] = []  # this process's time writing each result
        self.complete = {(s.name, i) for s in sequences for i in range(s.spec.frames)
                         if frame_done(Path(s.target), i) and reference_done(Path(s.target), i)}
        if manifest is not None and manifest.exists():  # keep the timings of an interrupted run
            try:
                old = json.loads(manifest.read_text())
                for entry in old.get("sequences", []):
                    if entry.get("name") in self.sequences and entry.get("key") == self.sequences[entry["name"]].key:
                        for frame in entry.get("frames", []):
                            self.timings[(entry["name"], frame["index"])] = frame.get("tasks", [])
            except (json.JSONDecodeError, KeyError, TypeError, AttributeError):
                pass

    def record(self, task: Task, result, timing: dict) -> None:
        start = time.perf_counter()
        self._record(task, result, timing)
        self.record_s.append(time.perf_counter() - start)

    def _record(self, task: Task, result, timing: dict) -> None:
        sequence = task.sequence
        timing = dict(timing, run=self.run_id)
        self.timings.setdefault((sequence.name, task.frame), []).append(timing)
        self.rendered[sequence.name].add(task.frame)
        target = Path(sequence.target)
        if task.kind == "frame":
            write_frame(target, task.frame, result)
        else:
            save_batch(batch_path(sequence, task.frame, task.batch), result)
            assemble_reference(sequence, task.frame)
        if frame_done(target, task.frame) and reference_done(target, task.frame):
            self.complete.add((sequence.name, task.frame))

    def frames_done(self) -> int:
        return len(self.complete)

    def write(self, extra: dict) -> None:
        if self.manifest is None:
            return
        entries = []
        for sequence in self.sequences.values():
            frames = []
            for i in range(sequence.spec.frames):
                target = Path(sequence.target)
                done = frame_done(target, i) and reference_done(target, i)
                status = ("rendered" if i in self.rendered[sequence.name] else "resumed") if done else "missing"
                batches = sum(batch_path(sequence, i, b).exists() for b in range(len(sequence.batches())))
                frames.append({"index": i, "status": status, "noisy_seed": seed(sequence.key, i, "noisy"),
                               "batches_waiting": batches, "tasks": self.timings.get((sequence.name, i), [])})
            entries.append({"name": sequence.name, "key": sequence.key, "folder": sequence.target,
                            "reference": str(sequence.reference), "settings": sequence.settings(), "frames": frames})
        if self.record_s:
            extra = dict(extra, writing_s_per_task=round(float(np.median(self.record_s)), 4))
        write_json(self.manifest, dict(extra, format=EXPORT_FORMAT, sequences=entries))


def progress_bar(total: int, frames: int):
    """tqdm over tasks, on stderr only when it is a terminal."""
    from tqdm import tqdm

    return tqdm(total=total, desc="frames+batches", unit="task", file=sys.stderr,
                disable=not sys.stderr.isatty(), postfix={"frames": f"0/{frames}"}, leave=False)


def run_local(tasks: list[Task], recorder: Recorder, after_task: Callable[[Task], None] | None = None,
              total_frames: int = 0) -> None:
    """Runs ``tasks`` one after the other in this process (no Dask)."""
    with progress_bar(len(tasks), total_frames) as bar:
        for task in tasks:
            result, timing = run_task(task)
            recorder.record(task, result, timing)
            bar.update()
            bar.set_postfix(frames=f"{recorder.frames_done()}/{total_frames}", refresh=False)
            if after_task:
                after_task(task)


# -- the whole export -------------------------------------------------------------------
def sequences_for(specs: list[tuple[str, Spec]], out: Path, data: Path | None = None, whitted: bool = False,
                  batch_spp: int = DEFAULT_BATCH_SPP, variant: str | None = None) -> list[Sequence]:
    """One :class:`Sequence` per (name, spec); one spec writes ``out`` itself,
    several write ``out/<name>``. Scenes are loaded and checked here, before any work."""
    import mitsuba as mi

    from course import data_dir, resolve_scene

    if batch_spp < 1 or batch_spp > MAX_SPP:
        raise SpecError(f"--batch-spp: expected 1..{MAX_SPP}, found {batch_spp}")
    names = [name for name, _ in specs]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise SpecError(f"two specs named {', '.join(twice)} would share one folder; rename one")
    result = []
    for name, spec in specs:
        spec.check(name)
        width, height = spec.size
        if width * height * min(batch_spp, spec.reference_spp // 2) > MAX_SAMPLES_PER_RENDER:
            raise SpecError(f"{name}: {width}x{height} at {batch_spp} spp per batch is more than "
                            f"{MAX_SAMPLES_PER_RENDER} samples in one render; lower --batch-spp")
        path = resolve_scene(spec.scene, data_dir(data)).resolve()
        spec.check_scene(_course_scene(str(path)), name)
        target = out if len(specs) == 1 else out / name
        result.append(Sequence(name, spec, str(path), str(target), batch_spp, whitted, variant or mi.variant()))
    return result


def export_sequences(sequences: list[Sequence], force: bool = False, scheduler: str | None = None,
                     workers: int | None = None, local: bool = False, manifest: Path | None = None,
                     after_task: Callable[[Task], None] | None = None, client=None,
                     threads: int | None = None) -> dict[str, list[int]]:
    """Renders what is missing of ``sequences`` (in this process with ``local``,
    else on Dask: ``client``, a scheduler address or a new LocalCluster of
    ``workers``); returns the indices of the frames that had work done, per
    sequence name. ``threads``: Dr.Jit threads per process that runs tasks."""
    if local or client is not None:
        return _export(sequences, force, manifest, after_task, client, threads)
    from .dataset import dask_client

    with dask_client(scheduler, workers) as (client, threads):
        return _export(sequences, force, manifest, after_task, client, threads, scheduler or "LocalCluster")


def _export(sequences: list[Sequence], force: bool, manifest: Path | None, after_task, client, threads,
            scheduler: str | None = None) -> dict[str, list[int]]:
    for sequence in sequences:
        claim_folder(sequence, force)
    recorder = Recorder(sequences, manifest)
    frames = sum(s.spec.frames for s in sequences)
    tasks = [t for s in sequences for t in plan(s, threads)]
    extra: dict = {"started": recorder.run_id, "tasks": len(tasks), "drjit_threads": threads}
    start = time.perf_counter()
    try:
        if client is None:
            extra.update(runner="local")
            run_local(tasks, recorder, after_task, frames)
        else:
            from .dataset import describe, run_futures

            extra.update(describe(client, scheduler))
            run_futures(client, tasks, recorder, after_task, frames)
    finally:
        extra["wall_s"] = round(time.perf_counter() - start, 3)
        recorder.write(extra)
    return {name: sorted(frames) for name, frames in recorder.rendered.items()}


def export(spec: Spec, target: Path, data: Path | None = None, whitted: bool = False, force: bool = False,
           batch_spp: int = DEFAULT_BATCH_SPP, **where) -> list[int]:
    """Renders the missing frames of one sequence into ``target`` in this
    process (``where``: ``scheduler=``/``workers=`` for Dask); returns their indices."""
    where.setdefault("local", not where.get("scheduler") and not where.get("workers"))
    target = Path(target)
    sequences = sequences_for([(target.name, spec)], target, data, whitted, batch_spp)
    done = export_sequences(sequences, force, manifest=target / "dataset.json", **where)
    return done[target.name]


def _parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(prog="python -m denoise.export", description=__doc__.split("\n\n")[0])
    parser.add_argument("paths", type=Path, nargs="+", metavar="SPEC.json... OUT",
                        help="one or more specs, then the output folder")
    parser.add_argument("--frames", type=ascii_int)
    parser.add_argument("--size", type=ascii_int, nargs=2, metavar=("W", "H"))
    parser.add_argument("--spp", type=ascii_int)
    parser.add_argument("--reference-spp", type=ascii_int)
    parser.add_argument("--batch-spp", type=ascii_int, default=DEFAULT_BATCH_SPP,
                        help=f"ground-truth samples per task (default {DEFAULT_BATCH_SPP})")
    parser.add_argument("--whitted", action="store_true", help="noisy beauty from whitted (jittered), not path")
    parser.add_argument("--data", type=Path, help="course data folder for course scene names")
    parser.add_argument("--variant")
    parser.add_argument("--force", action="store_true", help="start over in folders made with other settings")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--scheduler", metavar="ADDRESS", help="a running Dask scheduler (tcp://host:8786)")
    where.add_argument("--workers", type=ascii_int, help="local Dask worker processes (default: one per core)")
    where.add_argument("--local", action="store_true", help="render in this process, without Dask")
    return parser


def _main(argv: list[str] | None) -> int:
    from core.errors import UsageError
    from renderer.variants import set_variant

    args = _parser().parse_args(argv)
    if len(args.paths) < 2:
        raise UsageError("expected one or more SPEC.json files, then the output folder")
    *spec_paths, out = args.paths
    if args.workers is not None and not 1 <= args.workers <= 1024:
        raise UsageError(f"--workers: expected 1..1024, found {args.workers}")
    overrides = dict(frames=args.frames, size=tuple(args.size) if args.size else None, spp=args.spp,
                     reference_spp=args.reference_spp)
    specs = [(path.stem, Spec.load(path, **overrides)) for path in spec_paths]  # all checked before any work
    variant = set_variant(args.variant, quiet=True)
    sequences = sequences_for(specs, out, args.data, args.whitted, args.batch_spp, variant)
    manifest = out / "dataset.json"
    done = export_sequences(sequences, args.force, args.scheduler, args.workers, args.local, manifest)
    for sequence in sequences:
        print(f"{len(done[sequence.name])} frames rendered into {sequence.target} "
              f"(ground truth in {sequence.reference})")
    print(f"manifest: {manifest}")
    return 0


def main(argv: list[str] | None = None) -> int:
    from core.entry import run

    return run("python -m denoise.export", lambda: _main(argv))


if __name__ == "__main__":
    sys.exit(main())
