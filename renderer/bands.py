"""Rendering in horizontal bands across processes, for the scalar variants.

A Python integrator in a scalar variant makes one Python call per ray, and
the GIL keeps those on one core however many threads Mitsuba starts. Bands
of rows rendered by one process per core use them all: each worker loads the
scene once, then renders bands through a cropped copy of the sensor.
"""
from __future__ import annotations

import multiprocessing
import os

import numpy as np
from tqdm import tqdm

#: Fewer samples than this render in-process (starting workers costs ~1 s)
MIN_SAMPLES = 100_000
BANDS_PER_WORKER = 12

_scene = None
_description = None


def worth_it(width: int, height: int, spp: int) -> bool:
    return (os.cpu_count() or 1) > 1 and width * height * spp >= MIN_SAMPLES


def _start(description: dict, variant: str) -> None:
    global _scene, _description
    import mitsuba as mi

    from converters.to_mitsuba import load_scene_dict
    from renderer.variants import set_variant

    set_variant(variant, quiet=True)
    mi.set_log_level(mi.LogLevel.Error)  # not the scalar-performance warning, once per worker
    _description = description
    _scene = load_scene_dict(description)


def _render_band(rows: tuple[int, int]):
    import mitsuba as mi

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
    with context.Pool(workers, initializer=_start, initargs=(description, variant)) as pool, \
            tqdm(total=height, desc="Rendering", unit="row", delay=1.0, leave=False, disable=None) as bar:
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
