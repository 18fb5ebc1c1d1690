"""The assignment's joint bilateral filter, with clamped temporal accumulation."""
from __future__ import annotations

from ..filters import BilateralWindow, joint_bilateral
from .base import Option, SpatialFilterMethod, edge_options, edge_weights, temporal_options


class Bilateral(SpatialFilterMethod):
    """Joint bilateral filter over a (2 radius + 1)² window on the G-buffers
    (:func:`denoise.filters.joint_bilateral`): each neighbour weighted by
    ``exp(-d²/(2 sigma_coord²))`` and the edge-stopping weights on colour,
    normal angle and plane distance; then, with ``temporal``, blended with the
    back-projected previous result clamped to the current 7x7 mean ± k sigma.
    """
    name = "bilateral"
    description = ("the assignment's joint bilateral filter ((2 radius + 1)^2 window); bilateral+temporal: "
                   "blended with the back-projected, clamped previous result")
    window_defaults = BilateralWindow()
    options = edge_options() + (
        Option("radius", window_defaults.radius, "window (2 radius + 1)^2", kind=int, low=0, high=64, step=1,
               span=(0, 16), group="bilateral window"),
        Option("sigma_coord", window_defaults.sigma_coord, "the spatial sigma", unit="pixels", low=0.0,
               open_low=True, group="bilateral window"),
    ) + temporal_options(SpatialFilterMethod.temporal_defaults)
    benchmark = ("bilateral", "bilateral+temporal")

    def __init__(self, **props):
        super().__init__(**props)
        self.edges = edge_weights(self.props)
        self.window = BilateralWindow(self.props["radius"], self.props["sigma_coord"])

    def spatial(self, arrays):
        return joint_bilateral(arrays, self.edges, self.window)
