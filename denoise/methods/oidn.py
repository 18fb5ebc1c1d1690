"""Intel Open Image Denoise as a method, after our temporal accumulation."""
from __future__ import annotations

import time

import mitsuba as mi
import numpy as np

from ..filters import TemporalParams, accumulate
from ..oidn import OIDN, QUALITIES, OIDNParams
from .base import DenoisingMethod, Option, temporal_options, temporal_params


class OIDNMethod(DenoisingMethod):
    """Intel Open Image Denoise (:mod:`denoise.oidn`; HDR, the frame's albedo and
    normals as clean auxiliary images, one filter committed per image size).
    With ``temporal``, the input is first accumulated with the back-projected
    history clamped to its 7x7 mean ± k sigma, and OIDN denoises the
    accumulated colour; without, OIDN denoises each frame alone. It never
    demodulates (OIDN takes the albedo itself).

    The accumulation before OIDN keeps more of the current frame and clamps
    more loosely than the one after a spatial filter: OIDN removes the noise
    that lets through (the measurement is in docs/denoising_methods.md).

    :attr:`last_execute_s` and :attr:`last_execute_cpu_s` are the OIDN execute
    calls' wall and CPU time of the last frame (what the benchmark times).
    """
    name = "oidn"
    description = ("Intel Open Image Denoise (HDR, albedo and normals); oidn+temporal: with temporal "
                   "accumulation first")
    demodulates = False
    temporal_defaults = TemporalParams(alpha=0.5, k=3.0)
    quality = Option("oidn_quality", OIDNParams().quality, "OIDN 2's filter quality", kind=str, choices=QUALITIES,
                     group="oidn")
    options = (quality,) + temporal_options(temporal_defaults)
    presets = {q: {"oidn_quality": q} for q in QUALITIES}
    benchmark = tuple(f"oidn-{q}" for q in QUALITIES) + ("oidn+temporal",)

    def __init__(self, **props):
        super().__init__(**props)
        self.params = OIDNParams(quality=self.props["oidn_quality"])
        self.temporal_params = temporal_params(self.props, self.temporal_defaults)
        self.oidn = None  # made on the first frame: checking parameters must not load the library

    def run_oidn(self, color: mi.TensorXf, frame) -> mi.TensorXf:
        """OIDN on ``color`` with the frame's albedo and normals; adds its execute time."""
        if self.oidn is None:
            self.oidn = OIDN(self.params)
        self.oidn.set_inputs(np.array(color, np.float32), frame.albedo, frame.normal)
        start, cpu = time.perf_counter(), time.process_time()
        self.oidn.execute()
        self.last_execute_s += time.perf_counter() - start
        self.last_execute_cpu_s += time.process_time() - cpu
        return mi.TensorXf(self.oidn.output())

    def filter(self, arrays, frame, index, valid):
        self.last_execute_s = self.last_execute_cpu_s = 0.0
        color = accumulated = arrays.tensor(arrays.color)
        if index is not None:
            accumulated = accumulate(color, self.history, index, valid, self.temporal_params,
                                     bounds=self.history_bounds(color, frame))
        self.history = accumulated
        return self.run_oidn(accumulated, frame)

    def history_bounds(self, color: mi.TensorXf, frame) -> mi.TensorXf | None:
        """The hook: the image whose neighbourhood clamps the history (None: ``color``'s own)."""
        return None
