"""What ``svgf`` and ``asvgf`` share: SVGF's parameters, the variance of a
short history, the number of levels, and one edge-avoiding À-Trous level.

A level filters colour and variance with the B3-spline kernel ``B3 x B3``
with holes ``step`` (Schied et al. 2017, Eq. 1-5): each tap weighs by its
luminance difference over the 3x3-blurred standard deviation at the centre
(``sigma_luminance``), by ``max(0, n·n')^normal_exponent`` and by the distance
of its position from the centre's tangent plane (``sigma_plane``); the
variance is filtered with the squared weights. The parameters come from any
object with those three attributes, as Python floats (``SVGFParams``, a
method's options) or as Dr.Jit Floats whose gradients the fit tracks
(``denoise.methods.asvgf.FilterValues``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from core.errors import UsageError

from .edge_weights import inv_two_sigma_sq, plane_distance_sq
from .fastmath import EXP2_FLOOR, LOG2E, exp2_weight, log2_unit, neg_exp
from .filters import B3, FrameArrays, check_positive, check_whole, luminance
from .neighbours import ShiftedPlanes, usable

GAUSS3 = (0.25, 0.5, 0.25)
EPSILON = 1e-10


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


def plane_log_weight(k_plane: float, normal_p: mi.Vector3f, position_p: mi.Vector3f,
                     position_q: mi.Vector3f) -> mi.Float:
    return plane_distance_sq(normal_p, position_p, position_q) * k_plane


def estimate_variance(frame: FrameArrays, moments: mi.Vector2f, length: mi.Float, p: SVGFParams) -> mi.Float:
    """Variance from the temporal moments, or from 7x7 spatial moments while
    the history is short. The spatial estimate runs only on the pixels that
    need it (compressed to a list: after the first frames, disocclusions).
    Its inputs carry no gradient (the callers detach the moments)."""
    temporal = dr.maximum(moments.y - moments.x * moments.x, 0.0)
    packed = dr.ravel(moments)
    dr.eval(packed, length, temporal, frame.guides)  # gathered inside the symbolic loop: evaluated before it
    short = dr.compress(length < p.variance_frames)
    if dr.width(short) == 0:
        return temporal
    total, weights = spatial_moment_sums(frame, packed, short, p)
    spatial_moments = total / weights
    spatial = dr.maximum(spatial_moments.y - spatial_moments.x * spatial_moments.x, 0.0) * (
        p.variance_frames / dr.gather(mi.Float, length, short))
    spread = dr.zeros(mi.Float, dr.width(temporal))
    dr.scatter(spread, spatial, short)
    dr.eval(spread)
    return dr.select(length < p.variance_frames, spread, temporal)


@dr.syntax
def spatial_moment_sums(frame: FrameArrays, packed: mi.Float, short: mi.UInt32, p: SVGFParams
                        ) -> tuple[mi.Vector2f, mi.Float]:
    """``(Σ w m, Σ w)`` over the (2r+1)² window of each pixel listed in
    ``short``, ``m`` the moments ``packed`` two floats a pixel, ``w`` the normal
    and plane weights (1 at the centre, 0 outside the image). A symbolic loop
    over the window's rows, each row's taps unrolled: Python traces one row's
    taps a frame, not the whole window's (the same sums)."""
    cx, cy = dr.gather(mi.Int32, frame.x, short), dr.gather(mi.Int32, frame.y, short)
    normal = dr.gather(mi.Vector3f, frame.normal, short)
    position = dr.gather(mi.Vector3f, frame.position, short)
    # plain numbers, not loop state (the loop would treat p, a dataclass, as its state)
    k_plane, exponent, r = inv_two_sigma_sq(p.sigma_plane), p.normal_exponent, p.spatial_radius
    width, height = frame.width, frame.height
    total, weights = mi.Vector2f(0.0), mi.Float(0.0)
    dy = mi.Int32(-r)
    while dy <= r:
        y = cy + dy
        inside_row = (y >= 0) & (y < height)
        for dx in range(-r, r + 1):
            x = cx + dx
            j = mi.UInt32(dr.clip(y, 0, height - 1) * width + dr.clip(x, 0, width - 1))
            m = dr.gather(mi.Vector2f, packed, j)  # clamped, unmasked: outside taps weigh 0
            n_q, x_q = frame.gather_guides(x, y)
            w = normal_power(dr.dot(normal, n_q), exponent) * neg_exp(plane_log_weight(k_plane, normal, position, x_q))
            if dx == 0:
                w = dr.select(dy == 0, 1.0, w)  # the centre: weight 1
            w = dr.select(inside_row & (x >= 0) & (x < width), w, 0.0)
            total += w * m
            weights += w
        dy += 1
    return total, weights


def power_of_two(exponent) -> bool:
    """Whether ``exponent`` is a Python number 1, 2, 4, 8, ...: :func:`normal_power` squares."""
    if dr.is_array_v(exponent):
        return False
    e = float(exponent)
    return e >= 1 and e == int(e) and (int(e) & (int(e) - 1)) == 0


def normal_power(cosine: mi.Float, exponent: float) -> mi.Float:
    """``max(0, cosine)^exponent``; a power of two as repeated squaring (exact
    enough and cheaper than exp/log), else ``dr.power``."""
    x = dr.select(cosine > 0.0, cosine, 0.0)  # a compare and a select: cheaper than dr.maximum's NaN rules
    if power_of_two(exponent):
        for _ in range(int(exponent).bit_length() - 1):
            x = x * x
        return x
    return dr.select(x > 0.0, dr.power(x, float(exponent)), 0.0)


def plane_factor(sigma_plane) -> object:
    """``1 / (2 sigma²)`` of the plane weight, for a Python number or a Dr.Jit Float."""
    if not dr.is_array_v(sigma_plane):
        return inv_two_sigma_sq(sigma_plane)
    return 1.0 / dr.maximum(2.0 * sigma_plane * sigma_plane, 1e-30)


def blurred_variance(frame: FrameArrays, variance: mi.Float, planes: ShiftedPlanes | None = None) -> mi.Float:
    """The 3x3 Gaussian of the variance at each pixel, edges clamped (a tap past
    the image reads the nearest pixel inside it): each of the three rows'
    sums, then the column's. The taps read ``planes`` (its channel 3 the
    variance, as :func:`atrous_level` makes them) where given, else gather; a
    tap past the image is replaced by its row's (or column's) centre with a
    select, so both read the same values and sum them in the same order (bit
    for bit the same result) and no gather is left where planes are: a
    gather is a scalar load per lane where the CPU has no fast gather (AVX2)."""
    width, height = frame.width, frame.height

    def tap(dx: int, dy: int) -> mi.Float:
        if planes is not None:
            return planes.at(3, dy * width + dx)
        x, y = dr.clip(frame.x + dx, 0, width - 1), dr.clip(frame.y + dy, 0, height - 1)
        return dr.gather(mi.Float, variance, mi.UInt32(y * width + x))

    left, right = frame.x >= 1, frame.x < width - 1
    rows = {}
    for dy in (-1, 0, 1):
        centre = variance if dy == 0 else tap(0, dy)
        sides = dr.select(left, tap(-1, dy), centre) + dr.select(right, tap(1, dy), centre)
        rows[dy] = dr.fma(sides, GAUSS3[0], centre * GAUSS3[1])
    sides = dr.select(frame.y >= 1, rows[-1], rows[0]) + dr.select(frame.y < height - 1, rows[1], rows[0])
    return dr.fma(sides, GAUSS3[0], rows[0] * GAUSS3[1])


#: from this exponent on, ``max(0, c)^e`` is ``exp(e ln c)`` with ``ln c`` its degree-3 Taylor
#: polynomial about 1: the weight is then within 3.1e-5 of the exact one for every ``c`` (the
#: polynomial rises monotonically, and ``e`` times it is below -58 for ``c <= 0``)
SERIES_EXPONENT = 32.0


def normal_log2_weight(cosine: mi.Float, exponent, log2_w: mi.Float) -> mi.Float:
    """``log2_w`` plus the log2 of ``max(0, cosine)^exponent``, so that one
    exponential per tap makes the whole weight. For a Python exponent of at
    least :data:`SERIES_EXPONENT`, a Taylor polynomial of ``ln`` about 1 (three
    fused operations); else :func:`log2_unit`, and where ``cosine <= 0`` an
    exponent whose 2^ is about 0."""
    if not dr.is_array_v(exponent) and exponent >= SERIES_EXPONENT:
        k = float(exponent) * LOG2E
        t = cosine - 1.0  # ln(1 + t) = t - t²/2 + t³/3, the factor k in each coefficient
        q = dr.fma(dr.fma(t, k / 3.0, -k / 2.0), t, k)
        return dr.fma(t, q, log2_w)
    return dr.select(cosine > 0.0, dr.fma(log2_unit(cosine), exponent, log2_w), EXP2_FLOOR - 1.0)


def edge_masks(frame: FrameArrays, step: int) -> tuple[dict, dict]:
    """Per column offset ``dx`` and row offset ``dy`` of a level's taps (holes
    ``step``), whether the tap's column and row are inside the image: one
    compare each (a negative offset can leave the image only at the start),
    shared by the taps of that column or row."""
    x_ok = {k * step: (frame.x >= -k * step) if k < 0 else (frame.x < frame.width - k * step) for k in (-2, -1, 1, 2)}
    y_ok = {k * step: (frame.y >= -k * step) if k < 0 else (frame.y < frame.height - k * step) for k in (-2, -1, 1, 2)}
    return x_ok, y_ok


def tap_inside(x_ok: dict, y_ok: dict, dx: int, dy: int) -> mi.Bool:
    """Whether the tap at (``dx``, ``dy``), not both 0, is inside the image (:func:`edge_masks`)."""
    if dx == 0:
        return y_ok[dy]
    return x_ok[dx] if dy == 0 else x_ok[dx] & y_ok[dy]


def atrous_level(frame: FrameArrays, color: mi.Vector3f, variance: mi.Float, step: int, p
                 ) -> tuple[mi.Vector3f, mi.Float]:
    """One level with holes ``step``; ``p`` has ``sigma_luminance``,
    ``normal_exponent`` and ``sigma_plane`` (see the module). Returns the
    filtered colour and variance.

    Each tap's weight is one :func:`exp2_weight` of the sum of its terms'
    log2 (the kernel's factor, luminance, plane and the normal weight:
    :func:`normal_log2_weight`), but for a power of two below
    :data:`SERIES_EXPONENT`, which stays repeated squaring (:func:`normal_power`).

    Where no gradient is tracked, the taps read colour, variance, the
    colour's luminance and the guides as shifted planes (:mod:`denoise.neighbours`: plain loads, the same
    values for every tap inside the image, bit for bit the same result), and
    the level's kernel also writes its output as the next level's planes
    (:meth:`FrameArrays.planes_of` finds them); else each tap gathers one
    4-float colour record and one 8-float guide record."""
    shifted = usable(color, variance, p.sigma_luminance, p.sigma_plane, p.normal_exponent)
    if shifted:
        dr.eval(color, variance)
        planes = frame.planes_of((color.x, color.y, color.z, variance), 2 * step, derived=(luminance(color),))
        guides = frame.guide_planes(2 * step)
    else:
        packed = dr.ravel(mi.Vector4f(color.x, color.y, color.z, variance))
        dr.eval(packed, variance)  # the 3x3 blur gathers the variance alone
    squaring = power_of_two(p.normal_exponent) and p.normal_exponent < SERIES_EXPONENT
    k_plane = plane_factor(p.sigma_plane) * -LOG2E
    blurred = blurred_variance(frame, variance, planes if shifted else None)
    scale = -LOG2E / (p.sigma_luminance * dr.sqrt(dr.maximum(blurred, 0.0)) + EPSILON)
    lum_p = luminance(color)
    x_ok, y_ok = edge_masks(frame, step)
    total, weights, total_var = mi.Vector3f(0.0), mi.Float(0.0), mi.Float(0.0)
    for j, hy in enumerate(B3):
        for i, hx in enumerate(B3):
            dx, dy = (i - 2) * step, (j - 2) * step
            if dx == 0 and dy == 0:  # the centre: weight 1 times the kernel's, its own values (no gather)
                total += hx * hy * color
                weights += hx * hy
                total_var += hx * hy * hx * hy * variance
                continue
            if shifted:
                o = dy * frame.width + dx
                c_q = mi.Vector3f(planes.at(0, o), planes.at(1, o), planes.at(2, o))
                var_q, lum_q = planes.at(3, o), planes.at(4, o)
                n_q = mi.Vector3f(guides.at(0, o), guides.at(1, o), guides.at(2, o))
                x_q = mi.Vector3f(guides.at(3, o), guides.at(4, o), guides.at(5, o))
            else:
                x, y = frame.x + dx, frame.y + dy
                q = dr.gather(mi.Vector4f, packed, mi.UInt32(dr.clip(y, 0, frame.height - 1) * frame.width
                                                             + dr.clip(x, 0, frame.width - 1)))
                c_q, var_q = mi.Vector3f(q.x, q.y, q.z), q.w
                lum_q = luminance(c_q)
                n_q, x_q = frame.gather_guides(x, y)
            log2_w = dr.fma(dr.abs(lum_p - lum_q), scale, dr.fma(
                plane_distance_sq(frame.normal, frame.position, x_q), k_plane, math.log2(hx * hy)))
            cosine = dr.dot(frame.normal, n_q)
            if squaring:
                w = normal_power(cosine, p.normal_exponent) * exp2_weight(log2_w)
            else:
                w = exp2_weight(normal_log2_weight(cosine, p.normal_exponent, log2_w))
            w = dr.select(tap_inside(x_ok, y_ok, dx, dy), w, 0.0)
            total = dr.fma(w, c_q, total)  # fused: one operation a channel, not two
            weights += w
            total_var = dr.fma(w * w, var_q, total_var)
    out, out_var = total / weights, total_var / (weights * weights)
    if shifted:  # written by this level's kernel, read by the next level's taps (holes 2 step)
        frame.offer_planes((out.x, out.y, out.z, out_var), 4 * step, derived=(luminance(out),))
        dr.eval(out, out_var)  # read while the planes are held (see denoise.neighbours)
    return out, out_var
