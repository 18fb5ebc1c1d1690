"""Shared test helpers: rendering a parsed scene and comparing 8-bit images."""
from __future__ import annotations

import numpy as np

from benchmarks.course import MAX_BAD_FRACTION, bad_pixels  # noqa: F401 (the issue's bar, re-exported)
from converters.model import Scene
from converters.description import RenderOptions, scene_dict
from converters.scene_variants import apply
from converters.to_mitsuba import load_scene_dict
from imaging.colour import to_course_8bit


def bad_fraction(a: np.ndarray, b: np.ndarray, tolerance: int = 2) -> float:
    """Fraction of pixels whose 8-bit values differ by more than ``tolerance`` in any channel."""
    a = np.asarray(a)
    assert a.shape == np.shape(b), (a.shape, np.shape(b))
    return bad_pixels(a, b, tolerance) / float(a.shape[0] * a.shape[1])


def render_layers(scene: Scene, variants=(), **options) -> dict[str, np.ndarray]:
    """Renders with the active variant; returns beauty and the requested AOVs.
    ``variants``: :mod:`converters.scene_variants` functions, applied in order."""
    import mitsuba as mi

    from renderer.job import split_layers

    opts = RenderOptions(**options)
    image = np.array(mi.render(load_scene_dict(apply(scene_dict(scene, opts), variants))), np.float32)
    return split_layers(image, opts.aovs)


def encode(image: np.ndarray) -> np.ndarray:
    return to_course_8bit(image)
