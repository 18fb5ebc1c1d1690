"""A spatiotemporal filter that does not lag: SVGF with a fast and a slow
history, colour-box clipping and anti-lag, Dr.Jit array code, and the method
with its fitted parameters.

Per frame, on the (demodulated) colour ``c``, after our back projection
(:func:`denoise.filters.reproject`) of the previous frame's histories:

1. **Temporal gradient.** ``δ = |Ȳ_c - Ȳ_f| / (max(Ȳ_c, Ȳ_f) + floor)`` with ``Ȳ``
   the (2 ``box_radius`` + 1)² box mean of YCoCg's ``Y`` of the current frame
   and of the back-projected fast history: a sudden change of lighting, a
   moving shadow or highlight. ``λ = clip(antilag_gain (δ - antilag_threshold),
   0, 1)`` (A-SVGF's ``λ``, estimated from the history instead of re-rendered
   gradient samples).
2. **History length.** ``n = min(1 + n_prev (1 - λ), slow_frames)`` (1 where
   the history is invalid): λ = 1 forgets the history at once (NRD ReLAX's
   anti-lag shortens it the same way).
3. **Fast history** ``f = lerp(clip(f_prev), c, max(1/n, 1/fast_frames))``,
   its history clipped in YCoCg to the current box's mean ± ``fast_clip`` σ.
4. **Slow history** ``s = lerp(clip(s_prev), c, 1/n)``, its history clipped in
   YCoCg to mean ± ``clip_width`` σ of the (2 ``clip_radius`` + 1)² box of the
   fast history ``f``: the slow history follows wherever the fast one moves.
5. **Moments and variance** as SVGF's (:mod:`denoise.methods.svgf`), blended with
   ``1/n``; below ``variance_frames`` of history the current frame's 7x7
   spatial estimate (:func:`denoise.svgf_common.estimate_variance`), boosted by
   ``variance_frames / n``.
6. **À-Trous levels** of SVGF on ``s`` (variance-guided luminance weight,
   normal weight ``max(0, n·n')^normal_exponent``, plane weight); level
   ``feedback_level``'s output is the next frame's slow history.
7. **Wider where the history is short.** ``wide_levels`` more levels follow;
   the output is ``lerp(wide, c_L, clip((n - 1) / wide_frames, 0, 1))`` with
   ``c_L`` the last regular level's: a pixel just disoccluded or reset by the
   anti-lag has one sample, and a footprint that averages more of its
   surface, while one with a long history keeps its detail.

Every continuous parameter reaches the kernels through :class:`FilterValues`:
Python floats when denoising (constants in the kernels), or Dr.Jit Floats with
gradients enabled when :mod:`denoise.fit` differentiates the whole sequence.
The fitted values, ``denoise/asvgf_params.json``, are the method's defaults
(:class:`ASVGF` declares each parameter).
"""
from __future__ import annotations

from dataclasses import dataclass, fields, replace
from pathlib import Path

import drjit as dr
import mitsuba as mi

from core.errors import UsageError
from core.json_input import JSONInputError, read_json

from ..filters import FrameArrays, box_mean, clamp_box, luminance
from ..svgf_common import SVGFParams, atrous_level, estimate_variance, levels_for
from .base import DenoisingMethod, Option, edge_options, levels_option

#: added to the luminance in the temporal gradient's denominator: dark noise is not a change
GRADIENT_FLOOR = 1e-2


@dataclass(frozen=True)
class ASVGFParams:
    """The filter's parameters (see the module's steps). The continuous ones
    (the fields of :class:`FilterValues`) and ``levels`` are the method's
    options: :class:`ASVGF` declares them, with their ranges, the
    hand-set values and the fitted ones (``asvgf_params.json``).

    - ``levels``: À-Trous levels (None: :func:`denoise.svgf_common.levels_for` the width)
    - ``sigma_luminance``: scale of the variance-guided luminance weight
    - ``normal_exponent``: exponent of the normal weight ``max(0, n·n')``
    - ``sigma_plane``: σ of the plane-distance weight
    - ``slow_frames``: cap of the history length (the slow history's 1/α)
    - ``fast_frames``: the fast history's 1/α
    - ``clip_width``: the slow history clipped to the fast box's mean ± this σ
    - ``fast_clip``: the fast history clipped to the current box's mean ± this σ
    - ``antilag_gain``, ``antilag_threshold``: ``λ = clip(gain (δ - threshold), 0, 1)``
    - ``wide_frames``: up to this history length the wide levels' output is blended in
    - ``wide_levels``: À-Trous levels after the regular ones, for short histories (0: none)
    - ``box_radius``: the current frame's box (statistics, gradient), (2r+1)²
    - ``clip_radius``: the fast history's box for the slow clip, (2r+1)²
    - ``variance_frames``: below this history length the variance is spatial
    - ``spatial_radius``: the spatial variance's window, (2r+1)²
    - ``feedback_level``: the level whose output is the next slow history
    """
    sigma_luminance: float
    normal_exponent: float
    sigma_plane: float
    slow_frames: float
    fast_frames: float
    clip_width: float
    fast_clip: float
    antilag_gain: float
    antilag_threshold: float
    wide_frames: float
    levels: int | None = None
    box_radius: int = 3
    clip_radius: int = 1
    variance_frames: int = 4
    spatial_radius: int = 3
    feedback_level: int = 0
    wide_levels: int = 1

    def __post_init__(self):
        whole = {"box_radius": (1, 16), "clip_radius": (1, 16), "variance_frames": (1, 64),
                 "spatial_radius": (1, 16), "feedback_level": (0, (self.levels or 12) - 1), "wide_levels": (0, 4)}
        for name, (low, high) in whole.items():
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
                raise UsageError(f"asvgf: {name} must be a whole number from {low} to {high}, got {value!r}")

    def continuous(self) -> dict[str, float]:
        return {f.name: getattr(self, f.name) for f in fields(FilterValues)}

    def with_values(self, values: dict[str, float]) -> ASVGFParams:
        return replace(self, **values)


@dataclass
class FilterValues:
    """The continuous parameters as the kernels take them: Python floats, or
    Dr.Jit Floats (one lane each) whose gradients :mod:`denoise.fit` tracks."""
    sigma_luminance: object
    normal_exponent: object
    sigma_plane: object
    slow_frames: object
    fast_frames: object
    clip_width: object
    fast_clip: object
    antilag_gain: object
    antilag_threshold: object
    wide_frames: object

    @staticmethod
    def of(p: ASVGFParams) -> FilterValues:
        return FilterValues(**p.continuous())

    def widened(self, width: int) -> FilterValues:
        """Dr.Jit values gathered to one lane per pixel, evaluated: the backward
        pass then adds each frame's gradients into a parameter with one scatter,
        instead of one reduction per use of it in every tap."""
        def wide(value):
            if not dr.is_array_v(value) or dr.width(value) == width:
                return value
            out = dr.gather(mi.Float, value, dr.zeros(mi.UInt32, width))
            dr.eval(out)
            return out

        return FilterValues(**{f.name: wide(getattr(self, f.name)) for f in fields(self)})

    def as_floats(self) -> dict[str, float]:
        return {f.name: float(getattr(self, f.name)[0] if dr.is_array_v(getattr(self, f.name))
                              else getattr(self, f.name)) for f in fields(self)}


@dataclass
class ASVGFHistory:
    """What the filter keeps from one frame to the next, per pixel."""
    fast: mi.Vector3f
    slow: mi.Vector3f
    moments: mi.Vector2f
    length: mi.Float


def to_ycocg(c: mi.Vector3f) -> mi.Vector3f:
    return mi.Vector3f(0.25 * c.x + 0.5 * c.y + 0.25 * c.z, 0.5 * c.x - 0.5 * c.z, -0.25 * c.x + 0.5 * c.y - 0.25 * c.z)


def from_ycocg(c: mi.Vector3f) -> mi.Vector3f:
    return mi.Vector3f(c.x + c.y - c.z, c.x + c.z, c.x - c.y - c.z)


def box_statistics(frame: FrameArrays, color_ycocg: mi.Vector3f, radius: int) -> tuple[mi.Vector3f, mi.Vector3f]:
    """Mean and σ per channel of each pixel's (2r+1)² box (:func:`denoise.filters.clamp_box`)."""
    return clamp_box(frame.tensor(color_ycocg), radius)


def differentiable_box_statistics(frame: FrameArrays, color_ycocg: mi.Vector3f, radius: int
                                  ) -> tuple[mi.Vector3f, mi.Vector3f]:
    """As :func:`box_statistics`, σ from the box means of the values and their
    squares, with a finite derivative where a box is flat (a constant
    background): clamp_box's ``sqrt`` of a variance of exactly 0 has an
    infinite one, and the backward pass's ``0 · inf`` is NaN."""
    mean, _ = clamp_box(frame.tensor(color_ycocg), radius)
    mean_square, _ = clamp_box(frame.tensor(color_ycocg * color_ycocg), radius)
    return mean, dr.sqrt(dr.maximum(mean_square - mean * mean, 1e-30))


def clip_ycocg(history_ycocg: mi.Vector3f, mean: mi.Vector3f, sigma: mi.Vector3f, width) -> mi.Vector3f:
    """The history clipped per YCoCg channel to ``mean ± width σ``, back in RGB."""
    return from_ycocg(dr.clip(history_ycocg, mean - width * sigma, mean + width * sigma))


def temporal_gradient(current_mean_y: mi.Float, history_mean_y: mi.Float, v: FilterValues) -> mi.Float:
    """A-SVGF's ``λ`` from the box means of ``Y`` of the current frame and the fast history."""
    delta = dr.abs(current_mean_y - history_mean_y) / (
        dr.maximum(dr.maximum(current_mean_y, history_mean_y), 0.0) + GRADIENT_FLOOR)
    return dr.clip(v.antilag_gain * (delta - v.antilag_threshold), 0.0, 1.0)


def temporal_accumulation(frame: FrameArrays, history: ASVGFHistory | None, index: mi.UInt32 | None,
                          valid: mi.Bool | None, p: ASVGFParams, v: FilterValues, gradient: mi.Float | None = None,
                          statistics: dict | None = None) -> tuple[mi.Vector3f, mi.Vector3f, mi.Vector2f, mi.Float]:
    """Steps 1-5 but the variance: (fast, slow, moments, length) of this frame;
    ``gradient``, where given, is λ per pixel instead of step 1's estimate.
    ``statistics``, where given, receives what the step decided on the way
    (``valid``, ``gradient`` λ, ``slow_history`` and ``slow_clipped``, the
    back-projected slow history before and after its clip), for a caller that
    learns from them; it changes nothing that is returned."""
    c = frame.color
    lum = luminance(c)
    moments = mi.Vector2f(lum, lum * lum)
    if history is None:
        return c, c, moments, dr.full(mi.Float, 1.0, dr.width(lum))
    mean_c, sigma_c = box_statistics(frame, to_ycocg(c), p.box_radius)
    fast = dr.gather(mi.Vector3f, history.fast, index, valid)
    slow = dr.gather(mi.Vector3f, history.slow, index, valid)
    previous_moments = dr.gather(mi.Vector2f, history.moments, index, valid)
    previous_length = dr.gather(mi.Float, history.length, index, valid)
    valid = valid & dr.all(dr.isfinite(fast)) & dr.all(dr.isfinite(slow))
    fast = dr.select(valid, fast, c)
    if gradient is None:  # λ needs the fast history's box mean of Y alone
        lam = temporal_gradient(mean_c.x, box_mean(to_ycocg(fast).x, frame.width, frame.height, p.box_radius), v)
    else:
        lam = gradient
    length = dr.select(valid, dr.minimum(1.0 + previous_length * (1.0 - lam), v.slow_frames), 1.0)
    alpha = 1.0 / length
    fast = dr.lerp(clip_ycocg(to_ycocg(fast), mean_c, sigma_c, v.fast_clip), c,
                   dr.maximum(alpha, 1.0 / v.fast_frames))
    fast = dr.select(valid, fast, c)
    dr.eval(fast)
    if dr.grad_enabled(fast):  # a fit differentiates through the box's sigma
        mean_fast, sigma_fast = differentiable_box_statistics(frame, to_ycocg(fast), p.clip_radius)
    else:  # the same statistics in one pass over the box, sigma about the centre (no cancellation)
        mean_fast, sigma_fast = box_statistics(frame, to_ycocg(fast), p.clip_radius)
    clipped = clip_ycocg(to_ycocg(slow), mean_fast, sigma_fast, v.clip_width)
    if statistics is not None:
        statistics.update(valid=valid, gradient=lam, slow_history=slow, slow_clipped=clipped)
    slow = dr.lerp(clipped, c, alpha)
    slow = dr.select(valid, slow, c)
    moments = dr.select(valid, dr.lerp(previous_moments, moments, alpha), moments)
    return fast, slow, moments, length


def variance(frame: FrameArrays, moments: mi.Vector2f, length: mi.Float, p: ASVGFParams, v: FilterValues) -> mi.Float:
    """SVGF's variance from the blended moments; below ``variance_frames`` of
    history the current frame's spatial estimate times ``variance_frames / n``
    (computed on those pixels only, with SVGF's edge weights; its factor ``n_detached / n`` is 1 but
    carries the derivative with respect to ``n``)."""
    temporal = dr.maximum(moments.y - moments.x * moments.x, 0.0)
    lum = luminance(dr.detach(frame.color))
    detached = dr.detach(length)
    spatial = estimate_variance(frame, mi.Vector2f(lum, lum * lum), detached,
                                SVGFParams(variance_frames=p.variance_frames, spatial_radius=p.spatial_radius))
    return dr.select(detached < p.variance_frames, spatial * (detached / length), temporal)


def wide_blend(wide: mi.Vector3f, regular: mi.Vector3f, length: mi.Float, v: FilterValues) -> mi.Vector3f:
    """The output: the wide level where the history is short, the last regular one once it
    is ``wide_frames`` frames long."""
    return dr.lerp(wide, regular, dr.clip((length - 1.0) / v.wide_frames, 0.0, 1.0))


def asvgf(frame: FrameArrays, p: ASVGFParams, history: ASVGFHistory | None = None, index: mi.UInt32 | None = None,
          valid: mi.Bool | None = None, values: FilterValues | None = None, gradient: mi.Float | None = None,
          images: list | None = None) -> tuple[mi.TensorXf, ASVGFHistory]:
    """One frame on ``frame.color``; ``index``/``valid`` are the back
    projection onto the frame that ``history`` belongs to. ``values``
    overrides ``p``'s continuous parameters (Dr.Jit Floats to differentiate);
    ``gradient`` gives λ per pixel (from gradient samples, or from the ground
    truth in :mod:`benchmarks.asvgf_bounds`) instead of step 1's estimate;
    ``images``, where given, receives the slow history and every À-Trous
    level's output, the wide ones too (demodulated tensors, in that order).
    Returns (the filtered colour, the history for the next frame)."""
    v = FilterValues.of(p) if values is None else values.widened(dr.width(frame.color))
    fast, slow, moments, length = temporal_accumulation(frame, history, index, valid, p, v, gradient)
    dr.eval(fast, slow, moments, length)
    var = variance(frame, moments, length, p, v)
    color, feedback = slow, slow
    if images is not None:
        images.append(frame.tensor(slow))
    levels = p.levels if p.levels is not None else levels_for(frame.width)
    for level in range(levels):
        color, var = atrous_level(frame, color, var, 1 << level, v)
        dr.eval(color, var)
        if images is not None:
            images.append(frame.tensor(color))
        if level == min(p.feedback_level, levels - 1):
            feedback = color
    if p.wide_levels:
        wide = color
        for level in range(levels, levels + p.wide_levels):
            wide, var = atrous_level(frame, wide, var, 1 << level, v)
            dr.eval(wide, var)
            if images is not None:
                images.append(frame.tensor(wide))
        color = wide_blend(wide, color, length, v)
    return frame.tensor(color), ASVGFHistory(fast, feedback, moments, length)


#: the fitted parameters (written by ``python -m denoise.fit``), asvgf's defaults where given
PARAMETER_FILE = Path(__file__).resolve().parents[1] / "asvgf_params.json"
#: the largest parameter file read, in bytes
MAX_PARAMETER_BYTES = 64 << 10


def _fitted(key: str, default: float, help: str, low: float, high: float, **more) -> Option:
    return Option(key, default, help, low=low, high=high, default_text=f"fitted (hand-set {default:g})",
                  **{"group": "asvgf", **more})


#: the continuous parameters :mod:`denoise.fit` fits, with their hand-set values and the ranges it keeps to
FITTED_OPTIONS = (
    _fitted("sigma_luminance", 4.0, "luminance weight", 1e-3, 1e3, unit="standard deviations", step=0.1,
            span=(0.1, 32.0), group="svgf"),
    _fitted("normal_exponent", 128.0, "normal weight max(0, n.n')^exponent", 1e-3, 1e4, step=1.0,
            span=(1.0, 256.0), group="svgf"),
    replace(edge_options()[2], default=0.1, low=1e-4, high=1e3, open_low=False, default_text="fitted (hand-set 0.1)"),
    _fitted("slow_frames", 16.0, "the longest history", 1.0, 256.0, unit="frames", step=1.0, span=(1.0, 64.0)),
    _fitted("fast_frames", 3.0, "the fast history's 1/alpha", 1.0, 256.0, unit="frames"),
    _fitted("clip_width", 1.0, "the slow history clipped to the fast one's mean +- this sigma", 0.0, 100.0,
            step=0.05, span=(0.05, 8.0)),
    _fitted("fast_clip", 2.0, "the fast history clipped to the current frame's mean +- this sigma", 0.0, 100.0),
    _fitted("antilag_gain", 2.0, "anti-lag: lambda = clip(gain (delta - threshold), 0, 1)", 0.0, 1e3),
    _fitted("antilag_threshold", 0.25, "anti-lag: the temporal gradient below which nothing is forgotten",
            0.0, 10.0),
    _fitted("wide_frames", 16.0, "up to this history length the wide levels' output is blended in", 1.0, 256.0,
            unit="frames"),
)


def load_parameter_file(path: Path | None = None) -> dict[str, float]:
    """The fitted parameters of ``path`` (default :data:`PARAMETER_FILE`; ``{}``
    where there is no file); a damaged file, an unknown key or a value out of
    its declared range is one line naming the file."""
    path = PARAMETER_FILE if path is None else path
    if not path.is_file():
        return {}
    options = {o.key: o for o in FITTED_OPTIONS}
    try:
        data = read_json(path, MAX_PARAMETER_BYTES)
    except JSONInputError as error:
        raise UsageError(f"{path}: not a JSON parameter file ({str(error).removeprefix(f'{path}: ')})") from None
    values = data.get("parameters") if isinstance(data, dict) else None
    if not isinstance(values, dict) or set(values) - set(options):
        raise UsageError(f"{path}: expected {{\"parameters\": {{NAME: number}}}} with names from {', '.join(options)}")
    for key, value in values.items():
        try:
            options[key].check(value, str(path))
        except UsageError as error:
            raise UsageError(f"{error} (parameter {key})") from None
    return {key: float(value) for key, value in values.items()}


def hand_set(**changes) -> ASVGFParams:
    """The kernel's parameters as set by hand (the declarations' defaults), ``changes`` applied."""
    return ASVGFParams(**{**{o.key: o.default for o in FITTED_OPTIONS}, **changes})


def fitted(**changes) -> ASVGFParams:
    """The kernel's parameters as fitted (:data:`PARAMETER_FILE`, read now), ``changes`` applied."""
    return hand_set(**{**load_parameter_file(), **changes})


class ASVGF(DenoisingMethod):
    """SVGF with a fast and a slow history, colour-box clipping of both and
    anti-lag (the kernels above): where the current frame departs from the
    back-projected fast history beyond its noise (a light switched, a shadow or
    highlight moved), the history is shortened at once, so nothing trails
    behind. Its continuous parameters are fitted by ``python -m denoise.fit``
    (``denoise/asvgf_params.json``, read when the method is made: the defaults
    here). Temporal by nature (``--no-temporal``: no history); it always
    demodulates by the albedo when the frames have one.
    """
    name = "asvgf"
    description = "SVGF with fast and slow histories, history clipping and anti-lag (A-SVGF, Schied et al. 2018)"
    temporal_by_nature = True
    demodulates = True
    options = (levels_option(None, "as svgf, from the width"),) + FITTED_OPTIONS
    benchmark = ("asvgf",)
    data_files = (PARAMETER_FILE,)

    @classmethod
    def defaults(cls) -> dict:
        return {**super().defaults(), **load_parameter_file()}

    def __init__(self, **props):
        super().__init__(**props)
        self.params = ASVGFParams(**{o.key: self.props[o.key] for o in self.options})

    def filter(self, arrays, frame, index, valid):
        result, self.history = asvgf(arrays, self.params, self.history if index is not None else None, index, valid)
        return result
