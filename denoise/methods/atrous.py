"""The assignment's À-Trous wavelet filter, with clamped temporal accumulation."""
from __future__ import annotations

from ..filters import AtrousLevels, atrous
from .base import SpatialFilterMethod, edge_options, edge_weights, levels_option, temporal_options


class Atrous(SpatialFilterMethod):
    """À-Trous wavelet filter (:func:`denoise.filters.atrous`): ``levels``
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
