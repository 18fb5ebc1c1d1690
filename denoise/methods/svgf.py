"""Spatiotemporal variance-guided filtering as a method."""
from __future__ import annotations

from core.errors import UsageError

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

    Parameters:

    - ``--levels`` (int 1..12; default: the paper's 5 at 1280 pixels wide,
      one fewer per halving of the width, :func:`denoise.svgf.levels_for`);
    - ``--sigma-luminance`` (float > 0, 4): the luminance weight, in standard
      deviations;
    - ``--normal-exponent`` (float > 0, 128): the normal weight
      ``max(0, n.n')^exponent``.
    """
    name = "svgf"
    description = "spatiotemporal variance-guided filtering (Schied et al. 2017)"
    temporal_by_nature = True
    demodulates = True
    options = (
        levels_option(PAPER.levels, "the paper's 5 at 1280 pixels wide, one fewer per halving of the width"),
        Option("--sigma-luminance", PAPER.sigma_luminance, "luminance weight, in standard deviations",
               group="svgf"),
        Option("--normal-exponent", PAPER.sigma_normal, "normal weight max(0, n.n')^exponent", group="svgf"),
    )
    benchmark = ("svgf",)

    def __init__(self, **props):
        super().__init__(**props)
        try:
            self.params = SVGFParams(levels=self.props["levels"], sigma_luminance=self.props["sigma_luminance"],
                                     sigma_normal=self.props["normal_exponent"])
        except UsageError as error:  # name the command's option, not the parameter
            raise UsageError(str(error).replace("sigma_normal", "--normal-exponent")
                             .replace("sigma_luminance", "--sigma-luminance")) from None

    def filter(self, arrays, frame, index, valid):
        result, self.history, _ = svgf(arrays, self.params, self.history if index is not None else None,
                                       index, valid)
        return result
