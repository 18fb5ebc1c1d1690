"""Denoising a frame folder: spatial filter, back projection, temporal accumulation."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from imaging.image_io import write_exr

from .frames import FrameData, frame_indices, read_frame
from .filters import BilateralParams, Frame, TemporalParams, accumulate, atrous, joint_bilateral, reproject

METHODS = ("bilateral", "atrous")


@dataclass(frozen=True)
class DenoiseOptions:
    method: str = "atrous"
    temporal: bool = True
    levels: int = 5
    bilateral: BilateralParams = field(default_factory=BilateralParams)
    temporal_params: TemporalParams = field(default_factory=TemporalParams)


class Denoiser:
    """Stateful: each :meth:`step` denoises the next frame using the previous output."""

    def __init__(self, options: DenoiseOptions = DenoiseOptions()):
        if options.method not in METHODS:
            raise ValueError(f"unknown method {options.method!r}; choose from {', '.join(METHODS)}")
        self.options = options
        self.previous: tuple[FrameData, object] | None = None

    def step(self, frame: FrameData) -> np.ndarray:
        import mitsuba as mi

        def tensor(a):
            return mi.TensorXf(np.ascontiguousarray(a, np.float32))

        buffers = Frame(tensor(frame.beauty), tensor(frame.normal), tensor(frame.position))
        o = self.options
        filtered = atrous(buffers, o.bilateral, o.levels) if o.method == "atrous" else joint_bilateral(buffers, o.bilateral)
        result = filtered
        if o.temporal and self.previous is not None:
            before, before_result = self.previous
            if before.beauty.shape != frame.beauty.shape:
                raise ValueError(f"frame size changed from {before.beauty.shape[:2]} to {frame.beauty.shape[:2]}")
            index, valid = reproject(tensor(frame.position), tensor(frame.ids), tensor(before.ids),
                                     frame.object_to_world, before.object_to_world, before.world_to_screen)
            result = accumulate(filtered, before_result, index, valid, o.temporal_params)
        self.previous = (frame, result)
        return np.array(result, np.float32)


def denoise_folder(source: Path, target: Path, options: DenoiseOptions = DenoiseOptions()) -> list[Path]:
    """Denoises every frame of ``source`` into ``target/result_i.exr``."""
    indices = frame_indices(source)
    if not indices:
        raise FileNotFoundError(f"{source}: no beauty_<i>.exr frames")
    if indices != list(range(indices[0], indices[0] + len(indices))):
        missing = sorted(set(range(indices[0], indices[-1] + 1)) - set(indices))
        raise FileNotFoundError(f"{source}: frames {missing} are missing")
    denoiser, written = Denoiser(options), []
    for index in tqdm(indices, desc="denoising", unit="frame", delay=1.0, leave=False):
        result = denoiser.step(read_frame(source, index))
        path = target / f"result_{index}.exr"
        write_exr(path, {"": result})
        written.append(path)
    return written
