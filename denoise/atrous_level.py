"""One edge-avoiding À-Trous level of SVGF, shared by ``svgf`` and ``asvgf``.

A level filters colour and variance with the B3-spline kernel ``B3 x B3``
with holes ``step`` (Schied et al. 2017, Eq. 1-5): each tap weighs by its
luminance difference over the 3x3-blurred standard deviation at the centre
(``sigma_luminance``), by ``max(0, n·n')^normal_exponent`` and by the distance
of its position from the centre's tangent plane (``sigma_plane``); the
variance is filtered with the squared weights. The parameters come from any
object with those three attributes, as Python floats (``SVGFParams``, a
method's options) or as Dr.Jit Floats whose gradients the fit tracks
(``denoise.asvgf.FilterValues``).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from .filters import B3, FrameArrays, inv_two_sigma_sq, luminance, neg_exp, plane_distance_sq

GAUSS3 = (0.25, 0.5, 0.25)
EPSILON = 1e-10


def normal_power(cosine: mi.Float, exponent: float) -> mi.Float:
    """``max(0, cosine)^exponent``; a power of two as repeated squaring (exact
    enough and cheaper than exp/log)."""
    x = dr.maximum(cosine, 0.0)
    e = float(exponent)
    if e >= 1 and e == int(e) and (int(e) & (int(e) - 1)) == 0:
        for _ in range(int(e).bit_length() - 1):
            x = x * x
        return x
    return dr.select(x > 0.0, dr.power(x, e), 0.0)


def normal_weight(cosine: mi.Float, exponent) -> mi.Float:
    """``max(0, cosine)^exponent``: :func:`normal_power` for a Python number, else ``dr.power``."""
    if not dr.is_array_v(exponent):
        return normal_power(cosine, exponent)
    x = dr.maximum(cosine, 0.0)
    return dr.select(x > 0.0, dr.power(dr.select(x > 0.0, x, 1.0), exponent), 0.0)


def plane_factor(sigma_plane) -> object:
    """``1 / (2 sigma²)`` of the plane weight, for a Python number or a Dr.Jit Float."""
    if not dr.is_array_v(sigma_plane):
        return inv_two_sigma_sq(sigma_plane)
    return 1.0 / dr.maximum(2.0 * sigma_plane * sigma_plane, 1e-30)


def blurred_variance(frame: FrameArrays, variance: mi.Float) -> mi.Float:
    """The 3x3 Gaussian of the variance at each pixel (edges clamped)."""
    blurred = GAUSS3[1] * GAUSS3[1] * variance  # the centre's own (no gather)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dx == 0 and dy == 0:
                continue
            x = dr.clip(frame.x + dx, 0, frame.width - 1)
            y = dr.clip(frame.y + dy, 0, frame.height - 1)
            blurred += GAUSS3[dx + 1] * GAUSS3[dy + 1] * dr.gather(mi.Float, variance, mi.UInt32(y * frame.width + x))
    return blurred


def atrous_level(frame: FrameArrays, color: mi.Vector3f, variance: mi.Float, step: int, p
                 ) -> tuple[mi.Vector3f, mi.Float]:
    """One level with holes ``step``; ``p`` has ``sigma_luminance``,
    ``normal_exponent`` and ``sigma_plane`` (see the module). Returns the
    filtered colour and variance."""
    packed = dr.ravel(mi.Vector4f(color.x, color.y, color.z, variance))
    dr.eval(packed, variance)  # the 3x3 blur gathers the variance alone
    k_plane = plane_factor(p.sigma_plane)
    scale = -1.0 / (p.sigma_luminance * dr.sqrt(dr.maximum(blurred_variance(frame, variance), 0.0)) + EPSILON)
    lum_p = luminance(color)
    total, weights, total_var = mi.Vector3f(0.0), mi.Float(0.0), mi.Float(0.0)
    for j, hy in enumerate(B3):
        for i, hx in enumerate(B3):
            dx, dy = (i - 2) * step, (j - 2) * step
            if dx == 0 and dy == 0:  # the centre: weight 1 times the kernel's, its own values (no gather)
                total += hx * hy * color
                weights += hx * hy
                total_var += hx * hy * hx * hy * variance
                continue
            x, y = frame.x + dx, frame.y + dy
            inside = (x >= 0) & (x < frame.width) & (y >= 0) & (y < frame.height)
            q = dr.gather(mi.Vector4f, packed, mi.UInt32(dr.clip(y, 0, frame.height - 1) * frame.width
                                                         + dr.clip(x, 0, frame.width - 1)))
            c_q = mi.Vector3f(q.x, q.y, q.z)
            n_q, x_q = frame.gather_guides(x, y)
            log_w = (dr.abs(lum_p - luminance(c_q)) * scale
                     - plane_distance_sq(frame.normal, frame.position, x_q) * k_plane)
            w = hx * hy * normal_weight(dr.dot(frame.normal, n_q), p.normal_exponent) * neg_exp(-log_w)
            w = dr.select(inside, w, 0.0)
            total += w * c_q
            weights += w
            total_var += w * w * q.w
    return total / weights, total_var / (weights * weights)
