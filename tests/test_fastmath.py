"""The filters' exp2 and log2 (denoise/fastmath.py) against NumPy over the ranges the taps use."""
from __future__ import annotations

import numpy as np


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
