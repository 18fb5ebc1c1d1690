"""Spatiotemporal Variance-Guided Filtering (Schied et al. 2017), Dr.Jit array code, and the method.

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

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from ..filters import FrameArrays, luminance
from ..svgf_common import SVGFParams, atrous_level, estimate_variance, levels_for
from .base import DenoisingMethod, Option, levels_option


@dataclass
class SVGFHistory:
    """What SVGF keeps from one frame to the next, per pixel."""
    color: mi.Vector3f
    moments: mi.Vector2f
    length: mi.Float


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


PAPER = SVGFParams()


class SVGF(DenoisingMethod):
    """SVGF (Schied et al. 2017, the kernels above): temporal accumulation of
    the colour and its luminance moments through the back projection, a
    per-pixel variance from them (from a 7x7 neighbourhood while the history
    is short), then À-Trous levels whose luminance weight is scaled by that
    variance. Temporal by nature (``--no-temporal``: no history); it always
    demodulates by the albedo when the frames have one.
    """
    name = "svgf"
    description = "spatiotemporal variance-guided filtering (Schied et al. 2017)"
    temporal_by_nature = True
    demodulates = True
    options = (
        levels_option(PAPER.levels, "the paper's 5 at 1280 pixels wide, one fewer per halving of the width"),
        Option("sigma_luminance", PAPER.sigma_luminance, "luminance weight", unit="standard deviations", low=0.0,
               open_low=True, step=0.1, span=(0.1, 32.0), group="svgf"),
        Option("normal_exponent", PAPER.normal_exponent, "normal weight max(0, n.n')^exponent", low=0.0,
               open_low=True, step=1.0, span=(1.0, 256.0), group="svgf"),
    )
    benchmark = ("svgf",)

    def __init__(self, **props):
        super().__init__(**props)
        self.params = SVGFParams(**{o.key: self.props[o.key] for o in self.options})

    def filter(self, arrays, frame, index, valid):
        result, self.history, _ = svgf(arrays, self.params, self.history if index is not None else None,
                                       index, valid)
        return result
