"""Spatiotemporal Variance-Guided Filtering (Schied et al. 2017), Dr.Jit array code.

Per frame, on the (demodulated) colour ``c`` with luminance ``l``:

1. **Temporal accumulation** through our back projection
   (:func:`denoise.filters.reproject`): where the history is valid, its length
   ``n`` grows by one and colour and the first two luminance moments are
   blended, ``x = lerp(history, current, max(alpha, 1/n))``; elsewhere
   ``n = 1`` and they start from the current frame.
2. **Variance** ``max(0, m2 - m1²)`` from the accumulated moments; while the
   history is shorter than ``variance_frames`` (4) frames, from moments
   averaged over a 7x7 neighbourhood with the normal and plane weights
   instead, boosted by ``4/n`` (as the authors' code does).
3. **À-Trous levels** (5x5 B3 kernel, holes 2^i; by default as many as keep
   the paper's footprint, 5 levels or ±62 pixels at 1280 pixels wide, the
   same fraction of the image: see :func:`levels_for`), each tap weighted by
   ``exp(-|l_p - l_q| / (sigma_luminance · sqrt(g(var)_p) + ε))`` (``g``: the
   3x3 Gaussian blur of the variance), ``max(0, n_p·n_q)^normal_exponent`` and the
   assignment's plane weight ``exp(-(n_p · (x_q - x_p)/|x_q - x_p|)² / (2 sigma_plane²))``;
   the variance is filtered along with weights squared.
4. The first level's output is the next frame's colour history.

A level is one kernel: colour and variance are read as one 4-float record per
tap, the normal and position as packed records made once per frame.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from core.errors import UsageError

from .atrous_level import atrous_level, normal_power
from .filters import FrameArrays, check_positive, check_whole, inv_two_sigma_sq, luminance, neg_exp, plane_distance_sq


@dataclass(frozen=True)
class SVGFParams:
    """SVGF's parameters: the paper's, except ``alpha_color`` and ``levels`` (see there).
    ``levels``, ``sigma_luminance`` and ``normal_exponent`` are the method's
    options (:class:`denoise.methods.svgf.SVGF` declares and checks them)."""
    levels: int | None = None  # None: levels_for(width), the paper's 5 at 1280 pixels wide
    sigma_luminance: float = 4.0
    normal_exponent: float = 128.0  # exponent of max(0, n·n')
    sigma_plane: float = 0.1
    # the current frame's weight in the colour history: 0.3, not the paper's 0.2, because
    # our sequences move several pixels per frame and a moving shadow's history goes stale
    # sooner (measured in docs/denoising_methods.md)
    alpha_color: float = 0.3
    alpha_moments: float = 0.2
    variance_frames: int = 4  # below this history length the variance is estimated spatially
    spatial_radius: int = 3  # 7x7
    feedback_level: int = 0  # the level whose output becomes the next frame's history

    def __post_init__(self):
        check_positive("svgf", sigma_plane=self.sigma_plane)
        for name in ("alpha_color", "alpha_moments"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and 0.0 < value <= 1.0):
                raise UsageError(f"svgf: {name} must be in (0, 1], got {value!r}")
        check_whole("svgf", "variance_frames", self.variance_frames, 1, 64)
        check_whole("svgf", "spatial_radius", self.spatial_radius, 1, 16)
        check_whole("svgf", "feedback_level", self.feedback_level, 0, (self.levels or 12) - 1)


#: the paper's setting: 5 levels on 1280x720 frames
PAPER_LEVELS, PAPER_WIDTH = 5, 1280


def levels_for(width: int) -> int:
    """À-Trous levels whose footprint is the same fraction of the image as the
    paper's 5 levels at 1280 pixels wide: one level fewer per halving of the
    width (3 at 320 wide). A footprint fixed in pixels reaches across a small
    image's shadows and silhouettes (measured in docs/denoising_methods.md)."""
    return max(1, min(12, PAPER_LEVELS + round(math.log2(width / PAPER_WIDTH))))


@dataclass
class SVGFHistory:
    """What SVGF keeps from one frame to the next, per pixel."""
    color: mi.Vector3f
    moments: mi.Vector2f
    length: mi.Float


def plane_log_weight(k_plane: float, normal_p: mi.Vector3f, position_p: mi.Vector3f,
                     position_q: mi.Vector3f) -> mi.Float:
    return plane_distance_sq(normal_p, position_p, position_q) * k_plane


def temporal_accumulation(color: mi.Vector3f, history: SVGFHistory | None, index: mi.UInt32 | None,
                          valid: mi.Bool | None, p: SVGFParams) -> tuple[mi.Vector3f, mi.Vector2f, mi.Float]:
    """(integrated colour, integrated moments, history length) of this frame."""
    lum = luminance(color)
    moments = mi.Vector2f(lum, lum * lum)
    if history is None:
        return color, moments, dr.full(mi.Float, 1.0, dr.width(lum))
    previous_color = dr.gather(mi.Vector3f, history.color, index, valid)
    previous_moments = dr.gather(mi.Vector2f, history.moments, index, valid)
    previous_length = dr.gather(mi.Float, history.length, index, valid)
    valid = valid & dr.all(dr.isfinite(previous_color))
    length = dr.select(valid, previous_length + 1.0, 1.0)
    alpha_c = dr.select(valid, dr.maximum(p.alpha_color, 1.0 / length), 1.0)
    alpha_m = dr.select(valid, dr.maximum(p.alpha_moments, 1.0 / length), 1.0)
    integrated = dr.select(valid, dr.lerp(previous_color, color, alpha_c), color)
    moments = dr.select(valid, dr.lerp(previous_moments, moments, alpha_m), moments)
    return integrated, moments, length


def estimate_variance(frame: FrameArrays, moments: mi.Vector2f, length: mi.Float, p: SVGFParams) -> mi.Float:
    """Variance from the temporal moments, or from 7x7 spatial moments while
    the history is short. The spatial estimate runs only on the pixels that
    need it (compressed to a list: after the first frames, disocclusions)."""
    temporal = dr.maximum(moments.y - moments.x * moments.x, 0.0)
    packed = dr.ravel(moments)
    dr.eval(packed, length, temporal)
    short = dr.compress(length < p.variance_frames)
    if dr.width(short) == 0:
        return temporal
    cx, cy = dr.gather(mi.Int32, frame.x, short), dr.gather(mi.Int32, frame.y, short)
    normal = dr.gather(mi.Vector3f, frame.normal, short)
    position = dr.gather(mi.Vector3f, frame.position, short)
    k_plane = inv_two_sigma_sq(p.sigma_plane)
    total, weights = mi.Vector2f(0.0), mi.Float(0.0)
    r = p.spatial_radius
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            x, y = cx + dx, cy + dy
            inside = (x >= 0) & (x < frame.width) & (y >= 0) & (y < frame.height)
            j = mi.UInt32(dr.clip(y, 0, frame.height - 1) * frame.width + dr.clip(x, 0, frame.width - 1))
            m = dr.gather(mi.Vector2f, packed, j)  # clamped, unmasked: outside taps weigh 0
            if dx == 0 and dy == 0:
                w = mi.Float(1.0)
            else:
                n_q, x_q = frame.gather_guides(x, y)
                w = normal_power(dr.dot(normal, n_q), p.normal_exponent) * neg_exp(
                    plane_log_weight(k_plane, normal, position, x_q))
                w = dr.select(inside, w, 0.0)
            total += w * m
            weights += w
    spatial_moments = total / weights
    spatial = dr.maximum(spatial_moments.y - spatial_moments.x * spatial_moments.x, 0.0) * (
        p.variance_frames / dr.gather(mi.Float, length, short))
    spread = dr.zeros(mi.Float, dr.width(temporal))
    dr.scatter(spread, spatial, short)
    dr.eval(spread)
    return dr.select(length < p.variance_frames, spread, temporal)


def svgf(frame: FrameArrays, p: SVGFParams, history: SVGFHistory | None = None, index: mi.UInt32 | None = None,
         valid: mi.Bool | None = None) -> tuple[mi.TensorXf, SVGFHistory, mi.Float]:
    """One frame of SVGF on ``frame.color``; ``index``/``valid`` are the back
    projection onto the frame that ``history`` belongs to. Returns (the
    filtered colour, the history for the next frame, the final variance)."""
    color, moments, length = temporal_accumulation(frame.color, history, index, valid, p)
    dr.eval(color, moments, length)
    variance = estimate_variance(frame, moments, length, p)
    feedback = color
    levels = p.levels if p.levels is not None else levels_for(frame.width)
    for level in range(levels):
        color, variance = atrous_level(frame, color, variance, 1 << level, p)
        dr.eval(color, variance)
        if level == min(p.feedback_level, levels - 1):
            feedback = color
    return frame.tensor(color), SVGFHistory(feedback, moments, length), variance
