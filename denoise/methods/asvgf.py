"""A-SVGF-style filtering that does not lag, as a method, and its fitted parameters."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from core.errors import UsageError
from core.json_input import JSONInputError, read_json

from ..asvgf import ASVGFParams, asvgf
from .base import DenoisingMethod, Option, edge_options, levels_option

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
    anti-lag (:mod:`denoise.asvgf`): where the current frame departs from the
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

    @classmethod
    def defaults(cls) -> dict:
        return {**super().defaults(), **load_parameter_file()}

    def __init__(self, **props):
        super().__init__(**props)
        self.params = ASVGFParams(**{o.key: self.props[o.key] for o in self.options})

    def filter(self, arrays, frame, index, valid):
        result, self.history = asvgf(arrays, self.params, self.history if index is not None else None, index, valid)
        return result
