"""What every denoising method shares: its options, the frame's clean-up, albedo
demodulation, outlier removal and the back projection onto the previous frame.

A method is one subclass of :class:`DenoisingMethod` (one module each, listed in
:mod:`denoise.methods`) that declares its :class:`Option` s and overrides the
:meth:`DenoisingMethod.filter` hook, as Dr.Jit's optimizers override a few
methods of ``drjit.opt.Optimizer``. :class:`SpatialFilterMethod` is the base
of a spatial filter followed by clamped temporal accumulation: its subclasses
override :meth:`SpatialFilterMethod.spatial` alone.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import drjit as dr
import mitsuba as mi
import numpy as np

from core.errors import FrameError
from core.numbers import ascii_float, ascii_int

from ..filters import (
    EdgeWeights,
    FrameArrays,
    OutlierParams,
    TemporalParams,
    accumulate,
    demodulate,
    remodulate,
    remove_outliers,
    reproject,
)
from ..frames import FrameData

#: beauty values beyond +-this are clamped to it (NaN and inf become 0) before any filter:
#: squared differences and second moments of 49 such values stay finite in float32
RADIANCE_LIMIT = 1e12
#: positions beyond +-this are clamped to it (no scene is that large in float32 anyway)
POSITION_LIMIT = 1e15


def clamp_finite(values: np.ndarray, limit: float) -> tuple[np.ndarray, int]:
    """``values`` with NaN and inf set to 0 and the rest clamped to +-``limit``,
    and how many values that changed."""
    if values.size == 0 or (values.min() >= -limit and values.max() <= limit):  # NaN fails both: slow path
        return values, 0
    finite = np.isfinite(values)
    changed = int(values.size - np.count_nonzero(finite & (np.abs(values) <= limit)))
    return np.clip(np.where(finite, values, 0.0), -limit, limit).astype(np.float32), changed


@dataclass(frozen=True)
class Option:
    """One parameter of a method, and its command-line option.

    ``flag`` is the option (``--sigma-color``), ``key`` the parameter's name in
    the method's keyword arguments (by default the flag's words joined by
    ``_``), ``default`` the value when it is not given. ``kind`` is the argparse
    ``type`` (or, for ``action``, the argparse action of a switch).
    ``group`` titles the ``--help`` section the option is listed in (``None``:
    the options every method has). Methods that share an option declare the
    same flag, type, help and group; their defaults may differ, and ``--help``
    lists each. ``default_text`` replaces the default's value in ``--help``."""
    flag: str
    default: object
    help: str
    kind: Callable | None = ascii_float
    group: str | None = None
    key: str = ""
    action: str | None = None
    choices: tuple | None = None
    metavar: str | None = None
    default_text: str | None = None

    def __post_init__(self):
        if not self.key:
            object.__setattr__(self, "key", self.flag.lstrip("-").replace("-", "_"))


def temporal_options(defaults: TemporalParams) -> tuple[Option, Option]:
    """``--alpha`` and ``--k`` of the clamped temporal accumulation, with ``defaults``' values."""
    group = "temporal accumulation"
    return (Option("--alpha", defaults.alpha, "weight of the current frame, in (0, 1]", group=group),
            Option("--k", defaults.k, "clamp the history to the neighbourhood's mean +- k sigma, k >= 0",
                   group=group))


def temporal_params(props: dict, defaults: TemporalParams) -> TemporalParams:
    """The accumulation of :func:`temporal_options`' parameters (checked), clamped
    over ``defaults``' radius."""
    return TemporalParams(alpha=props["alpha"], k=props["k"], clamp_radius=defaults.clamp_radius)


def levels_option(default: int | None, default_text: str | None = None) -> Option:
    """``--levels``, the À-Trous passes (``default_text`` where the default is computed)."""
    return Option("--levels", default, "passes, 1..12", kind=ascii_int, group="a-trous levels",
                  default_text=default_text)


def edge_options() -> tuple[Option, Option, Option]:
    """The assignment's edge-stopping sigmas (:class:`denoise.filters.EdgeWeights`)."""
    defaults, group = EdgeWeights(), "edge-stopping weights"
    return (Option("--sigma-color", defaults.sigma_color, "on the colour difference", group=group),
            Option("--sigma-normal", defaults.sigma_normal, "on the normals' angle in radians", group=group),
            Option("--sigma-plane", defaults.sigma_plane, "on the plane distance", group=group))


def edge_weights(props: dict) -> EdgeWeights:
    """The edge weights of :func:`edge_options`' parameters (checked)."""
    return EdgeWeights(props["sigma_color"], props["sigma_normal"], props["sigma_plane"])


class DenoisingMethod:
    """The base of every denoising method: :meth:`step` denoises the next frame
    of a sequence, keeping what the method needs of the previous one.

    Per frame, :meth:`step` makes the buffers usable (:meth:`usable_frame`),
    divides the colour by the albedo where the method demodulates and the
    frame has one, clamps outliers where asked, back-projects every pixel onto
    the previous frame where the method is temporal, and calls the hook
    :meth:`filter`; then it multiplies the albedo back and keeps the frame as
    the previous one.

    Parameters every method has (``--no-temporal``, ``--demodulate``,
    ``--outliers``):

    - ``temporal`` (bool, True): back-project onto the previous frame (off:
      each frame on its own, ``index`` and ``valid`` are always ``None``);
    - ``demodulate`` (bool, False): filter ``beauty / albedo`` and multiply
      back; a class with ``demodulates`` ``True`` (always) or ``False``
      (never) overrides it;
    - ``outliers`` (float or None, None): clamp each pixel's luminance to its
      7x7 mean +- this many sigma first (None: no clamp).

    A subclass sets ``name`` (its ``--method`` choice), ``description`` (one
    line for ``--help`` and the docs), ``options`` (its own parameters, read
    from ``self.props`` in its ``__init__``) and ``benchmark`` (the names
    ``python -m benchmarks.denoise`` runs it under, see
    :func:`denoise.methods.from_name`), and overrides :meth:`filter`.
    """
    name: str = ""
    description: str = ""
    options: tuple[Option, ...] = ()
    #: the benchmark runs it with history even without ``+temporal`` in its name
    temporal_by_nature: bool = False
    #: None: as the ``demodulate`` parameter says; True or False: always or never
    demodulates: bool | None = None
    #: the names the benchmark runs, ``[demod+][outliers+]NAME[-PRESET][+temporal]``
    benchmark: tuple[str, ...] = ()
    #: named parameter sets for benchmark names (``oidn-fast``: ``{"oidn_quality": "fast"}``)
    presets: dict[str, dict] = {}

    common_options = (
        Option("--no-temporal", True, "each frame on its own (no history)", kind=None, key="temporal",
               action="store_false"),
        Option("--demodulate", False, "filter beauty / albedo and multiply back (needs albedo_i.exr for every "
               "frame; svgf does so whenever the frames have it)", kind=None, action="store_true"),
        Option("--outliers", None, f"first clamp each pixel's luminance to its 7x7 mean +- K sigma (off by "
               f"default; {OutlierParams().k:g} is a usual K)", metavar="K"),
    )

    @classmethod
    def all_options(cls) -> tuple[Option, ...]:
        return cls.common_options + cls.options

    def __init__(self, **props):
        options = {o.key: o for o in self.all_options()}
        unknown = set(props) - set(options)
        if unknown:
            raise TypeError(f"{self.name}: no parameter {sorted(unknown)[0]!r}")
        #: every parameter's value: the given ones, the declared defaults for the rest
        self.props = {key: props.get(key, option.default) for key, option in options.items()}
        self.temporal = bool(self.props["temporal"])
        self.demodulate = bool(self.props["demodulate"]) if self.demodulates is None else self.demodulates
        k = self.props["outliers"]
        self.outliers = None if k is None else OutlierParams(k=k)
        self.previous: FrameData | None = None
        self.previous_ids = None  # the previous frame's ids, uploaded once
        self.history = None  # what the method keeps of the previous frame (its own format)
        self.last_replaced = 0  # beauty values of the last frame that were not usable (see usable_frame())
        self.last_execute_s = None  # None: the whole step is the method's time; else the part worth timing
        self.last_execute_cpu_s = None  # the same as this process's CPU time (all threads)

    def usable_frame(self, frame: FrameData) -> FrameData:
        """``frame`` with every buffer the filters and OIDN read made usable
        (:func:`clamp_finite`): beauty and albedo within +-:data:`RADIANCE_LIMIT`,
        normal and position within +-:data:`POSITION_LIMIT` (a normal's length
        then stays finite in float32); counts the beauty values replaced."""
        beauty, self.last_replaced = clamp_finite(frame.beauty, RADIANCE_LIMIT)
        normal, _ = clamp_finite(frame.normal, POSITION_LIMIT)
        position, _ = clamp_finite(frame.position, POSITION_LIMIT)
        albedo = None if frame.albedo is None else clamp_finite(frame.albedo, RADIANCE_LIMIT)[0]
        return replace(frame, beauty=beauty, normal=normal, position=position, albedo=albedo)

    def step(self, frame: FrameData) -> np.ndarray:
        """The next frame denoised, (H, W, 3) float32."""
        def tensor(a):
            return mi.TensorXf(np.ascontiguousarray(a, np.float32))

        if self.previous is not None and self.previous.beauty.shape != frame.beauty.shape:
            raise FrameError(f"frame size changed from {self.previous.beauty.shape[1]}x"
                             f"{self.previous.beauty.shape[0]} to {frame.beauty.shape[1]}x{frame.beauty.shape[0]}")
        frame = self.usable_frame(frame)
        color = tensor(frame.beauty)
        position = tensor(frame.position)
        ids = tensor(frame.ids)
        albedo = tensor(frame.albedo) if self.demodulate and frame.albedo is not None else None
        if albedo is not None:
            color = demodulate(color, albedo)
        if self.outliers is not None:
            color = remove_outliers(color, self.outliers)
        index = valid = None
        if self.temporal and self.previous is not None:
            index, valid = reproject(position, ids, self.previous_ids, frame.object_to_world,
                                     self.previous.object_to_world, self.previous.world_to_screen)
        result = self.filter(FrameArrays(color, tensor(frame.normal), position), frame, index, valid)
        if albedo is not None:
            result = remodulate(result, albedo)
        dr.eval(result.array)
        self.previous, self.previous_ids = frame, ids
        return np.array(result, np.float32)

    def filter(self, arrays: FrameArrays, frame: FrameData, index: mi.UInt32 | None,
               valid: mi.Bool | None) -> mi.TensorXf:
        """The hook: this frame denoised, (H, W, 3).

        ``arrays`` holds the colour to filter (demodulated and outlier-clamped
        as asked), normal and position as Dr.Jit arrays; ``frame`` the same
        frame as NumPy arrays, its buffers made usable (albedo, ids, matrices);
        ``index`` and ``valid`` the back projection (:func:`denoise.filters.reproject`)
        onto the previous frame, ``None`` on the first frame or without
        ``temporal``. Keep what the next frame needs in ``self.history``."""
        raise NotImplementedError


class SpatialFilterMethod(DenoisingMethod):
    """A spatial filter, then the clamped temporal accumulation
    ``alpha C + (1 - alpha) clamp(history)`` of its output: subclasses
    override :meth:`spatial`. ``temporal_defaults`` gives ``--alpha`` and
    ``--k`` their defaults and the clamp its radius."""
    temporal_defaults = TemporalParams()

    def __init__(self, **props):
        super().__init__(**props)
        self.temporal_params = temporal_params(self.props, self.temporal_defaults)

    def spatial(self, arrays: FrameArrays) -> mi.TensorXf:
        """The hook: the frame filtered on its own."""
        raise NotImplementedError

    def filter(self, arrays, frame, index, valid):
        result = self.spatial(arrays)
        if index is not None:
            result = accumulate(result, self.history, index, valid, self.temporal_params)
        self.history = result
        return result
