"""Denoising a frame folder with one method (:mod:`denoise.methods`): the
folder checked first, then frame by frame, each result written as it comes.
"""
from __future__ import annotations

import json
import re
import stat
import sys
from contextlib import suppress
from dataclasses import dataclass, field
from pathlib import Path

from tqdm import tqdm

from core.entry import check_stopped
from core.errors import FrameError, OutputError
from export import Spec
from export.files import locked
from export.frames import frame_indices, missing_between, missing_files, read_frame
from export.ground_truth import check_export_finished
from export.store import write_record
from imaging.image_io import check_writable, exr_size, write_exr
from renderer.checks import check_memory

from .methods.base import DenoisingMethod


def check_folder(source: Path, require_albedo: bool = False) -> list[int]:
    """The frame indices of ``source``, which must be consecutive, each with
    every required file, and albedo for all frames or for none (for every
    frame where ``require_albedo``): checked before any frame is denoised."""
    if not source.is_dir():
        raise FrameError(f"{source}: not a folder")
    indices = frame_indices(source)
    if not indices:
        raise FrameError(f"{source}: no beauty_<i>.exr frames")
    check_export_finished(source, indices)
    gap = missing_between(indices)
    if gap:
        more = f" (and {gap[1] - 1} more frames)" if gap[1] > 1 else ""
        raise FrameError(f"{source}: frames {indices[0]}..{indices[-1]} without {source / f'beauty_{gap[0]}.exr'}"
                         f"{more}; frames must be consecutive")
    for index in indices:
        missing = missing_files(source, index)
        if missing:
            raise FrameError(f"{source}: frame {index} lacks {', '.join(missing)}")
    with_albedo = [i for i in indices if (source / f"albedo_{i}.exr").exists()]
    if require_albedo and len(with_albedo) < len(indices):
        lacking = sorted(set(indices) - set(with_albedo))
        raise FrameError(f"{source}: demodulation (--demodulate, or demod+ in the method's name) needs albedo_i.exr, "
                         f"and frame {lacking[0]} has none"
                         + (f" ({len(lacking)} frames lack it)" if len(lacking) > 1 else ""))
    if 0 < len(with_albedo) < len(indices):
        lacking = sorted(set(indices) - set(with_albedo))
        raise FrameError(f"{source / f'albedo_{lacking[0]}.exr'}: missing, while frame {with_albedo[0]} has its "
                         "albedo (every frame or none)")
    return indices


#: what denoising a frame holds at its peak, per pixel, and what the process holds besides:
#: above the peak of every built-in method (measured at 1280x720: docs/denoising.md)
BYTES_PER_PIXEL, BASE_BYTES = 900, 512 * 2 ** 20


def check_frames_fit(first: Path, memory: int | None = None) -> None:
    """Frames of ``first``'s size (its header read alone) within the memory
    available (``memory``: bytes; measured if None): else a :class:`LimitError`
    before any frame, not a process killed for memory in the first."""
    size = exr_size(first)
    if size is not None:
        check_memory(BASE_BYTES + BYTES_PER_PIXEL * size[0] * size[1],
                     f"{first}: denoising {size[0]}x{size[1]} frames", "denoise smaller frames", memory=memory)


def check_sequences_fit(doing: str, loaded: list[tuple[Path, Spec]], needed: int, remedy: str,
                        memory: int | None = None) -> None:
    """``needed`` bytes for a command that holds every frame of the sequences
    ``loaded`` at once (``doing``: "training", "fitting") within the memory
    available, else a :class:`LimitError` naming the largest, before anything is rendered."""
    frames = sum(spec.frames for _, spec in loaded)
    path, spec = max(loaded, key=lambda item: item[1].size[0] * item[1].size[1])
    check_memory(needed, f"{doing} on {frames} frames held at once (the largest {spec.size[0]}x{spec.size[1]}, "
                 f"{path})", remedy, memory=memory)


@dataclass
class FolderReport:
    """What :func:`denoise_folder` did: the results written, and how many
    beauty values were not usable (NaN, inf, beyond
    :data:`denoise.methods.base.RADIANCE_LIMIT`)."""
    written: list[Path] = field(default_factory=list)
    replaced_values: int = 0
    frames_with_replaced: int = 0
    removed: int = 0  # results the last run into the target left, which this run did not replace


#: what python -m denoise writes into its OUT_DIR: result_i.exr, and with --png result_i.png
RESULT_NAME = re.compile(r"result_(0|[1-9][0-9]*)\.(exr|png)", re.ASCII)
#: the record, in OUT_DIR, of the results a run wrote there: all that the next run may remove
RESULTS_RECORD = "denoise_results.json"

#: seconds before the progress bar shows (a short run shows none)
PROGRESS_DELAY_S = 1.0


def identity(path: Path) -> tuple[int, int] | None:
    """``path``'s inode and modification time where it is a plain file (not a link), else None:
    a file that a later write replaced (written whole, then renamed over it) has others."""
    try:
        status = path.lstat()
    except OSError:
        return None
    return (status.st_ino, status.st_mtime_ns) if stat.S_ISREG(status.st_mode) else None


def result_files(target: Path) -> dict[Path, tuple[int, int]]:
    """The plain files named as :data:`RESULT_NAME` in ``target``, with their :func:`identity`."""
    found = {}
    if target.is_dir():
        for path in target.iterdir():
            if RESULT_NAME.fullmatch(path.name) and (mark := identity(path)) is not None:
                found[path] = mark
    return found


def last_run_results(target: Path) -> dict[Path, tuple[int, int]]:
    """The results that the last run into ``target`` recorded (:data:`RESULTS_RECORD`),
    each with the :func:`identity` it had then; none where there is no readable record."""
    try:
        files = json.loads((target / RESULTS_RECORD).read_text())["files"]
        return {target / name: tuple(mark) for name, mark in files.items() if RESULT_NAME.fullmatch(name)}
    except (OSError, ValueError, TypeError, KeyError, AttributeError):
        return {}


def results_since(target: Path, before: dict) -> dict[str, list]:
    """This run's results in ``target``: the result files not as they were ``before``, by name, with their identity."""
    return {path.name: list(mark) for path, mark in result_files(target).items() if before.get(path) != mark}


def record_results(target: Path, source: Path, method: DenoisingMethod, files: dict[str, list]) -> None:
    write_record(target / RESULTS_RECORD, {"source": str(source.absolute()), "method": method.name, "files": files})


def record_progress(target: Path, source: Path, method: DenoisingMethod, last: dict, before: dict) -> None:
    """Records this run's results so far with the last run's results still as it wrote them:
    a run that ends before :func:`finish_results` (the watchdog after a stop signal, a kill)
    leaves the next run every one of them to remove."""
    files = {path.name: list(mark) for path, mark in last.items() if identity(path) == mark}
    record_results(target, source, method, {**files, **results_since(target, before)})


def finish_results(target: Path, source: Path, method: DenoisingMethod, last: dict, before: dict) -> int:
    """After a run that wrote results into ``target``: removes the last run's
    results (``last``, :func:`last_run_results`) that are still the files it
    wrote (neither replaced by this run nor by anyone since), and records
    this run's (the result files that are not as they were ``before`` it).
    Returns how many were removed."""
    removed = 0
    for path, mark in last.items():
        if identity(path) == mark:
            try:
                path.unlink()
            except OSError as error:
                raise OutputError(f"{path}: a result of the last run cannot be removed ({error.strerror or error})"
                                  ) from None
            removed += 1
    record_results(target, source, method, results_since(target, before))
    return removed


def check_results_writable(target: Path, indices: list[int], suffixes: tuple[str, ...]) -> None:
    """Every result ``target/result_i<suffix>`` of the frames ``indices`` can be written: a folder
    or a read-only file in the place of one is refused before the first frame, not at its own."""
    for index in indices:
        for suffix in suffixes:
            check_writable("OUT_DIR", target / f"result_{index}{suffix}")


def denoise_folder(source: Path, target: Path, method: DenoisingMethod, on_frame=None,
                   require_albedo: bool = False, suffixes: tuple[str, ...] = (".exr",)) -> FolderReport:
    """Denoises every frame of ``source`` with ``method`` (a fresh one: it keeps
    its history) into ``target/result_i.exr``; ``on_frame(index, frame,
    result)`` is called after each (previews). The folder's files are checked
    before the first frame; a frame that turns out damaged later stops the
    run with the results before it kept, as the error says. Once a result is
    written, however the run ends, the results the last run recorded in
    ``target`` (:data:`RESULTS_RECORD`) that this run did not replace are
    removed, and this run's recorded: the folder never holds two runs'
    results, and no file the runs did not write is removed. ``target`` is
    locked meanwhile (a second run into it is refused). The progress bar is
    shown only when stderr is a terminal. ``suffixes``: the results written
    for each frame (``on_frame`` writes those besides ``.exr``), checked
    writable before the first frame."""
    indices = check_folder(source, require_albedo)
    check_frames_fit(source / f"beauty_{indices[0]}.exr")
    check_results_writable(target, indices, suffixes)
    report = FolderReport()
    made = missing_folders(target)
    try:
        with locked([target], doing="denoise"):
            last, before = last_run_results(target), result_files(target)
            try:
                def frame_done(index, frame, result):
                    if on_frame is not None:
                        on_frame(index, frame, result)
                    with suppress(OutputError):  # a full disk is said by the next result's error, or the end's
                        record_progress(target, source, method, last, before)

                run_frames(source, target, method, indices, report, frame_done)
            except BaseException:
                # a result is on disk from its rename on: a stop signal may raise before write_exr returns
                if report.written or results_since(target, before):
                    with suppress(OutputError):  # the error is what the user needs to read, not a failed clean-up
                        finish_results(target, source, method, last, before)
                raise
            report.removed = finish_results(target, source, method, last, before)
    finally:
        if not report.written:  # a run stopped before its first result leaves no empty OUT_DIR
            for folder in made:
                with suppress(OSError):
                    folder.rmdir()  # only an empty folder goes
    return report


def missing_folders(target: Path) -> list[Path]:
    """``target`` and those of its parents that do not exist yet (a run makes them), deepest first."""
    missing, folder = [], Path(target).absolute()
    while not folder.exists() and not folder.is_symlink() and folder != folder.parent:
        missing.append(folder)
        folder = folder.parent
    return missing


def run_frames(source: Path, target: Path, method: DenoisingMethod, indices: list[int], report: FolderReport,
               on_frame) -> None:
    """:func:`denoise_folder`'s loop over the frames ``indices``, recording what it writes in ``report``."""
    size = None
    for index in tqdm(indices, desc="denoising", unit="frame", delay=PROGRESS_DELAY_S, leave=False,
                      file=sys.stderr, disable=not sys.stderr.isatty()):
        try:
            frame = read_frame(source, index)
            if size is None:
                size = frame.beauty.shape[:2]
            elif frame.beauty.shape[:2] != size:
                raise FrameError(f"{source / f'beauty_{index}.exr'}: {frame.beauty.shape[1]}x"
                                 f"{frame.beauty.shape[0]} pixels, but frame {indices[0]} has {size[1]}x{size[0]}")
            result = method.step(frame)
            check_stopped()  # nothing written after a stop signal, whatever the method made of it
            path = target / f"result_{index}.exr"
            write_exr(path, {"": result})
        except (FrameError, OutputError) as error:
            if report.written:
                done = (f"the result of frame {indices[0]} was" if index - 1 == indices[0]
                        else f"the results of frames {indices[0]} to {index - 1} were")
                raise type(error)(f"{error} ({done} written to {target}; none from frame {index} on)") from None
            raise
        report.written.append(path)
        report.replaced_values += method.last_replaced
        report.frames_with_replaced += method.last_replaced > 0
        if on_frame is not None:
            check_stopped()
            on_frame(index, frame, result)
