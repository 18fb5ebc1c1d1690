"""The course camera's basis, in one place (NumPy only: no Mitsuba, no variant).

The course's camera shoots the ray through normalised image coordinates
:math:`(x, y) \\in [-1, 1]^2` (``x`` to the right, ``y`` up) along
``forward + x * horizontal + y * up``, normalised, with

- ``forward = normalize(direction) / tan(fov / 2)``,
- ``horizontal = normalize(normalize(direction) x up)``,
- ``up`` exactly as given: neither normalised nor made orthogonal to
  ``direction``, as in the course's solution.

The ``course_camera`` sensor (``mi_plugins/course_camera.py``) traces these
rays and the denoiser's frame matrices (``export/frames.py``) invert them.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np


class CameraBasis(NamedTuple):
    forward: np.ndarray  # unit direction / tan(fov / 2)
    horizontal: np.ndarray  # unit, direction x up
    up: np.ndarray  # as given
    tan_half_fov: float


def course_camera_basis(direction, up, fov_degrees: float) -> CameraBasis:
    """The basis of a course camera (float64), or a ValueError that says why there is none."""
    fov = float(fov_degrees)
    if not 0.0 < fov < 180.0:
        raise ValueError(f"course_camera: fov must be in (0, 180) degrees, got {fov}")
    direction = np.asarray(direction, np.float64).reshape(3)
    up = np.asarray(up, np.float64).reshape(3)
    length = float(np.linalg.norm(direction))
    if not length > 0.0:
        raise ValueError("course_camera: direction must not be zero")
    unit = direction / length
    cross = np.cross(unit, up)
    if not float(np.linalg.norm(cross)) > 1e-12 * float(np.linalg.norm(up)):
        raise ValueError("course_camera: up must not be parallel to direction")
    tan_half = math.tan(math.radians(fov) * 0.5)
    return CameraBasis(unit / tan_half, cross / np.linalg.norm(cross), up, tan_half)
