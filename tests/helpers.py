"""Shared test helpers: rendering a parsed scene and comparing 8-bit images."""
from __future__ import annotations

import numpy as np

from converters.model import Scene
from converters.to_mitsuba import RenderOptions, load_scene_dict, scene_dict
from imaging.colour import to_course_8bit

#: The issue's bar: at most this fraction of pixels may differ by more than 2/255
MAX_BAD_FRACTION = 0.005


def bad_fraction(a: np.ndarray, b: np.ndarray, tolerance: int = 2) -> float:
    """Fraction of pixels whose 8-bit values differ by more than ``tolerance`` in any channel."""
    a, b = np.asarray(a).astype(int), np.asarray(b).astype(int)
    assert a.shape == b.shape, (a.shape, b.shape)
    diff = np.abs(a - b)
    return float((diff.max(axis=-1) if diff.ndim == 3 else diff).__gt__(tolerance).mean())


def render_layers(scene: Scene, **options) -> dict[str, np.ndarray]:
    """Renders with the active variant; returns beauty and the requested AOVs."""
    import mitsuba as mi

    from renderer.job import split_layers

    opts = RenderOptions(**options)
    image = np.array(mi.render(load_scene_dict(scene_dict(scene, opts))), np.float32)
    return split_layers(image, opts.aovs)


def encode(image: np.ndarray) -> np.ndarray:
    return to_course_8bit(image)
