"""The few transcendental functions the filters' taps evaluate, for the
ranges they use, in fewer Dr.Jit operations than ``dr.exp2``/``dr.log2``
(which handle every float: NaN, infinities, denormals, overflow).

An À-Trous level is bound by its operations (``benchmarks.roofline``), and
each tap's weight is one exponential: these keep the weights within 3 parts
in 10⁶ of the exact ones (checked against NumPy in tests/test_fastmath.py).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

#: log2(e): ``exp(x) = exp2(x * LOG2E)``
LOG2E = 1.4426950408889634
#: the smallest exponent :func:`exp2_weight` returns 2^ of: its result stays a normal float
EXP2_FLOOR = -125.0
#: 1.5 2^23: a float this large has no fraction bits, so adding it rounds to an integer (to even)
ROUNDING = 12582912.0
#: 2^f on [-0.5, 0.5], highest power first: a relative-error fit with the constant 1
#: (2^0 exactly 1), at most 2.9e-6 from 2^f in float32 (a weight's relative error)
EXP2_POLY = (0.009582853876054287, 0.055906426161527634, 0.24024099111557007, 0.6931241750717163, 1.0)
#: log2(m) / (m - 1) on m in [0.5, 1], highest power first: log2(m) within 5.5e-7 in float32
LOG2_POLY = (1.8960845470428467, -9.671701431274414, 21.183528900146484, -26.0462646484375,
             19.828250885009766, -9.989044189453125, 4.241885662078857)


def exp2_weight(x: mi.Float) -> mi.Float:
    """``2^x`` for a weight's exponent ``x <= 0`` (and up to 127); below
    :data:`EXP2_FLOOR` (and for NaN) ``2^EXP2_FLOOR``, about 2e-38, not 0.
    ``x`` plus 1.5 2^23 rounds it to an integer ``n`` in the float's low
    bits, which shifted are ``n``'s exponent field; ``2^f``, ``f = x - n`` in
    [-0.5, 0.5], is a polynomial, scaled by 2^n as an integer add to its
    exponent field (a multiply where a gradient is tracked: differentiable
    in ``x``, ``n`` a constant)."""
    x = dr.select(x > EXP2_FLOOR, x, EXP2_FLOOR)
    shifted = dr.detach(x) + ROUNDING
    f = x - (shifted - ROUNDING)
    p = dr.fma(f, EXP2_POLY[0], EXP2_POLY[1])
    for c in EXP2_POLY[2:]:
        p = dr.fma(p, f, c)
    exponent = dr.reinterpret_array(mi.Int32, shifted) << 23
    if dr.grad_enabled(p):
        return p * dr.reinterpret_array(mi.Float, exponent + 0x3F800000)
    return dr.reinterpret_array(mi.Float, dr.reinterpret_array(mi.Int32, p) + exponent)


def neg_exp(x: mi.Float) -> mi.Float:
    """``exp(-x)`` for ``x >= 0`` (:func:`exp2_weight`)."""
    return exp2_weight(x * -LOG2E)


def log2_unit(c: mi.Float) -> mi.Float:
    """``log2(c)`` for ``0 < c <= 1`` (a cosine of two unit normals), within
    6e-7; other values give some finite number, which callers select away.
    ``c = m 2^k`` with ``m`` in [0.5, 1) from the float's bits, ``log2(m)`` a
    polynomial times ``m - 1``. Not differentiable in ``c``."""
    bits = dr.reinterpret_array(mi.Int32, c)
    m = dr.reinterpret_array(mi.Float, (bits & 0x007FFFFF) | 0x3F000000)
    k = mi.Float((bits >> 23) - 126)
    q = dr.fma(m, LOG2_POLY[0], LOG2_POLY[1])
    for a in LOG2_POLY[2:]:
        q = dr.fma(q, m, a)
    return dr.fma(m - 1.0, q, k)
