"""The filters' exp2 and log2 (denoise/fastmath.py) against NumPy over the ranges the taps use."""
from __future__ import annotations

import numpy as np
import pytest


def test_exp2_weight_is_within_3e_6_and_floored(variant_vectorised_rgb):
    import mitsuba as mi

    from denoise.fastmath import EXP2_FLOOR, exp2_weight

    x = np.linspace(-124.9, 5.0, 100001).astype(np.float32)
    ours = np.array(exp2_weight(mi.Float(x)), np.float64)
    assert np.abs(ours / np.exp2(x.astype(np.float64)) - 1).max() < 3e-6
    assert np.array(exp2_weight(mi.Float(0.0)))[0] == 1.0  # identical features weigh exactly 1
    # far below the floor, -inf and NaN: 2^EXP2_FLOOR, a weight of about 0 and never NaN
    low = np.array(exp2_weight(mi.Float([-300.0, -np.inf, np.nan])))
    assert np.allclose(low, 2.0 ** EXP2_FLOOR, rtol=1e-6)


def test_exp2_weight_is_differentiable(variant_vectorised_rgb):
    import drjit as dr
    import mitsuba as mi

    from denoise.fastmath import exp2_weight

    x = mi.Float([-7.3, -0.2, 0.0])
    dr.enable_grad(x)
    dr.backward(exp2_weight(x))
    expected = np.exp2([-7.3, -0.2, 0.0]) * np.log(2)
    assert np.allclose(np.array(dr.grad(x)), expected, rtol=1e-4)  # the polynomial's slope


def test_log2_unit_is_within_2e_6(variant_vectorised_rgb):
    import mitsuba as mi

    from denoise.fastmath import log2_unit

    c = np.concatenate([np.linspace(1e-6, 1.0, 100001), [1.0, 0.5, 0.999999]]).astype(np.float32)
    ours = np.array(log2_unit(mi.Float(c)), np.float64)
    assert np.abs(ours - np.log2(c.astype(np.float64))).max() < 2e-6


@pytest.mark.parametrize("sigma_normal", [0.05, 0.1, 0.11, 0.125, 0.5, 2.0])
def test_normal_angle_weight_without_the_square_root_is_the_same_weight(variant_vectorised_rgb, sigma_normal):
    """The normal term of an edge weight, ``2^(-log2(e) acos(x)²/(2σ²))``, for dots
    ``x`` over [-1, 1]: where :func:`facing_apart_floored` lets
    :func:`normal_angle_sq` skip the square root, its exponent within 1e-4 of
    the one through :func:`fast_acos` (exactly the floor where normals face apart);
    where it does not, the shortcut would change the weights of normals facing apart."""
    import mitsuba as mi

    from denoise.edge_weights import facing_apart_floored, inv_two_sigma_sq, normal_angle_sq
    from denoise.fastmath import EXP2_FLOOR, LOG2E, exp2_weight

    x = mi.Float(np.linspace(-1.0, 1.0, 20001).astype(np.float32))
    apart = np.array(x) < 0
    k = -LOG2E * inv_two_sigma_sq(sigma_normal)
    floored = facing_apart_floored(k)
    assert floored == (sigma_normal <= 0.11)  # (π/2)² k log2(e) >= 126 up to sigma 0.1186
    through_acos = np.array(exp2_weight(k * normal_angle_sq(x, False)), np.float64)
    shortcut = np.array(exp2_weight(k * normal_angle_sq(x, True)), np.float64)
    if floored:
        assert np.abs(np.log2(shortcut) - np.log2(through_acos)).max() < 1e-4  # float32 rounding
        assert (shortcut[apart] == 2.0 ** EXP2_FLOOR).all() and (through_acos[apart] == 2.0 ** EXP2_FLOOR).all()
    else:
        assert np.abs(shortcut[apart] / through_acos[apart] - 1).max() > 0.1


@pytest.mark.parametrize("sigma_normal", [0.05, 0.1, 0.15, 0.2, 0.5, 2.0])
@pytest.mark.parametrize("sign", [-1.0, 1.0])
def test_normal_log_term_is_the_angles_weight(variant_vectorised_rgb, sigma_normal, sign):
    """:func:`normal_log_term` between float32 unit normals at angles over [0, π]:
    the weight (``2^`` of the term with the -log2(e) factor, ``exp(-term)``
    without) within 4e-5 (:func:`fast_acos`'s error) of the exact
    ``exp(-arccos(x)² / (2σ²))`` of their dot ``x`` in float64; where it takes
    the series (sigmas up to 0.15), no further from it than the arccos is."""
    import drjit as dr
    import mitsuba as mi

    from denoise import edge_weights as ew
    from denoise.fastmath import LOG2E

    angle = np.linspace(0.0, np.pi, 20001)
    rng = np.random.default_rng(5)  # n_i in every direction, n_j at the angle from it
    a = rng.normal(size=(angle.size, 3))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    u = np.cross(a, rng.normal(size=(angle.size, 3)))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    b = np.cos(angle)[:, None] * a + np.sin(angle)[:, None] * u
    n_i, n_j = (dr.normalize(mi.Vector3f(*(mi.Float(c) for c in v.T.astype(np.float32)))) for v in (a, b))
    x = np.clip((np.array(n_i, np.float64) * np.array(n_j, np.float64)).sum(axis=0), -1.0, 1.0)
    exact = np.exp(-np.arccos(x) ** 2 * ew.inv_two_sigma_sq(sigma_normal))
    k = sign * ew.inv_two_sigma_sq(sigma_normal) * (LOG2E if sign < 0 else 1.0)

    def weight(term):
        term = np.array(term, np.float64)
        return np.exp2(term) if sign < 0 else np.exp(-term)

    error = np.abs(weight(ew.normal_log_term(n_i, n_j, k, mi.Float(0.0))) - exact).max()
    through_acos = weight(ew.normal_angle_sq(dr.dot(n_i, n_j), ew.facing_apart_floored(k)) * k)
    assert ew.angle_series_fits(k) == (sigma_normal <= 0.15)
    assert error < 4e-5
    if ew.angle_series_fits(k):
        assert error <= np.abs(through_acos - exact).max()
