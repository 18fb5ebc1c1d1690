"""The course binary's command line as data, and the checks of its numbers.

A :class:`RenderJob` is what ``render.py`` renders and what ``python -m
converters`` writes as XML; both refuse the same numbers here, before anything
is loaded (``renderer.checks`` adds the memory the render would need).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from core.errors import LimitError, UsageError
from mi_plugins.aovs import AOV_CHANNELS

from .description import RenderOptions

#: Every AOV, in the order the EXR stores them
ALL_AOVS = tuple(AOV_CHANNELS)
JITTER_SPP = 16
FILTER_SCALE = 3
#: Deepest mirror recursion accepted. Each bounce multiplies by the mirror's
#: specular colour; past a few dozen bounces nothing changes in an 8-bit image
#: unless mirrors reflect nearly all light, and a huge count (1e9) would only
#: make two parallel mirrors loop for hours.
MAX_BOUNCES = 1000
#: Mitsuba and Dr.Jit index the samples of one render (pixels x samples per
#: pixel, x9 with -filter) with 32-bit integers; beyond this they crash (SIGSEGV).
MAX_SAMPLES = 2**32 - 1
#: Largest --spp, so that huge numbers are refused as a count, not as memory
MAX_SPP = 2**20


@dataclass(frozen=True)
class DepthOutput:
    near: float
    far: float
    path: Path


@dataclass(frozen=True)
class RenderJob:
    """The course binary's command line, as data."""
    scene: Path
    width: int = 800
    height: int = 800
    output: Path | None = None  # beauty image (8-bit, course encoding; .exr writes float)
    normals: Path | None = None
    depth: DepthOutput | None = None
    exr: Path | None = None  # multilayer EXR: beauty and every AOV
    bounces: int = 0
    shadows: bool = False
    jitter: bool = False  # 16 jittered samples per pixel
    filter: bool = False  # render 3x larger, then the course's 3x3 Gaussian
    spp: int | None = None  # overrides the sample count (default 1, or 16 with jitter)
    stats: bool = False  # count what the render traces (see RenderResult.stats)

    @property
    def aovs(self) -> tuple[str, ...]:
        """Only the AOVs some output needs."""
        if self.exr is not None:
            return ALL_AOVS
        return tuple(name for name, wanted in (("depth", self.depth is not None),
                                               ("normal", self.normals is not None)) if wanted)

    def options(self) -> RenderOptions:
        scale = FILTER_SCALE if self.filter else 1
        spp = self.spp if self.spp is not None else (JITTER_SPP if self.jitter else 1)
        return RenderOptions(width=self.width * scale, height=self.height * scale, bounces=self.bounces,
                             shadows=self.shadows, spp=spp, jitter=self.jitter, aovs=self.aovs, stats=self.stats)


def check_numbers(width: int, height: int, bounces: int, spp: int | None) -> None:
    """The command line's numbers, before anything is loaded."""
    if width < 1 or height < 1:
        raise UsageError(f"-size wants positive numbers, got {width} {height}")
    if not 0 <= bounces <= MAX_BOUNCES:
        raise UsageError(f"-bounces wants a number in 0..{MAX_BOUNCES}, got {bounces}")
    if spp is not None and not 1 <= spp <= MAX_SPP:
        raise UsageError(f"--spp wants a number in 1..{MAX_SPP}, got {spp}")


def render_samples(job) -> int:
    options = job.options()
    return options.width * options.height * options.spp


def check_samples(job: RenderJob) -> None:
    """The samples of one render, which Mitsuba indexes with 32-bit integers."""
    options = job.options()
    samples = render_samples(job)
    if samples > MAX_SAMPLES:
        what = f"{options.width}x{options.height} pixels x {options.spp} spp"
        if job.filter:
            what += " (-filter renders at 3x)"
        raise LimitError(f"{samples:,} samples ({what}) exceed the {MAX_SAMPLES:,} that one render can index "
                         f"(32-bit); use a smaller -size or fewer samples")
