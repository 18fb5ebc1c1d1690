"""The assignment's À-Trous wavelet filter (one kernel per level), with clamped temporal accumulation."""
from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from ..edge_weights import EdgeWeights, edge_coefficients, edge_log_weight
from ..fastmath import LOG2E, exp2_weight
from ..filters import B3, FrameArrays, pack
from ..neighbours import usable
from ..svgf_common import edge_masks, tap_inside
from .base import SpatialFilterMethod, edge_options, edge_weights, levels_option, temporal_options


@dataclass(frozen=True)
class AtrousLevels:
    """À-Trous: ``levels`` passes of the 5x5 B3 kernel with holes 2^i; the
    colour sigma halves from one level to the next (``--levels`` declares and checks it)."""
    levels: int = 5


def atrous(frame: FrameArrays, p: EdgeWeights | None = None,
           levels: AtrousLevels | int = AtrousLevels()) -> mi.TensorXf:
    """The À-Trous wavelet: ``levels`` passes of a 5x5 B3-spline kernel with
    holes (step 2^i), each with the bilateral edge-stopping weights; the
    colour sigma halves from one level to the next (``p``: the default
    :class:`EdgeWeights` if None).

    Where no gradient is tracked, the taps read colour and guides as shifted
    planes (:mod:`denoise.neighbours`: plain loads, bit for bit the same
    result), each level's kernel writing the next level's colour planes;
    else they gather 4-float colour and 8-float guide records."""
    p = EdgeWeights() if p is None else p
    count = levels.levels if isinstance(levels, AtrousLevels) else AtrousLevels(levels).levels
    color = frame.color
    shifted = usable(color)
    if shifted:
        planes = frame.planes_of((color.x, color.y, color.z), 2)
        guides = frame.guide_planes(2 << (count - 1))
    else:
        color4 = pack(color)
    for level in range(count):
        step = 1 << level
        # the weight is 2^(log2(h) - log2(e) sum of D² k): one exponential per tap, the kernel's factor h in it
        coefficients = tuple(-LOG2E * k for k in edge_coefficients(p, p.sigma_color / step))
        x_ok, y_ok = edge_masks(frame, step)
        total, weights = mi.Vector3f(0.0), mi.Float(0.0)
        for j, hy in enumerate(B3):
            for i, hx in enumerate(B3):
                dx, dy = (i - 2) * step, (j - 2) * step
                if dx == 0 and dy == 0:  # the centre: weight exp(0), its own colour (no gather)
                    total += hx * hy * color
                    weights += hx * hy
                    continue
                if shifted:
                    o = dy * frame.width + dx
                    color_j = mi.Vector3f(planes.at(0, o), planes.at(1, o), planes.at(2, o))
                    guides_j = (mi.Vector3f(guides.at(0, o), guides.at(1, o), guides.at(2, o)),
                                mi.Vector3f(guides.at(3, o), guides.at(4, o), guides.at(5, o)))
                else:
                    x, y = frame.x + dx, frame.y + dy
                    color_j = frame.gather(color4, x, y)
                    guides_j = frame.gather_guides(x, y)
                log2_w = edge_log_weight(coefficients, color, frame.normal, frame.position, color_j, *guides_j,
                                         offset=math.log2(hx * hy))
                w = dr.select(tap_inside(x_ok, y_ok, dx, dy), exp2_weight(log2_w), 0.0)
                total = dr.fma(w, color_j, total)  # fused: one operation a channel, not two
                weights += w
        color = total / weights
        last = level + 1 == count
        if shifted and not last:  # the next level's taps, written by this level's kernel
            frame.offer_planes((color.x, color.y, color.z), 4 * step)
        dr.eval(color)
        if not last:
            if shifted:
                planes = frame.planes_of((color.x, color.y, color.z), 4 * step)
            else:
                color4 = pack(color)  # the next level's taps
    return frame.tensor(color)


class Atrous(SpatialFilterMethod):
    """À-Trous wavelet filter (:func:`atrous`): ``levels``
    passes of the 5x5 B3-spline kernel with holes 2^i, each tap weighted by the
    edge-stopping weights, the colour sigma halved from one level to the next;
    then, with ``temporal``, blended with the back-projected previous result
    clamped to the current 7x7 mean ± k sigma.
    """
    name = "atrous"
    description = ("the assignment's A-Trous wavelet filter (--levels passes); atrous+temporal: blended with "
                   "the back-projected, clamped previous result")
    options = edge_options() + (levels_option(AtrousLevels().levels),) + temporal_options(
        SpatialFilterMethod.temporal_defaults)
    benchmark = ("atrous", "atrous+temporal", "demod+outliers+atrous+temporal")

    def __init__(self, **props):
        super().__init__(**props)
        self.edges = edge_weights(self.props)
        self.levels = AtrousLevels(self.props["levels"])

    def spatial(self, arrays):
        return atrous(arrays, self.edges, self.levels)
