"""Image error metrics, each defined once: relMSE, mean FLIP (and its heat map)
and the course's "pixels off by more than N/255" (the denoiser's temporal
figures, which need its back projection, are :mod:`denoise.temporal_metrics`).

Every check, benchmark, score command, notebook and test takes them from here.
"""
from __future__ import annotations

import numpy as np

#: a pixel is bad when some 8-bit channel differs by more than this (the course's 2/255)
TOLERANCE = 2
#: the course's bar: at most this fraction of bad pixels per image
MAX_BAD_FRACTION = 0.005


#: relMSE's term in the denominator: dark pixels' errors count as absolute ones
RELMSE_EPSILON = 1e-2


def relmse(image: np.ndarray, reference: np.ndarray, epsilon: float = RELMSE_EPSILON) -> float:
    """Relative mean squared error, ``mean((x - ref)^2 / (ref^2 + eps))``."""
    image, reference = np.asarray(image, np.float64), np.asarray(reference, np.float64)
    return float(np.mean((image - reference) ** 2 / (reference ** 2 + epsilon)))


def relmse_per_pixel(images, reference: np.ndarray, epsilon: float = RELMSE_EPSILON) -> np.ndarray:
    """(K, H, W): each of K (H, W, C) images' relMSE per pixel (its mean over the channels)."""
    stack, reference = np.asarray(images, np.float64), np.asarray(reference, np.float64)
    return np.mean((stack - reference) ** 2 / (reference ** 2 + epsilon), axis=-1)


def least_error_per_tile(errors: np.ndarray, tile: int) -> float:
    """The mean error of the image that takes, in each ``tile``-square tile (those on
    the right and bottom edges cut short), the one of K images whose summed error
    there is least; ``errors``: (K, H, W) per pixel."""
    _, height, width = errors.shape
    ids = (np.arange(height)[:, None] // tile) * -(-width // tile) + np.arange(width)[None, :] // tile
    sums = np.stack([np.bincount(ids.ravel(), weights=e.ravel()) for e in errors])
    return float(sums.min(axis=0).sum() / (height * width))


def flip_error(image: np.ndarray, reference: np.ndarray) -> float:
    """Mean FLIP (``flip-evaluator``, LDR) of linear images clamped to [0, 1], as the course displays them."""
    return evaluate_flip(image, reference, heat_map=False)[0]


def flip_heat_map(image: np.ndarray, reference: np.ndarray) -> tuple[float, np.ndarray]:
    """(mean FLIP as :func:`flip_error` has it, the per-pixel error as a magma-coloured uint8 RGB image)."""
    mean, colours = evaluate_flip(image, reference, heat_map=True)
    return mean, np.round(np.clip(colours, 0, 1) * 255).astype(np.uint8)


def evaluate_flip(image: np.ndarray, reference: np.ndarray, heat_map: bool) -> tuple[float, np.ndarray]:
    """flip-evaluator's (mean, map) under :func:`flip_error`'s conventions; the map magma-coloured with ``heat_map``."""
    import flip_evaluator  # noqa: PLC0415  flip_evaluator loads on use: --help and the paths without it stay quick

    error_map, mean, _ = flip_evaluator.evaluate(np.clip(reference, 0, 1).astype(np.float32),
                                                 np.clip(image, 0, 1).astype(np.float32), "LDR",
                                                 applyMagma=heat_map)
    return float(mean), error_map


def bad_pixels(a: np.ndarray, b: np.ndarray, tolerance: int = TOLERANCE) -> int:
    """Pixels whose 8-bit values differ by more than ``tolerance`` in any channel."""
    a, b = np.asarray(a).astype(int), np.asarray(b).astype(int)
    if a.shape != b.shape:
        raise ValueError(f"image shapes differ: {a.shape} vs {b.shape}")
    diff = np.abs(a - b)
    return int((diff.max(axis=-1) if diff.ndim == 3 else diff).__gt__(tolerance).sum())


def bad_fraction(a: np.ndarray, b: np.ndarray, tolerance: int = TOLERANCE) -> float:
    """Fraction of pixels whose 8-bit values differ by more than ``tolerance`` in any channel."""
    a = np.asarray(a)
    return bad_pixels(a, b, tolerance) / float(a.shape[0] * a.shape[1])
