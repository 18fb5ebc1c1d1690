"""Every input of a render checked before any work starts.

A render that cannot succeed must fail in the first second with one line,
not after minutes of rendering, and never with a signal:

- numbers: ``-size`` and ``--spp`` positive, ``-bounces`` in 0..:data:`MAX_BOUNCES`;
- limits (:class:`LimitError`): the samples of one render must be indexable
  by the variant (:data:`MAX_SAMPLES`) and the memory the render needs
  (:func:`render_memory`) must be available (:func:`available_memory`);
- outputs (:class:`OutputError`): a known format per flag, no two outputs on
  one file (also across the lines of a batch, and across named scenes that
  map to the same ``<out>/<stem>.png``), no folder where a file should go, a
  folder that exists or can be created, and permission to write there;
  no output on a file the render reads (the scene, its meshes, cube-map faces).
"""
from __future__ import annotations

import os
import resource
from pathlib import Path

from converters.render_flags import (  # noqa: F401 (MAX_*, check_numbers re-exported for the CLI)
    MAX_BOUNCES,
    MAX_SAMPLES,
    MAX_SPP,
    check_numbers,
    check_samples,
)
from core.errors import LimitError, OutputError
from imaging.image_io import check_writable
from mi_plugins.aovs import AOV_CHANNELS

#: Peak memory per film pixel and channel, in float32 copies: Mitsuba's image
#: block, the developed film, the NumPy copy, the split layers and the encoded
#: files (the peak measured with /usr/bin/time -v: docs/rendering.md)
COPIES = 6
#: Film channels besides the AOVs: R, G, B, alpha and the filter weight
BEAUTY_CHANNELS = 5
#: What the process needs besides the film (Mitsuba, Dr.Jit, LLVM, the scene)
BASELINE_BYTES = 400 * 2**20
#: Image formats per flag, by suffix
IMAGE_SUFFIXES = (".png", ".bmp", ".tga", ".exr")


def render_memory(job) -> int:
    """Bytes a render of ``job`` needs at its peak (see :data:`COPIES`)."""
    options = job.options()
    channels = BEAUTY_CHANNELS + sum(len(AOV_CHANNELS[name]) for name in job.aovs)
    return BASELINE_BYTES + options.width * options.height * channels * 4 * COPIES


def available_memory() -> int | None:
    """Bytes this process may still allocate: the least of the system's
    available memory, the cgroup's remaining limit and the address-space limit."""
    limits = []
    try:
        with open("/proc/meminfo") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    limits.append(int(line.split()[1]) * 1024)
    except (OSError, ValueError, IndexError):
        try:
            limits.append(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
        except (OSError, ValueError):
            pass
    try:
        maximum = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        if maximum != "max":
            current = int(Path("/sys/fs/cgroup/memory.current").read_text())
            limits.append(int(maximum) - current)
    except (OSError, ValueError):
        pass
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft != resource.RLIM_INFINITY:
        limits.append(soft)
    return min(limits) if limits else None


def check_memory(needed: int, what: str, remedy: str, need: str | None = None, memory: int | None = None) -> None:
    """A :class:`LimitError` ``WHAT needs about N GiB of memory, but M GiB is
    available; REMEDY`` where ``needed`` bytes exceed the memory available
    (``memory``; measured if None; no check where it cannot be measured):
    raised before the work, which would otherwise be killed for memory."""
    memory = available_memory() if memory is None else memory
    if memory is not None and needed > memory:
        raise LimitError(f"{what} needs about {_gib(needed)} of memory, but {_gib(memory)} is available", remedy, need)


def _gib(n: int) -> str:
    return f"{n / 2**30:.1f} GiB"


def check_limits(job, memory: int | None = None) -> None:
    """Samples and memory of one render (``memory``: bytes available; measured if None)."""
    options = job.options()
    what = f"{options.width}x{options.height} pixels x {options.spp} spp"
    if job.filter:
        what += " (-filter renders at 3x)"
    check_samples(job)
    memory = available_memory() if memory is None else memory
    needed = render_memory(job)
    if memory is not None and needed > memory:
        channels = (needed - BASELINE_BYTES) // (options.width * options.height * 4 * COPIES)
        raise LimitError(f"the render needs about {_gib(needed)} of memory ({what}, {channels} float "
                         f"channels) but {_gib(memory)} is available; "
                         f"use a smaller -size, or fewer outputs")


def job_outputs(job) -> list[tuple[str, Path]]:
    """``(flag, path)`` for every file ``job`` writes."""
    outputs = []
    if job.output is not None:
        outputs.append(("-output", job.output))
    if job.normals is not None:
        outputs.append(("-normals", job.normals))
    if job.depth is not None:
        outputs.append(("-depth", job.depth.path))
    if job.exr is not None:
        outputs.append(("--exr", job.exr))
    return outputs


def job_inputs(job) -> list[tuple[str, Path]]:
    """``(what, path)`` for every file ``job`` reads: the scene, its meshes and cube-map faces."""
    from converters.course_scene import referenced_files  # noqa: PLC0415  NumPy loads on use: --help stays quick

    return [("the scene", Path(job.scene))] + [("the input", path) for path in referenced_files(job.scene)]


def _same_file(output: Path, source: Path) -> bool:
    """``output`` is ``source`` (through links, relative spellings or hard links)."""
    if _identity(output) == _identity(source):
        return True
    try:
        return os.path.samefile(output, source)
    except (OSError, ValueError):  # one of them does not exist: not one file
        return False


def _identity(path: Path) -> str:
    """Two spellings of one file (relative, through links) give one identity."""
    return os.path.normcase(os.path.realpath(path))


def check_outputs(job, seen: dict[str, str] | None = None, extra: list[tuple[str, Path]] = ()) -> None:
    """Formats, distinct files and writability of ``job``'s outputs (and of
    ``extra`` ``(flag, path)`` ones).

    ``seen`` maps the files of earlier jobs (of a batch, or of other named
    scenes) to who writes them; this job's files are added to it.
    """
    seen = {} if seen is None else seen
    inputs = job_inputs(job)
    for flag, path in job_outputs(job) + list(extra):
        suffix = path.suffix.lower()
        if flag == "--exr" and suffix != ".exr":
            raise OutputError(f"--exr {path}: expected a .exr file name, found {suffix or 'no suffix'}")
        if flag == "--png" and suffix != ".png":
            raise OutputError(f"--png {path}: expected a .png file name")
        if suffix not in IMAGE_SUFFIXES:
            raise OutputError(f"{flag} {path}: unknown image format {suffix or '(no suffix)'}; "
                              f"use {', '.join(IMAGE_SUFFIXES)}")
        identity = _identity(path)
        writer = f"{flag} {path}"
        if identity in seen:
            raise OutputError(f"{writer}: the same file as {seen[identity]}; give each output its own file")
        for what, source in inputs:
            if _same_file(path, source):
                raise OutputError(f"{writer}: the same file as {what} {source}, which the render reads; "
                                  f"writing it would destroy it")
        check_writable(flag, path)
        seen[identity] = writer


def check_jobs(jobs, seen: dict[str, str] | None = None, memory: int | None = None) -> None:
    """Everything about ``jobs`` that can be known before loading a scene."""
    seen = {} if seen is None else seen
    for job in jobs:
        check_limits(job, memory)
        check_outputs(job, seen)
