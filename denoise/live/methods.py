"""The methods the live page offers and the sliders of each: the one place
that turns a method name and slider values into :class:`DenoiseOptions`.

Names are ``raw`` (no denoising) and those of
:func:`denoise.pipeline.parse_method`: every ``python -m denoise --method``
plus the temporal variants of the filters that have one. Each slider is a
:class:`Slider` (a field of one of the options' parameter blocks, with the
range the page offers); :func:`options_for` builds the options, so a change
of how methods are registered touches only this module.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

RAW = "raw"
#: what the page lists, in its order
METHOD_NAMES = (RAW, "bilateral", "bilateral+temporal", "atrous", "atrous+temporal", "svgf",
                "oidn", "oidn+temporal", "oidn-guided")


@dataclass(frozen=True)
class Slider:
    """One parameter: ``block`` is the DenoiseOptions field holding it
    (``edges``, ``svgf``, ...), ``field`` its name there."""
    name: str
    block: str
    field: str
    low: float
    high: float
    step: float
    whole: bool = False

    def as_json(self, options) -> dict:
        return {"name": self.name, "low": self.low, "high": self.high, "step": self.step,
                "value": getattr(getattr(options, self.block), self.field)}


EDGES = (Slider("sigma_color", "edges", "sigma_color", 0.01, 4.0, 0.01),
         Slider("sigma_normal", "edges", "sigma_normal", 0.01, 2.0, 0.01),
         Slider("sigma_plane", "edges", "sigma_plane", 0.01, 2.0, 0.01))
TEMPORAL = (Slider("alpha", "temporal_params", "alpha", 0.01, 1.0, 0.01),
            Slider("k", "temporal_params", "k", 0.0, 8.0, 0.1))
SLIDERS = {
    RAW: (),
    "bilateral": EDGES + (Slider("radius", "window", "radius", 0, 16, 1, whole=True),),
    "atrous": EDGES + (Slider("levels", "atrous", "levels", 1, 8, 1, whole=True),),
    "svgf": (Slider("sigma_luminance", "svgf", "sigma_luminance", 0.1, 32.0, 0.1),
             Slider("normal_exponent", "svgf", "sigma_normal", 1.0, 256.0, 1.0),
             Slider("sigma_plane", "svgf", "sigma_plane", 0.01, 2.0, 0.01),
             Slider("alpha_color", "svgf", "alpha_color", 0.01, 1.0, 0.01),
             Slider("levels", "svgf", "levels", 1, 8, 1, whole=True)),
    "oidn": (),
    "oidn+temporal": (Slider("alpha", "oidn_temporal", "alpha", 0.01, 1.0, 0.01),
                      Slider("k", "oidn_temporal", "k", 0.0, 8.0, 0.1)),
    "oidn-guided": (Slider("alpha", "oidn_guided", "alpha", 0.01, 1.0, 0.01),
                    Slider("k", "oidn_guided", "k", 0.0, 8.0, 0.1)),
}
SLIDERS["bilateral+temporal"] = SLIDERS["bilateral"] + TEMPORAL
SLIDERS["atrous+temporal"] = SLIDERS["atrous"] + TEMPORAL


def base_options(name: str, width: int):
    """The :class:`DenoiseOptions` of method ``name`` before any slider (None
    for ``raw``); SVGF's levels made explicit for a ``width``-pixel image."""
    # imported here: the denoiser loads Dr.Jit, which must wait until the libLLVM is chosen
    from denoise.pipeline import parse_method
    from denoise.svgf import levels_for

    if name == RAW:
        return None
    options = parse_method(name)
    if options.method == "svgf":
        options = replace(options, svgf=replace(options.svgf, levels=levels_for(width)))
    return options


def options_for(name: str, width: int, values: dict[str, float]):
    """The options of method ``name`` with slider ``values`` (name -> value,
    each already checked against its :class:`Slider`'s range)."""
    options = base_options(name, width)
    if options is None:
        return None
    sliders = {s.name: s for s in SLIDERS[name]}
    for key, value in values.items():
        slider = sliders[key]
        block = getattr(options, slider.block)
        options = replace(options, **{slider.block: replace(block, **{slider.field: int(value) if slider.whole
                                                                        else float(value)})})
    return options


def describe(name: str, width: int, values: dict[str, float]) -> list[dict]:
    """The sliders of ``name`` with their current values, for the page."""
    options = options_for(name, width, values)
    return [s.as_json(options) for s in SLIDERS[name]] if options is not None else []
