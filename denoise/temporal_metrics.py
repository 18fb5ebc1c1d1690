"""The denoiser's temporal figures, beside its frames: the relMSE between an
output and the previous one back-projected onto it (through the denoiser's
own back projection), and the stability figure made of them.
"""
from __future__ import annotations

import mitsuba as mi
import numpy as np

from imaging.metrics import relmse

from .filters import reproject

#: the quality figures average frames from this one on (the first frames have no history yet)
QUALITY_FROM = 4


def back_projected(frames, images) -> list[tuple[np.ndarray, np.ndarray]]:
    """For frames 1.., (image t at the pixels that keep history, image t-1 at
    the pixels they came from), through the denoiser's back projection."""
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
    (``frames``: the :class:`export.frames.FrameData` the images belong to)."""
    return [relmse(current, previous) if len(current) else 0.0 for current, previous in back_projected(frames, images)]


def stability(temporal: list[float], reference_temporal: list[float]) -> float:
    """Temporal stability: the mean of a method's :func:`temporal_relmse` over the
    ground truth's (1 = as stable as the truth, lower is steadier)."""
    return float(np.mean(temporal) / max(float(np.mean(reference_temporal)), 1e-12))
