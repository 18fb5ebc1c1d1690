"""Rendering in horizontal bands across processes, for the scalar variants.

A Python integrator in a scalar variant makes one Python call per ray, and
the GIL keeps those on one core however many threads Mitsuba starts. Bands
of rows rendered by one process per core use them all: each worker loads the
scene once, then renders bands through a cropped copy of the sensor.

A scalar ``mi.render`` cannot be interrupted (Python sees a signal only when
it returns), so every render of more than :data:`MIN_WORK` ray casts runs in
workers, even on one core: the main process only waits for bands, Ctrl-C
and SIGTERM reach it there, and leaving the pool terminates the workers
mid-band. Workers never see SIGINT or SIGHUP themselves (a terminal sends
them to the whole process group): they are blocked in them, so that they
print no traceback of their own and are not replaced by the pool while the
main process stops.
"""
from __future__ import annotations

import multiprocessing
import os
import pickle
import signal
from contextlib import ExitStack

import mitsuba as mi
import numpy as np
from tqdm import tqdm

from converters.to_mitsuba import load_scene_dict
from core.entry import hold_signals, native_start_up
from renderer.variants import set_variant

#: Renders of less work than this (ray casts, as :func:`description_work`
#: counts them) render in-process: they take well under a second, less than
#: starting workers does
MIN_WORK = 60_000
BANDS_PER_WORKER = 12
#: What a terminal sends to the whole process group: blocked in the workers
GROUP_SIGNALS = {signal.SIGINT, signal.SIGHUP}

_scene = None
_description = None


def description_work(description: dict) -> int:
    """The most ray casts a render of ``description`` may take: each sample a
    camera ray and up to ``bounces`` mirror rays, each shaded by every light."""
    film = description["sensor"]["film"]
    spp = description["sensor"].get("sampler", {}).get("sample_count", 1)
    bounces = description.get("integrator", {}).get("bounces", 0)
    lights = sum(1 for value in description.values()
                 if isinstance(value, dict) and value.get("type") in ("point", "directional"))
    return film["width"] * film["height"] * spp * (1 + bounces) * (1 + lights)


def worth_it(description: dict) -> bool:
    """Whether to render in workers (see the module's docstring)."""
    return description_work(description) >= MIN_WORK


def _start(pickled_description: bytes, variant: str) -> None:
    """A worker's start-up. The description comes pickled: unpickling it
    imports Mitsuba, whose start-up notices (once per worker: the main
    process has said what there was to say) are held back here."""
    global _scene, _description
    with native_start_up():
        set_variant(variant, quiet=True)
        description = pickle.loads(pickled_description)


    mi.set_log_level(mi.LogLevel.Error)  # not the scalar-performance warning, once per worker
    _description = description
    _scene = load_scene_dict(description)


def _render_band(rows: tuple[int, int]):
    y0, y1 = rows
    sensor = dict(_description["sensor"])
    film = sensor["film"]
    sensor["film"] = dict(film, crop_offset_x=0, crop_offset_y=y0, crop_width=film["width"], crop_height=y1 - y0)
    integrator = _scene.integrator()
    if getattr(integrator, "stats", False):
        integrator.reset_counts()
    image = np.array(mi.render(_scene, sensor=mi.load_dict(sensor)), np.float32)
    counts = integrator.ray_counts() if getattr(integrator, "stats", False) else {}
    return y0, image, counts


def render_in_bands(description: dict, variant: str, workers: int | None = None) -> tuple[np.ndarray, dict]:
    """The image of ``description`` (and summed ray counts), rendered by worker processes."""
    film = description["sensor"]["film"]
    width, height = film["width"], film["height"]
    workers = workers or os.cpu_count() or 1
    bands = min(height, workers * BANDS_PER_WORKER)
    edges = np.linspace(0, height, bands + 1).round().astype(int)
    image, counts = None, {}
    context = multiprocessing.get_context("spawn")  # no fork after Dr.Jit started its threads
    with ExitStack() as stack:
        # Both signals wait until the pool exists and is sure to be terminated
        # (an interruption inside Pool() would leave its first workers); the
        # workers inherit GROUP_SIGNALS blocked (see the module's docstring)
        with hold_signals():
            signal.pthread_sigmask(signal.SIG_BLOCK, GROUP_SIGNALS)
            try:
                pool = context.Pool(workers, initializer=_start, initargs=(pickle.dumps(description), variant))
            finally:
                signal.pthread_sigmask(signal.SIG_UNBLOCK, GROUP_SIGNALS)
            stack.enter_context(pool)  # leaving it terminates the workers
        bar = stack.enter_context(tqdm(total=height, desc="Rendering", unit="row", delay=1.0, leave=False,
                                       disable=None))
        for y0, band, band_counts in pool.imap_unordered(_render_band, list(zip(edges[:-1], edges[1:]))):
            if image is None:
                image = np.zeros((height, width, band.shape[-1]), np.float32)
            image[y0:y0 + band.shape[0]] = band
            for key, value in band_counts.items():
                if isinstance(value, list):  # mirror rays by depth
                    counts[key] = np.add(counts.get(key, [0] * len(value)), value).tolist()
                else:
                    counts[key] = counts.get(key, 0) + value
            bar.update(band.shape[0])
    return image, counts
