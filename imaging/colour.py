"""Colour encoding: the one place where float images become display values."""
from __future__ import annotations

import warnings

import numpy as np


def to_course_8bit(image: np.ndarray) -> np.ndarray:
    """The course's PNG encoding: linear values clamped to [0, 1], times 255,
    truncated (so 0.5 becomes 127), no gamma. NaN becomes 0."""
    values = np.nan_to_num(np.asarray(image, np.float64), nan=0.0, posinf=1.0, neginf=0.0)
    return np.floor(np.clip(values, 0.0, 1.0) * 255.0).astype(np.uint8)


def to_srgb_8bit(image: np.ndarray) -> np.ndarray:
    """Linear Rec.709 radiance to 8-bit sRGB (IEC 61966-2-1 transfer function)."""
    with warnings.catch_warnings():  # colour-science warns that SciPy is absent; unused here
        warnings.simplefilter("ignore")
        import colour  # noqa: PLC0415  colour-science loads on use: it is slow to import
    values = np.nan_to_num(np.asarray(image, np.float64), nan=0.0, posinf=1.0, neginf=0.0)
    encoded = colour.cctf_encoding(np.clip(values, 0.0, 1.0), function="sRGB")
    return np.round(encoded * 255.0).astype(np.uint8)


def normals_to_rgb(normals: np.ndarray) -> np.ndarray:
    """The course's normal image: (N + 1) / 2; pixels without a hit have N = 0."""
    return (np.asarray(normals) + 1.0) * 0.5


def depth_to_grey(depth: np.ndarray, near: float, far: float) -> np.ndarray:
    """The course's depth image: (t - near) / (far - near), clamped to [0, 1]
    for every format (an .exr stores the same values as a .png). Pixels
    without a hit (t = 0) are black, also for an inverted ramp (``near > far``).
    ``near == far`` gives a step."""
    depth = np.asarray(depth, np.float64)
    span = far - near
    if span == 0.0:
        grey = np.where(depth > near, 1.0, 0.0)
    else:
        grey = np.clip((depth - near) / span, 0.0, 1.0)
    grey = np.where(depth > 0.0, np.nan_to_num(grey, nan=0.0), 0.0)
    return np.repeat(grey[..., None], 3, axis=-1) if grey.ndim == 2 else grey


def tone_map(image: np.ndarray) -> np.ndarray:
    """HDR to 8-bit sRGB for previews: Reinhard's extended operator (white 4) per
    channel, then the sRGB transfer function (colour-science)."""
    x = np.maximum(np.nan_to_num(np.asarray(image, np.float64)), 0.0)
    return to_srgb_8bit(x * (1.0 + x / 16.0) / (1.0 + x))


def side_by_side(images: list[np.ndarray], shrink: int = 1) -> np.ndarray:
    """HDR images tone-mapped (:func:`tone_map`) and set side by side, each first
    box-filtered down by ``shrink``."""
    def small(image: np.ndarray) -> np.ndarray:
        if shrink == 1:
            return image
        h, w = image.shape[0] // shrink, image.shape[1] // shrink
        return image[: h * shrink, : w * shrink].reshape(h, shrink, w, shrink, -1).mean(axis=(1, 3))

    return np.concatenate([tone_map(small(i)) for i in images], axis=1)
