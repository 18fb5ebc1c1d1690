"""OIDN on the accumulated input, the history clamped by OIDN's own output."""
from __future__ import annotations

from ..filters import TemporalParams
from .base import temporal_options
from .oidn import OIDNMethod


class OIDNGuided(OIDNMethod):
    """OIDN twice per frame. First on the frame alone: that output (the guide)
    is a low-noise estimate of the current frame, whose 3x3 neighbourhood
    (mean ± k sigma, the usual TAA neighbourhood clamp) clamps the
    back-projected history of the accumulated input; then on the input
    accumulated with that clamped history. A clamp from the 1-spp input's own
    neighbourhood is too wide to stop a moving shadow or highlight from
    lagging; the guide's is tight. Temporal by nature (``--no-temporal``:
    OIDN on each frame alone, once).
    """
    name = "oidn-guided"
    description = ("OIDN on the input accumulated over time, its history clamped to the neighbourhood of "
                   "OIDN's output on the frame alone (two OIDN runs per frame)")
    temporal_by_nature = True
    temporal_defaults = TemporalParams(alpha=0.5, k=1.0, clamp_radius=1)
    options = (OIDNMethod.quality,) + temporal_options(temporal_defaults)
    presets = {}
    benchmark = ("oidn-guided",)

    def history_bounds(self, color, frame):
        return self.run_oidn(color, frame)
