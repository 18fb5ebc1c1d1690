"""Shared test helpers: rendering a parsed scene and comparing 8-bit images."""
from __future__ import annotations

import numpy as np

from converters.description import RenderOptions, scene_dict
from converters.model import Scene
from converters.scene_variants import apply
from converters.to_mitsuba import load_scene_dict
from imaging.colour import to_course_8bit
from imaging.metrics import MAX_BAD_FRACTION, bad_fraction, bad_pixels  # noqa: F401 (the course's bar, re-exported)


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
