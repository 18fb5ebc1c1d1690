"""A-SVGF-style filtering that does not lag, as a method."""
from __future__ import annotations

from dataclasses import replace

from core.errors import UsageError

from ..asvgf import ASVGFParams, asvgf
from .base import DenoisingMethod, Option, levels_option

FITTED = ASVGFParams()


class ASVGF(DenoisingMethod):
    """SVGF with a fast and a slow history, colour-box clipping of both and
    anti-lag (:mod:`denoise.asvgf`): where the current frame departs from the
    back-projected fast history beyond its noise (a light switched, a shadow or
    highlight moved), the history is shortened at once, so nothing trails
    behind. Its continuous parameters are fitted by ``python -m denoise.fit``
    (``denoise/asvgf_params.json``, the defaults here). Temporal by nature
    (``--no-temporal``: no history); it always demodulates by the albedo when
    the frames have one.

    Parameters:

    - ``--levels`` (int 1..12; default: as svgf, from the width);
    - ``--sigma-luminance`` (float > 0; fitted): the luminance weight, in
      standard deviations;
    - ``--normal-exponent`` (float > 0; fitted): the normal weight
      ``max(0, n.n')^exponent``;
    - ``--slow-frames`` (float >= 1; fitted): the longest history, in frames;
    - ``--clip-width`` (float >= 0; fitted): the slow history is clipped to the
      fast history's 3x3 mean ± this many sigma.
    """
    name = "asvgf"
    description = "SVGF with fast and slow histories, history clipping and anti-lag (A-SVGF, Schied et al. 2018)"
    temporal_by_nature = True
    demodulates = True
    options = (
        levels_option(FITTED.levels, "as svgf, from the width"),
        Option("--sigma-luminance", FITTED.sigma_luminance, "luminance weight, in standard deviations",
               group="svgf"),
        Option("--normal-exponent", FITTED.sigma_normal, "normal weight max(0, n.n')^exponent", group="svgf"),
        Option("--slow-frames", FITTED.slow_frames, "the longest history, in frames", group="asvgf"),
        Option("--clip-width", FITTED.clip_width, "the slow history clipped to the fast one's mean +- this sigma",
               group="asvgf"),
    )
    benchmark = ("asvgf",)

    def __init__(self, **props):
        super().__init__(**props)
        try:
            self.params = replace(FITTED, levels=self.props["levels"], sigma_luminance=self.props["sigma_luminance"],
                                  sigma_normal=self.props["normal_exponent"], slow_frames=self.props["slow_frames"],
                                  clip_width=self.props["clip_width"])
        except UsageError as error:  # name the command's options, not the parameters
            raise UsageError(str(error).replace("sigma_normal", "--normal-exponent")
                             .replace("sigma_luminance", "--sigma-luminance").replace("slow_frames", "--slow-frames")
                             .replace("clip_width", "--clip-width")) from None

    def filter(self, arrays, frame, index, valid):
        result, self.history = asvgf(arrays, self.params, self.history if index is not None else None, index, valid)
        return result
