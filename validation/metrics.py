"""Image error metrics, each defined once: relMSE, mean FLIP (and its heat map),
the course's "pixels off by more than N/255", and the denoiser's temporal figures
(relMSE between an output and the previous one back-projected onto it, and the
stability figure made of them).

Every check, benchmark, score command, notebook and test takes them from here.
"""
from __future__ import annotations

import mitsuba as mi
import numpy as np

from denoise.filters import reproject

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


def back_projected(frames, images) -> list[tuple[np.ndarray, np.ndarray]]:
    """For frames 1.., (image t at the pixels that keep history, image t-1 at
    the pixels they came from), through the denoiser's back projection."""
    # Dr.Jit loads only for the temporal figures: the image metrics above stay NumPy-only


    def tensor(a):
        return mi.TensorXf(np.ascontiguousarray(a, np.float32))

    pairs = []
    for before, after, previous, current in zip(frames, frames[1:], images, images[1:]):
        index, valid = reproject(tensor(after.position), tensor(after.ids), tensor(before.ids),
                                 after.object_to_world, before.object_to_world, before.world_to_screen)
        index, valid = np.array(index), np.array(valid, bool)
        pairs.append((current.reshape(-1, 3)[valid], previous.reshape(-1, 3)[index[valid]]))
    return pairs


def temporal_relmse(frames, images) -> list[float]:
    """Per frame from 1: relMSE between an image and the previous one back-projected onto it
    (``frames``: the :class:`denoise.frames.FrameData` the images belong to)."""
    return [relmse(current, previous) if len(current) else 0.0 for current, previous in back_projected(frames, images)]


def stability(temporal: list[float], reference_temporal: list[float]) -> float:
    """Temporal stability: the mean of a method's :func:`temporal_relmse` over the
    ground truth's (1 = as stable as the truth, lower is steadier)."""
    return float(np.mean(temporal) / max(float(np.mean(reference_temporal)), 1e-12))
