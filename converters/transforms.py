"""4x4 affine matrices (float64, column vectors) for the course's transforms."""
from __future__ import annotations

import numpy as np


def scale(v) -> np.ndarray:
    return np.diag([v[0], v[1], v[2], 1.0])


def uniform_scale(s: float) -> np.ndarray:
    return scale((s, s, s))


def translate(v) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = v
    return m


def rotate(axis, degrees: float) -> np.ndarray:
    """Right-handed rotation about ``axis`` (Rodrigues)."""
    axis = np.asarray(axis, np.float64)
    x, y, z = axis / np.linalg.norm(axis)
    theta = np.radians(degrees)
    c, s, t = np.cos(theta), np.sin(theta), 1.0 - np.cos(theta)
    m = np.eye(4)
    m[:3, :3] = [[t * x * x + c, t * x * y - s * z, t * x * z + s * y],
                 [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
                 [t * x * z - s * y, t * y * z + s * x, t * z * z + c]]
    return m


def rotate_x(degrees: float) -> np.ndarray:
    return rotate((1, 0, 0), degrees)


def rotate_y(degrees: float) -> np.ndarray:
    return rotate((0, 1, 0), degrees)


def rotate_z(degrees: float) -> np.ndarray:
    return rotate((0, 0, 1), degrees)
