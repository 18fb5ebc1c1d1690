"""The work of one task, on a Dask worker or in this process: rendering a
frame's G-buffers and noisy beauty, or one batch of its ground truth.

A process keeps the loaded Mitsuba scenes of the last frames it rendered, so
that a frame's batches that land on one worker load its scene once.
"""
from __future__ import annotations

import dataclasses
import os
import sys
import time
from collections import OrderedDict
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

from converters.course_scene import load_scene
from converters.description import RenderOptions, scene_dict
from converters.model import Scene
from converters.scene_variants import with_path_tracer, without_ambient
from converters.to_mitsuba import load_scene_dict
from core.entry import hold_signals
from renderer.job import split_layers
from renderer.variants import set_variant

from .animation import animate
from .frames import FrameData, camera_matrices, depth_range
from .sequence import MAX_SPP_PER_RENDER, RENDER_THREADS, Sequence, part_seed

#: the layers the G-buffer pass writes (whitted's AOVs at pixel centres)
GBUFFER_AOVS = ("depth", "normal", "position", "id", "albedo")


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


# The loaded Mitsuba scenes of the last frames this process rendered, by
# variant: a frame's batches that land on one worker load its scene once.
_LOADED: OrderedDict = OrderedDict()
_COURSE_SCENES: dict = {}


def forget_loaded_scenes() -> None:
    """Drops the loaded scenes: they hold Dr.Jit instances, which
    ``dr.detail.clear_registry()`` invalidates (they would then render black)."""
    _LOADED.clear()


def prepare_process(variant: str, threads: int | None) -> None:
    """Sets this process's Mitsuba variant and Dr.Jit thread count (None: keep)
    for the tasks it runs (a Dask worker's start-up, or this process's)."""
    if mi.variant() != variant:
        set_variant(variant, quiet=True)
    # Mitsuba's own warnings go to stdout; a render that Ctrl-C cancels says "winding down" there
    mi.set_log_level(mi.LogLevel.Error)
    if threads and dr.thread_count() != threads:
        dr.set_thread_count(threads)


def course_scene(path: str) -> Scene:
    """The course scene in ``path``, parsed once per version of the file."""
    stamp = os.stat(path).st_mtime_ns
    if _COURSE_SCENES.get(path, (None,))[0] != stamp:
        _COURSE_SCENES[path] = (stamp, load_scene(Path(path)))
    return _COURSE_SCENES[path][1]


def loaded_frame(sequence: Sequence, frame: int):
    """(Mitsuba scene, noisy-pass integrator, animated course scene) of one
    frame, loaded once: the G-buffer integrator (whitted with AOVs) is the
    scene's own, the sensor ``sensor`` shoots through pixel centres and
    ``sensor_jittered`` at sub-pixel positions."""
    cache_key = (mi.variant(), sequence.key, sequence.scene_path, frame)
    if cache_key in _LOADED:
        _LOADED.move_to_end(cache_key)
        return _LOADED[cache_key]
    spec = sequence.spec
    width, height = spec.size
    scene = animate(course_scene(sequence.scene_path), spec, frame / max(spec.frames - 1, 1))
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


def render_held(mi_scene, integrator, sensor, spp: int, seed: int) -> np.ndarray:
    """One ``mi.render`` (``integrator`` None: the scene's) as an (H, W, C)
    float32 array. Ctrl-C makes Mitsuba cancel a render and return what it
    has: the signal is held until the render is back and raised then, before
    that image can be used."""
    with hold_signals():
        image = mi.render(mi_scene, integrator=integrator, sensor=sensor, spp=spp, seed=seed)
    return np.array(image, np.float32)


def render_mean(mi_scene, integrator, sensor, spp: int, seed: int) -> np.ndarray:
    """The (H, W, 3) mean of ``spp`` samples per pixel. Mitsuba's film sums
    a pixel's samples in float32, whose rounding grows with their count, so
    a render accumulates at most :data:`MAX_SPP_PER_RENDER` samples: more are
    split into parts of that many (the first seeded ``seed``, part k
    ``part_seed(seed, k)``), whose means are summed in float64."""
    if spp <= MAX_SPP_PER_RENDER:
        return render_held(mi_scene, integrator, sensor, spp, seed)[..., :3]
    total = None
    for part, first in enumerate(range(0, spp, MAX_SPP_PER_RENDER)):
        count = min(MAX_SPP_PER_RENDER, spp - first)
        image = render_held(mi_scene, integrator, sensor, count, seed if part == 0 else part_seed(seed, part))
        image = image[..., :3].astype(np.float64) * count
        total = image if total is None else total + image
    return (total / spp).astype(np.float32)


def worker_address() -> str:
    """The Dask worker running this task, or "local"."""
    # looked up where it is used: Dask is not installed or loaded for local exports
    distributed = sys.modules.get("distributed")
    if distributed is None:
        return "local"
    try:
        return distributed.get_worker().address
    except ValueError:
        return "local"


def run_task(task: Task) -> tuple[object, dict]:
    """Renders one task on :data:`RENDER_THREADS` Dr.Jit threads (the
    process's count restored after); returns (its result, its timing)."""
    prepare_process(task.sequence.variant, task.threads)
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
    start = time.perf_counter()
    sequence = task.sequence
    prepare_process(sequence.variant, task.threads)
    mi_scene, integrator, scene = loaded_frame(sequence, task.frame)
    loaded = time.perf_counter()
    jittered = _sensor(mi_scene, sequence.spec.jitter)
    if task.kind == "frame":
        width, height = sequence.spec.size
        image = render_held(mi_scene, None, _sensor(mi_scene, False), 1, 0)
        layers = split_layers(image, GBUFFER_AOVS)
        beauty = render_mean(mi_scene, integrator, jittered, task.spp, task.seed)
        world_to_camera, world_to_screen = camera_matrices(scene.camera, width, height, *depth_range(
            scene.camera, layers["position"][layers["id"] >= 0]))
        result = FrameData(beauty, layers["normal"], layers["position"], layers["depth"],
                           layers["id"].astype(np.int32), [o.to_world for o in scene.objects], world_to_camera,
                           world_to_screen)
        result.albedo = layers["albedo"]  # not in the course's layout; OIDN uses it
    elif task.kind == "batch":
        result = render_mean(mi_scene, integrator, jittered, task.spp, task.seed)
    else:
        raise ValueError(f"unknown task kind {task.kind!r}")
    end = time.perf_counter()
    return result, {"kind": task.kind, "batch": task.batch, "seconds": round(end - start, 4),
                    "load_s": round(loaded - start, 4), "worker": worker_address()}
