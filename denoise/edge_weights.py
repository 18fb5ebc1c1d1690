"""The assignment's edge-stopping weights on colour, normal angle and plane
distance, as the exponents of ``exp(-D²/(2σ²))`` that the joint bilateral and
À-Trous filters' taps sum (one exponential per tap, :mod:`denoise.fastmath`)."""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import drjit as dr
import mitsuba as mi
import numpy as np

from .fastmath import EXP2_FLOOR, LOG2E


@dataclass(frozen=True)
class EdgeWeights:
    """The assignment's edge-stopping weights ``exp(-D²/(2σ²))`` on colour,
    normal angle (``arccos`` of the normals' dot) and plane distance (the
    normal dotted with the unit vector between the two positions). The
    methods' options declare and check each (:func:`denoise.methods.base.edge_options`)."""
    sigma_color: float = 0.6
    sigma_normal: float = 0.1
    sigma_plane: float = 0.1


def inv_two_sigma_sq(sigma: float) -> float:
    """``1 / (2 sigma²)``, the factor of a Gaussian weight's exponent."""
    # sigma -> 0 means "only identical values": a huge but finite factor keeps exp() at 0, not NaN
    return 1.0 / max(2.0 * sigma * sigma, 1e-30)


def edge_log_weight(coefficients: tuple[float, float, float], color_i, normal_i, position_i,
                    color_j, normal_j, position_j, offset: float = 0.0) -> mi.Float:
    """``offset`` plus the colour, normal and plane terms of the weight's
    exponent, each D² times its factor in ``coefficients`` (1/(2σ²), or that
    times -log2(e) for a caller that takes exp2). Identical positions give a
    plane distance of 0, not 0/0."""
    k_color, k_normal, k_plane = coefficients
    d_color = dr.squared_norm(color_i - color_j)
    plane = plane_distance_sq(normal_i, position_i, position_j)
    return dr.fma(d_color, k_color, normal_log_term(normal_i, normal_j, k_normal, dr.fma(plane, k_plane, offset)))


def normal_log_term(normal_i: mi.Vector3f, normal_j: mi.Vector3f, k_normal: float, rest: mi.Float) -> mi.Float:
    """``rest + k_normal arccos(n_i · n_j)²``. Where :func:`angle_series_fits`,
    ``arccos(1 - t)²`` is its Taylor series in ``t = 1 - n_i · n_j`` to the
    third power (six fused operations in all); else :func:`normal_angle_sq`."""
    if not angle_series_fits(k_normal):
        x = dr.dot(normal_i, normal_j)
        return dr.fma(normal_angle_sq(x, facing_apart_floored(k_normal)), k_normal, rest)
    t = dr.fma(-normal_i.x, normal_j.x, dr.fma(-normal_i.y, normal_j.y, dr.fma(-normal_i.z, normal_j.z, 1.0)))
    c1, c2, c3 = (k_normal * c for c in ANGLE_SERIES)
    return dr.fma(t, dr.fma(dr.fma(t, c3, c2), t, c1), rest)


#: ``arccos(1 - t)² = 2 t + t²/3 + 4 t³/45 + ...``: the coefficients of t, t², t³
ANGLE_SERIES = (2.0, 1.0 / 3.0, 4.0 / 45.0)
#: the most a weight (at most 1) may move where :func:`normal_log_term` takes the series
ANGLE_SERIES_TOLERANCE = 1e-6


@lru_cache(maxsize=64)
def angle_series_fits(k_normal: float) -> bool:
    """Whether the normal term's weight ``2^(k' arccos(x)²)`` (``k_normal``:
    1/(2σ²), or that times -log2(e)) moves by at most
    :data:`ANGLE_SERIES_TOLERANCE` anywhere on x in [-1, 1] when the series
    stands for ``arccos(x)²``: true for small sigmas (0.15 and below), whose
    weights vanish before the series departs from the angle."""
    log2_units = -abs(k_normal) * (1.0 if k_normal < 0 else LOG2E)
    t = np.linspace(0.0, 2.0, 8001)
    series = t * (ANGLE_SERIES[0] + t * (ANGLE_SERIES[1] + t * ANGLE_SERIES[2]))
    error = np.abs(np.exp2(log2_units * series) - np.exp2(log2_units * np.arccos(1.0 - t) ** 2))
    return bool(error.max() <= ANGLE_SERIES_TOLERANCE)


def plane_distance_sq(normal_i: mi.Vector3f, position_i: mi.Vector3f, position_j: mi.Vector3f) -> mi.Float:
    """``(n_i · (x_j - x_i) / |x_j - x_i|)²`` as one division, without the square
    root of a normalisation; 0 for identical positions (0/1e-30, not 0/0: the
    1e-30 changes no |x_j - x_i|² above 1e-22, and costs one add where a test
    and two selects did)."""
    d = position_j - position_i
    return dr.square(dr.dot(normal_i, d)) / (dr.squared_norm(d) + 1e-30)


def facing_apart_floored(k_normal: float) -> bool:
    """Whether an angle of 90° or more between the normals alone makes a tap's
    weight the floor of :func:`exp2_weight` (``k_normal``: 1/(2σ²), or that times
    -log2(e)); every other term of the exponent only lowers it further."""
    log2_units = abs(k_normal) * (1.0 if k_normal < 0 else LOG2E)
    return log2_units * RIGHT_ANGLE_SQ >= 1.0 - EXP2_FLOOR


#: (π/2)²: the squared angle between normals at right angles
RIGHT_ANGLE_SQ = (math.pi / 2) ** 2


def normal_angle_sq(x: mi.Float, floored: bool) -> mi.Float:
    """``arccos(x)²`` of ``x``, a dot of unit normals (:func:`fast_acos`). Where
    ``floored`` (:func:`facing_apart_floored`), normals facing apart (``x < 0``)
    get (π/2)², which weighs the same (the floor), and the rest ``(1 - x) p(x)²``:
    the square of ``sqrt(1 - x) p(x)`` without the square root."""
    if not floored:
        return dr.square(fast_acos(x))
    p = acos_polynomial(x)
    return dr.select(x < 0.0, RIGHT_ANGLE_SQ, (1.0 - x) * (p * p))


def acos_polynomial(a: mi.Float) -> mi.Float:
    """The degree-4 polynomial of :func:`fast_acos`, at ``a`` in [0, 1]."""
    p = mi.Float(0.009732975624501705)
    for c in (-0.037618231028318405, 0.0856383889913559, -0.2142806202173233, 1.570791482925415):
        p = dr.fma(p, a, c)
    return p


def fast_acos(x: mi.Float) -> mi.Float:
    """``arccos`` of ``x`` clipped to [-1, 1]: ``sqrt(1 - |x|)`` times a
    degree-4 polynomial (the form of Abramowitz & Stegun 4.4.46, refitted:
    |error| <= 5e-6 rad in float32, which moves an edge weight's exponent by
    at most 1e-4 at the default sigma_normal), about a third of ``dr.acos``'s cost."""
    a = dr.abs(x)
    a = dr.select(a < 1.0, a, 1.0)  # a compare and a select: cheaper than dr.minimum's NaN rules
    r = dr.sqrt(1.0 - a) * acos_polynomial(a)
    return dr.select(x < 0.0, dr.pi - r, r)


def edge_coefficients(p: EdgeWeights, sigma_color: float) -> tuple[float, float, float]:
    return inv_two_sigma_sq(sigma_color), inv_two_sigma_sq(p.sigma_normal), inv_two_sigma_sq(p.sigma_plane)
