"""Spatiotemporal variance-guided filtering as a method."""
from __future__ import annotations

from ..svgf import SVGFParams, svgf
from .base import DenoisingMethod, Option, levels_option

PAPER = SVGFParams()


class SVGF(DenoisingMethod):
    """SVGF (Schied et al. 2017, :mod:`denoise.svgf`): temporal accumulation of
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
