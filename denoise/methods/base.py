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

import inspect
import keyword
import math
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

from core.entry import check_stopped, interruption, message_of, stop_received
from core.errors import FrameError, ToolkitError, UsageError
from core.numbers import ascii_float, ascii_int
from export.frames import FrameData

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
from .declarations import ACTIONS, printable, text_problem

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
    """One parameter of a method, declared once: its command-line option, its
    range, its ``--help`` and docs text and its slider on the live page.

    ``key`` is the parameter's name in the method's keyword arguments and its
    kernel's field; the flag is ``--KEY`` with dashes (``--no-KEY`` for a
    ``store_false`` switch). ``default`` is the value when it is not given.
    ``kind`` is ``float``, ``int`` or ``str`` (``None`` for a switch, whose
    argparse ``action`` it has). A number lies from ``low`` to ``high`` (``None``:
    unbounded, yet finite), each end excluded where ``open_low``/``open_high``;
    :meth:`check` refuses any other value in one line naming the flag. ``step``
    gives the number a slider on the live page, moving by ``step`` over
    ``span`` (where the range is wider than a slider is useful) within the
    range. ``unit`` follows the value in ``--help`` and the docs; ``group``
    titles the ``--help`` section (``None``: the options every method has).
    Methods that share an option declare the same key, kind, help, unit and
    group; defaults and ranges may differ, and ``--help`` lists each default.
    ``default_text`` replaces the default's value in ``--help``; ``temporal``
    marks a parameter of the temporal accumulation (of no use without it)."""
    key: str
    default: object
    help: str
    kind: type | None = float
    low: float | None = None
    high: float | None = None
    open_low: bool = False
    open_high: bool = False
    step: float | None = None
    span: tuple[float, float] | None = None
    unit: str = ""
    group: str | None = None
    action: str | None = None
    choices: tuple | None = None
    metavar: str | None = None
    default_text: str | None = None
    temporal: bool = False
    #: where it was declared (``file:line``), for the messages about it
    origin: str = field(default="", compare=False)

    def __post_init__(self):
        if not self.origin:  # the line that called Option(...): the dataclass's __init__ is "<string>"
            where = next((f for f in reversed(traceback.extract_stack()[:-1]) if f.filename != "<string>"), None)
            object.__setattr__(self, "origin", f"{where.filename}:{where.lineno}" if where else "?")
        problem = self.declaration_problem()
        if problem:
            raise DeclarationError(f"{self.origin}: option {self.key!r}: {problem}")

    def declaration_problem(self) -> str | None:
        """What is wrong with this declaration, or None."""
        if not isinstance(self.key, str) or not self.key.isidentifier() or keyword.iskeyword(self.key):
            return "the key must be a Python name that is not a keyword (the parameter's field)"
        if self.kind not in (float, int, str, None) or (self.kind is None) != (self.action is not None):
            return "kind must be float, int or str, or None with an action"
        if self.action is not None and self.action not in ACTIONS:
            return f"action must be one of {', '.join(map(repr, ACTIONS))} (a switch), got {printable(self.action)}"
        problem = text_problem(self)
        if problem:
            return problem
        if self.low is not None and self.high is not None and not self.low <= self.high:
            return f"low {self.low!r} is above high {self.high!r}"
        if self.step is not None and (self.kind not in (float, int) or not self.step > 0):
            return "a slider step needs a number option and a step > 0"
        if self.span is not None and not (isinstance(self.span, tuple) and len(self.span) == 2
                                          and all(isinstance(v, (int, float)) for v in self.span)
                                          and self.span[0] <= self.span[1]):
            return f"span must be (low end, high end) of a slider, got {self.span!r}"
        if self.span is not None and ((self.low is not None and self.span[0] < self.low)
                                      or (self.high is not None and self.span[1] > self.high)):
            return f"span {self.span!r} reaches outside the range ({self.range_text()})"
        if self.step is not None and self.slider_range() is None:
            return "a slider needs finite ends: give low and high, or span"
        if self.action is None and self.default is not None and self.default_text is None:
            try:
                self.check(self.default, "default")
            except UsageError as error:
                return f"its default is out of its range ({str(error).split(': ', 1)[1]})"
        return None

    @property
    def flag(self) -> str:
        words = self.key.replace("_", "-")
        return f"--no-{words}" if self.action == "store_false" else f"--{words}"

    @property
    def parse(self) -> Callable | None:
        """The argparse ``type`` (ASCII digits only)."""
        return {float: ascii_float, int: ascii_int, str: str}.get(self.kind)

    def range_text(self) -> str:
        """The range in words: ``a whole number from 1 to 12``, ``a finite number > 0``."""
        whole = "a whole number" if self.kind is int else "a finite number"
        low, high = self.low, self.high
        if low is not None and high is not None:
            whole = "a whole number" if self.kind is int else "a number"
            if not self.open_low and not self.open_high:
                return f"{whole} from {low:g} to {high:g}"
            return f"{whole} in {'(' if self.open_low else '['}{low:g}, {high:g}{')' if self.open_high else ']'}"
        if low is not None:
            return f"{whole} {'>' if self.open_low else '>='} {low:g}"
        if high is not None:
            return f"{whole} {'<' if self.open_high else '<='} {high:g}"
        return whole

    def check(self, value, owner: str) -> None:
        """A one-line :class:`UsageError` naming ``owner`` and the flag unless
        ``value`` is in the declared range (or choices)."""
        if self.action is not None or (value is None and self.default is None):
            return
        if self.choices is not None:
            if value not in self.choices:
                raise UsageError(f"{owner}: {self.flag} must be one of {', '.join(map(str, self.choices))}, "
                                 f"got {value!r}")
            return
        if self.kind is str:
            return
        number = not isinstance(value, bool) and (isinstance(value, int) if self.kind is int
                                                  else isinstance(value, (int, float)) and math.isfinite(value))
        if not number or (self.low is not None and (value <= self.low if self.open_low else value < self.low)) or (
                self.high is not None and (value >= self.high if self.open_high else value > self.high)):
            raise UsageError(f"{owner}: {self.flag} must be {self.range_text()}, got {value!r}")

    def slider_range(self) -> tuple[float, float] | None:
        """The slider's ends: ``span`` within the range (an excluded end moved in by a step)."""
        low, high = self.span if self.span is not None else (self.low, self.high)
        if low is None or high is None:
            return None
        if self.low is not None:
            low = max(low, self.low + (self.step if self.open_low else 0.0))
        if self.high is not None:
            high = min(high, self.high - (self.step if self.open_high else 0.0))
        return low, high


class MethodError(ToolkitError):
    """A method's ``filter`` that raised or returned something unusable (names
    the method and its file and line)."""


class DeclarationError(UsageError):
    """A method or option declared wrongly (names where), or two methods that
    declare one option differently (names both)."""


def temporal_options(defaults: TemporalParams) -> tuple[Option, Option]:
    """``--alpha`` and ``--k`` of the clamped temporal accumulation, with ``defaults``' values."""
    group = "temporal accumulation"
    return (Option("alpha", defaults.alpha, "weight of the current frame", low=0.0, high=1.0, open_low=True,
                   step=0.01, group=group, temporal=True),
            Option("k", defaults.k, "clamp the history to the neighbourhood's mean +- k sigma", low=0.0,
                   step=0.1, span=(0.0, 8.0), group=group, temporal=True))


def temporal_params(props: dict, defaults: TemporalParams) -> TemporalParams:
    """The accumulation of :func:`temporal_options`' parameters (checked), clamped
    over ``defaults``' radius."""
    return TemporalParams(alpha=props["alpha"], k=props["k"], clamp_radius=defaults.clamp_radius)


def levels_option(default: int | None, default_text: str | None = None) -> Option:
    """``--levels``, the À-Trous passes (``default_text`` where the default is computed)."""
    return Option("levels", default, "passes", kind=int, low=1, high=12, step=1, span=(1, 8), group="a-trous levels",
                  default_text=default_text)


def edge_options() -> tuple[Option, Option, Option]:
    """The assignment's edge-stopping sigmas (:class:`denoise.filters.EdgeWeights`)."""
    defaults, group = EdgeWeights(), "edge-stopping weights"
    positive = dict(low=0.0, open_low=True, step=0.01, group=group)
    return (Option("sigma_color", defaults.sigma_color, "on the colour difference", span=(0.01, 4.0), **positive),
            Option("sigma_normal", defaults.sigma_normal, "on the normals' angle", unit="radians",
                   span=(0.01, 2.0), **positive),
            Option("sigma_plane", defaults.sigma_plane, "on the plane distance", span=(0.01, 2.0), **positive))


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

    Every method has the parameters of :attr:`common_options` (their table is
    generated from the declarations): ``temporal`` back-projects onto the
    previous frame (off: each frame on its own, ``index`` and ``valid`` always
    ``None``); a command names it in the method's name (``atrous+temporal``,
    :func:`denoise.methods.resolve`), and ``--no-temporal`` turns it off for a
    method that is temporal by nature. ``demodulate`` filters ``beauty /
    albedo`` (a class with ``demodulates`` ``True`` or ``False`` overrides it);
    ``outliers`` clamps each pixel's luminance to its 7x7 mean +- this many
    sigma first.

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
    #: the files the method reads unless told otherwise (fitted parameters, trained weights):
    #: no command writes an output onto one (:func:`denoise.methods.data_files`)
    data_files: tuple[Path, ...] = ()

    common_options = (
        Option("temporal", True, "each frame on its own (no history)", kind=None, action="store_false"),
        Option("demodulate", False, "filter beauty / albedo and multiply back (needs albedo_i.exr for every "
               "frame; svgf does so whenever the frames have it)", kind=None, action="store_true"),
        Option("outliers", None, f"first clamp each pixel's luminance to its 7x7 mean +- K sigma (off by "
               f"default; {OutlierParams().k:g} is a usual K)", low=0.0, open_low=True, metavar="K"),
    )

    @classmethod
    def all_options(cls) -> tuple[Option, ...]:
        return cls.common_options + cls.options

    @classmethod
    def defaults(cls) -> dict:
        """Every parameter's default by key: the declarations' (the hook of a
        method whose defaults are read from a file when it is made)."""
        return {o.key: o.default for o in cls.all_options()}

    def __init__(self, **props):
        options = {o.key: o for o in self.all_options()}
        unknown = set(props) - set(options)
        if unknown:
            raise TypeError(f"{self.name}: no parameter {sorted(unknown)[0]!r}")
        for key, value in props.items():
            options[key].check(value, self.name)
        #: every parameter's value: the given ones, the defaults for the rest
        self.props = {**self.defaults(), **props}
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
        try:
            result = self.filter(FrameArrays(color, tensor(frame.normal), position, albedo), frame, index, valid)
        except ToolkitError:
            raise
        except BaseException as error:  # the method's own code failed: where, and what (Ctrl-C stays one)
            if interruption(error) is not None or stop_received() is not None:
                raise
            raise MethodError(f"{self.name} ({self.hook_origin(error)}): {self.hook().__name__}() raised "
                              f"{message_of(error)}") from None
        check_stopped()  # a hook that caught the interruption: it still stops the command
        self.check_result(result, frame.beauty.shape[:2])
        if albedo is not None:
            result = remodulate(result, albedo)
        dr.eval(result.array)
        image = np.array(result, np.float32)
        if not np.isfinite(image).all():
            bad = int(image.size - np.count_nonzero(np.isfinite(image)))
            raise MethodError(f"{self.name} ({self.hook_origin()}): {self.hook().__name__}() returned {bad} "
                              "NaN or infinite values (a result must be finite)")
        self.previous, self.previous_ids = frame, ids
        return image

    def check_result(self, result, size: tuple[int, int]) -> None:
        """A one-line :class:`MethodError` unless the hook's ``result`` is a
        ``mi.TensorXf`` of ``size`` (height, width) by 3."""
        if not isinstance(result, mi.TensorXf):
            raise MethodError(f"{self.name} ({self.hook_origin()}): {self.hook().__name__}() must return a "
                              f"mi.TensorXf (arrays.tensor(...)), got {type(result).__module__}."
                              f"{type(result).__qualname__}")
        if tuple(result.shape) != (*size, 3):
            raise MethodError(f"{self.name} ({self.hook_origin()}): {self.hook().__name__}() must return the "
                              f"frame's shape {(*size, 3)}, got {tuple(result.shape)}")

    def hook(self) -> Callable:
        """The method's own hook: ``filter``, or ``spatial`` where only that is overridden."""
        hook = type(self).filter
        return type(self).spatial if hook is SpatialFilterMethod.filter else hook

    def hook_origin(self, error: BaseException | None = None) -> str:
        """``file:line`` of the method's own hook (:meth:`hook`): the last line of
        that file in ``error``'s traceback, else the hook's ``def``."""
        hook = self.hook()
        try:
            path, line = Path(inspect.getsourcefile(hook)), inspect.getsourcelines(hook)[1]
        except (OSError, TypeError):
            return "?"
        if error is not None:
            lines = [f.lineno for f in traceback.extract_tb(error.__traceback__) if Path(f.filename) == path]
            line = lines[-1] if lines else line
        return f"{path}:{line}"

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
        self.check_result(result, frame.beauty.shape[:2])
        if index is not None:
            result = accumulate(result, self.history, index, valid, self.temporal_params)
        self.history = result
        return result
