"""Denoising a frame folder: optional outlier removal and albedo demodulation,
a spatial filter or SVGF or OIDN, back projection and temporal accumulation.

Methods (``DenoiseOptions.method``):

- ``bilateral``, ``atrous``: the assignment's filters; with ``temporal`` the
  filtered frame is blended with the back-projected, clamped previous result;
- ``svgf``: :mod:`denoise.svgf` (its own temporal accumulation; ``temporal``
  off means no history);
- ``oidn``: Intel Open Image Denoise (:mod:`denoise.oidn`); with
  ``temporal``, our back projection and clamped accumulation on the input
  first, then OIDN on the accumulated colour (``oidn+temporal``);
- ``oidn-guided``: OIDN twice per frame. First on the frame alone: that
  output (the guide) is a low-noise estimate of the current frame, whose 3x3
  neighbourhood (mean ± kσ) clamps the back-projected history of the
  accumulated input; then on the input accumulated with that clamped
  history. A clamp from the 1-spp input's own neighbourhood is too wide to
  stop a moving shadow or highlight from lagging (``oidn+temporal`` on
  glossy_shadow); the guide's is tight.

``outliers`` clamps each pixel's luminance to its neighbourhood's mean ± kσ
before filtering; ``demodulate`` filters ``beauty / albedo`` and multiplies
back (frames without ``albedo_i.exr`` are filtered as they are).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from core.errors import FrameError, UsageError
from imaging.image_io import write_exr

from .filters import (AtrousLevels, BilateralWindow, EdgeWeights, FrameArrays, OutlierParams, TemporalParams,
                      accumulate, atrous, demodulate, joint_bilateral, remodulate, remove_outliers, reproject)
from .frames import FrameData, frame_indices, missing_files, read_frame
from .oidn import OIDNParams
from .svgf import SVGFParams, svgf

METHODS = ("bilateral", "atrous", "svgf", "oidn", "oidn-guided")
#: methods that carry their own temporal accumulation
TEMPORAL_BY_NATURE = ("svgf", "oidn-guided")


@dataclass(frozen=True)
class DenoiseOptions:
    method: str = "atrous"
    temporal: bool = True
    edges: EdgeWeights = field(default_factory=EdgeWeights)
    window: BilateralWindow = field(default_factory=BilateralWindow)
    atrous: AtrousLevels = field(default_factory=AtrousLevels)
    temporal_params: TemporalParams = field(default_factory=TemporalParams)
    svgf: SVGFParams = field(default_factory=SVGFParams)
    oidn: OIDNParams = field(default_factory=OIDNParams)
    #: the accumulation before OIDN: a larger current weight and a looser clamp than after a
    #: spatial filter (chosen on dolly_lamps, frames 0-5: relMSE 0.0027 against 0.0053 with 0.2 and 1)
    oidn_temporal: TemporalParams = field(default_factory=lambda: TemporalParams(alpha=0.5, k=3.0))
    #: oidn-guided's accumulation: the same current weight, the history clamped to the
    #: guide's 3x3 mean ± 1σ (the usual TAA neighbourhood clamp)
    oidn_guided: TemporalParams = field(default_factory=lambda: TemporalParams(alpha=0.5, k=1.0, clamp_radius=1))
    outliers: OutlierParams | None = None  # None: no outlier removal
    demodulate: bool = False

    def __post_init__(self):
        if self.method not in METHODS:
            raise UsageError(f"unknown method {self.method!r}; choose from {', '.join(METHODS)}")


def parse_method(name: str) -> DenoiseOptions:
    """Options from a benchmark name: ``[demod+][outliers+]METHOD[+temporal]``,
    e.g. ``atrous+temporal``, ``oidn``, ``demod+outliers+atrous+temporal``;
    ``svgf`` and ``oidn-guided`` are temporal by nature (``svgf`` demodulates
    when an albedo is there)."""
    parts = name.split("+")
    method = next((p for p in parts if p in METHODS), None)
    unknown = set(parts) - set(METHODS) - {"temporal", "demod", "outliers"}
    if method is None or unknown:
        raise UsageError(f"unknown method {name!r}")
    temporal = "temporal" in parts or method in TEMPORAL_BY_NATURE
    return DenoiseOptions(method=method, temporal=temporal, demodulate="demod" in parts or method == "svgf",
                          outliers=OutlierParams() if "outliers" in parts else None)


class Denoiser:
    """Stateful: each :meth:`step` denoises the next frame using the history."""

    def __init__(self, options: DenoiseOptions = DenoiseOptions()):
        self.options = options
        self.previous: FrameData | None = None
        self.previous_ids = None  # the previous frame's ids, uploaded once
        self.history = None  # the previous result (or SVGF's history, or the accumulated input for OIDN)
        self.oidn = None
        if options.method in ("oidn", "oidn-guided"):
            from .oidn import OIDN

            self.oidn = OIDN(options.oidn)
        self.last_replaced = 0  # beauty values of the last frame that were not usable (see usable())
        self.last_execute_s = 0.0  # OIDN's execute time of the last frame (both runs for oidn-guided)
        self.last_execute_cpu_s = 0.0  # the same as this process's CPU time (all threads)

    def _oidn(self, color, frame: FrameData):
        """OIDN on ``color`` with the frame's albedo and normals; adds its execute time."""
        import time

        import mitsuba as mi

        self.oidn.set_inputs(np.array(color, np.float32), frame.albedo, frame.normal)
        start, cpu = time.perf_counter(), time.process_time()
        self.oidn.execute()
        self.last_execute_s += time.perf_counter() - start
        self.last_execute_cpu_s += time.process_time() - cpu
        return mi.TensorXf(self.oidn.output())

    def usable_frame(self, frame: FrameData) -> FrameData:
        """``frame`` with every buffer the filters and OIDN read made usable
        (:func:`usable`): beauty and albedo within +-:data:`RADIANCE_LIMIT`,
        normal and position within +-:data:`POSITION_LIMIT` (a normal's length
        then stays finite in float32); counts the beauty values replaced."""
        from dataclasses import replace

        beauty, self.last_replaced = usable(frame.beauty, RADIANCE_LIMIT)
        normal, _ = usable(frame.normal, POSITION_LIMIT)
        position, _ = usable(frame.position, POSITION_LIMIT)
        albedo = None if frame.albedo is None else usable(frame.albedo, RADIANCE_LIMIT)[0]
        return replace(frame, beauty=beauty, normal=normal, position=position, albedo=albedo)

    def step(self, frame: FrameData) -> np.ndarray:
        import drjit as dr
        import mitsuba as mi

        def tensor(a):
            return mi.TensorXf(np.ascontiguousarray(a, np.float32))

        o = self.options
        if self.previous is not None and self.previous.beauty.shape != frame.beauty.shape:
            raise FrameError(f"frame size changed from {self.previous.beauty.shape[1]}x"
                             f"{self.previous.beauty.shape[0]} to {frame.beauty.shape[1]}x{frame.beauty.shape[0]}")
        frame = self.usable_frame(frame)
        color = tensor(frame.beauty)
        position = tensor(frame.position)
        ids = tensor(frame.ids)
        albedo = (tensor(frame.albedo) if (o.demodulate and frame.albedo is not None and not o.method.startswith("oidn"))
                  else None)
        if albedo is not None:
            color = demodulate(color, albedo)
        if o.outliers is not None:
            color = remove_outliers(color, o.outliers)
        index = valid = None
        if o.temporal and self.previous is not None:
            index, valid = reproject(position, ids, self.previous_ids, frame.object_to_world,
                                     self.previous.object_to_world, self.previous.world_to_screen)
        buffers = FrameArrays(color, tensor(frame.normal), position)
        if o.method == "svgf":
            result, self.history, _ = svgf(buffers, o.svgf, self.history if index is not None else None, index, valid)
        elif o.method == "oidn":
            self.last_execute_s = self.last_execute_cpu_s = 0.0
            accumulated = color
            if index is not None:
                accumulated = accumulate(color, self.history, index, valid, o.oidn_temporal)
            self.history = accumulated
            result = self._oidn(accumulated, frame)
        elif o.method == "oidn-guided":
            self.last_execute_s = self.last_execute_cpu_s = 0.0
            accumulated = color
            if index is not None:
                guide = self._oidn(color, frame)
                accumulated = accumulate(color, self.history, index, valid, o.oidn_guided, bounds=guide)
            self.history = accumulated
            result = self._oidn(accumulated, frame)
        else:
            result = (atrous(buffers, o.edges, o.atrous) if o.method == "atrous"
                      else joint_bilateral(buffers, o.edges, o.window))
            if index is not None:
                result = accumulate(result, self.history, index, valid, o.temporal_params)
            self.history = result
        if albedo is not None:
            result = remodulate(result, albedo)
        dr.eval(result.array)
        self.previous, self.previous_ids = frame, ids
        return np.array(result, np.float32)


def check_folder(source: Path, require_albedo: bool = False) -> list[int]:
    """The frame indices of ``source``, which must be consecutive, each with
    every required file, and albedo for all frames or for none (for every
    frame where ``require_albedo``): checked before any frame is denoised."""
    if not source.is_dir():
        raise FrameError(f"{source}: not a folder")
    indices = frame_indices(source)
    if not indices:
        raise FrameError(f"{source}: no beauty_<i>.exr frames")
    if indices != list(range(indices[0], indices[0] + len(indices))):
        missing = sorted(set(range(indices[0], indices[-1] + 1)) - set(indices))
        raise FrameError(f"{source}: frames {missing} are missing")
    for index in indices:
        missing = missing_files(source, index)
        if missing:
            raise FrameError(f"{source}: frame {index} lacks {', '.join(missing)}")
    with_albedo = [i for i in indices if (source / f"albedo_{i}.exr").exists()]
    if require_albedo and len(with_albedo) < len(indices):
        lacking = sorted(set(indices) - set(with_albedo))
        raise FrameError(f"{source}: --demodulate needs albedo_i.exr, and frame {lacking[0]} has none"
                         + (f" ({len(lacking)} frames lack it)" if len(lacking) > 1 else ""))
    if 0 < len(with_albedo) < len(indices):
        lacking = sorted(set(indices) - set(with_albedo))
        raise FrameError(f"{source / f'albedo_{lacking[0]}.exr'}: missing, while frame {with_albedo[0]} has its "
                         "albedo (every frame or none)")
    return indices


#: beauty values beyond +-this are clamped to it (NaN and inf become 0) before any filter:
#: squared differences and second moments of 49 such values stay finite in float32
RADIANCE_LIMIT = 1e12
#: positions beyond +-this are clamped to it (no scene is that large in float32 anyway)
POSITION_LIMIT = 1e15


def usable(values: np.ndarray, limit: float) -> tuple[np.ndarray, int]:
    """``values`` with NaN and inf set to 0 and the rest clamped to +-``limit``,
    and how many values that changed."""
    if values.size == 0 or (values.min() >= -limit and values.max() <= limit):  # NaN fails both: slow path
        return values, 0
    finite = np.isfinite(values)
    changed = int(values.size - np.count_nonzero(finite & (np.abs(values) <= limit)))
    return np.clip(np.where(finite, values, 0.0), -limit, limit).astype(np.float32), changed


@dataclass
class FolderReport:
    """What :func:`denoise_folder` did: the results written, and how many
    beauty values were not usable (NaN, inf, beyond :data:`RADIANCE_LIMIT`)."""
    written: list[Path] = field(default_factory=list)
    replaced_values: int = 0
    frames_with_replaced: int = 0


def denoise_folder(source: Path, target: Path, options: DenoiseOptions = DenoiseOptions(),
                   on_frame=None, require_albedo: bool = False) -> FolderReport:
    """Denoises every frame of ``source`` into ``target/result_i.exr``;
    ``on_frame(index, frame, result)`` is called after each (previews). The
    folder's files are checked before the first frame; a frame that turns out
    damaged later stops the run with the results before it kept, as the
    error says."""
    indices = check_folder(source, require_albedo)
    denoiser, report = Denoiser(options), FolderReport()
    size = None
    for index in tqdm(indices, desc="denoising", unit="frame", delay=1.0, leave=False):
        try:
            frame = read_frame(source, index)
            if size is None:
                size = frame.beauty.shape[:2]
            elif frame.beauty.shape[:2] != size:
                raise FrameError(f"{source / f'beauty_{index}.exr'}: {frame.beauty.shape[1]}x"
                                 f"{frame.beauty.shape[0]} pixels, but frame {indices[0]} has {size[1]}x{size[0]}")
            result = denoiser.step(frame)
        except FrameError as error:
            if report.written:
                done = (f"the result of frame {indices[0]} was" if index - 1 == indices[0]
                        else f"the results of frames {indices[0]} to {index - 1} were")
                raise FrameError(f"{error} ({done} written to {target}; none from frame {index} on)") from None
            raise
        path = target / f"result_{index}.exr"
        write_exr(path, {"": result})
        report.written.append(path)
        report.replaced_values += denoiser.last_replaced
        report.frames_with_replaced += denoiser.last_replaced > 0
        if on_frame is not None:
            on_frame(index, frame, result)
    return report
