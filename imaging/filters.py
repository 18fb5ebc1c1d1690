"""Image-space filters."""
from __future__ import annotations

import numpy as np

#: The course's ``-filter`` kernel: 3x3 Gaussian, sigma = 1 (high-res) pixel
_TAPS = np.exp(-0.5 * np.array([-1.0, 0.0, 1.0]) ** 2)
GAUSS_3X3 = np.outer(_TAPS, _TAPS) / np.outer(_TAPS, _TAPS).sum()


def downsample_3x(image: np.ndarray) -> np.ndarray:
    """The course's anti-aliasing filter: an image rendered at 3x the size is
    reduced to the requested size, each pixel the 3x3 Gaussian-weighted mean
    of the high-resolution pixels it covers (centre weight largest)."""
    h, w = image.shape[0] // 3, image.shape[1] // 3
    blocks = np.asarray(image, np.float64)[: 3 * h, : 3 * w].reshape(h, 3, w, 3, *image.shape[2:])
    weights = GAUSS_3X3.reshape((1, 3, 1, 3) + (1,) * (image.ndim - 2))
    return (blocks * weights).sum(axis=(1, 3)).astype(image.dtype)


def centre_sample_3x(image: np.ndarray) -> np.ndarray:
    """The centre high-resolution pixel of each 3x3 block (for values that must
    not be averaged, such as object ids)."""
    return np.asarray(image)[1::3, 1::3]
