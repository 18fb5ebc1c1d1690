"""Image error metrics, each defined once: relMSE, mean FLIP, and the course's
"pixels off by more than N/255".

Every check, benchmark, notebook and test takes them from here.
"""
from __future__ import annotations

import numpy as np

#: a pixel is bad when some 8-bit channel differs by more than this (the course's 2/255)
TOLERANCE = 2
#: the course's bar: at most this fraction of bad pixels per image
MAX_BAD_FRACTION = 0.005


def relmse(image: np.ndarray, reference: np.ndarray, epsilon: float = 1e-2) -> float:
    """Relative mean squared error, ``mean((x - ref)^2 / (ref^2 + eps))``."""
    image, reference = np.asarray(image, np.float64), np.asarray(reference, np.float64)
    return float(np.mean((image - reference) ** 2 / (reference ** 2 + epsilon)))


def flip_error(image: np.ndarray, reference: np.ndarray) -> float:
    """Mean FLIP (``flip-evaluator``, LDR) of linear images clamped to [0, 1], as the course displays them."""
    import flip_evaluator

    _, mean, _ = flip_evaluator.evaluate(np.clip(reference, 0, 1).astype(np.float32),
                                         np.clip(image, 0, 1).astype(np.float32), "LDR",
                                         applyMagma=False)
    return float(mean)


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
