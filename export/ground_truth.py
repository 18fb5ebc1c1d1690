"""What a ground-truth folder is, and the checks before anything is judged against it.

``python -m export`` writes a sequence's frames into ``OUT`` (with
``sequence.json``, its settings) and their ground truth into ``OUT_reference``
(with ``ground_truth.json``: what the folder holds, at how many samples per
pixel). A folder given as the truth is refused when it is a frame folder (an
export's, by its record, or any in the course's layout, by its G-buffers),
or when its record says it has no more samples per pixel than the frames it
would judge: every figure against it would be a figure against noise; and
when its record names another sequence than the frame folder's
``sequence.json`` (another spec, size or frame count: its key differs).
Folders without records (a truth rendered elsewhere) are taken as they are.
"""
from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

from core.errors import UsageError
from core.json_input import JSONInputError, read_json

#: a frame folder's settings, written by the export
SEQUENCE_RECORD = "sequence.json"
#: a reference folder's contents, written by the export
GROUND_TRUTH_RECORD = "ground_truth.json"
#: an export's folders by their records: (record, what the folder holds)
RECORDS = ((SEQUENCE_RECORD, "frames"), (GROUND_TRUTH_RECORD, "ground truth"))
#: the largest record read (they are a few kilobytes)
RECORD_LIMIT = 1 << 20


#: the settings of ``sequence.json`` that decide no pixel: left out of the sequence's key
NOT_IN_KEY = ("versions", "seeds", "scene_file", "scene_sha256", "spp_per_render")


def settings_key(settings: dict) -> str:
    """The key of a sequence with these settings (``sequence.json``): the root of
    its seeds, and what its ground truth's record names as the frames it judges."""
    kept = {name: value for name, value in settings.items() if name not in NOT_IN_KEY}
    return hashlib.sha256(json.dumps(kept, sort_keys=True).encode()).hexdigest()


def reference_folder(target: Path) -> Path:
    """Where the export writes the ground truth of the frame folder ``target``:
    beside it, named after it (a target that ends in ``.`` or ``..`` is named by
    the folder it means: ``.``'s would be ``./_reference``, inside the frames)."""
    target = Path(target)
    if target.name in ("", ".", ".."):
        target = Path(os.path.normpath(os.path.abspath(target)))
    return target.parent / f"{target.name}_reference"


def check_not_an_export_folder(flag: str, output: Path) -> None:
    """Refuses an output folder that holds an export's frames or ground truth (by
    their records): results written there would be read back as its input."""
    for record, what in RECORDS:
        if (Path(output) / record).exists():
            raise UsageError(f"{flag} {output} holds an export's {what} ({record}), an input; "
                             f"write outputs elsewhere")


#: the export's record of a whole dataset, in OUT beside its sequences' folders
DATASET_RECORD = "dataset.json"


def check_outside_exports(outputs: dict[str, Path | None]) -> None:
    """Refuses an output (label -> path; a file or a folder a command writes) that
    lies inside an export's frames or ground truth (by their records), whichever
    the command was given, or that is an export's record itself (a dataset's
    ``dataset.json``): it would replace what the export and the commands after it read."""
    for label, output in outputs.items():
        if output is None:
            continue
        path = Path(output).absolute()
        if path.name in (SEQUENCE_RECORD, GROUND_TRUTH_RECORD, DATASET_RECORD) and path.is_file():
            raise UsageError(f"{label} {output} is an export's record ({path.name}), an input; write outputs elsewhere")
        for folder in path.parents:
            for record, what in RECORDS:
                if (folder / record).is_file():
                    raise UsageError(f"{label} {output} lies inside {folder}, an export's {what} ({record}), "
                                     f"an input; write outputs elsewhere")


def check_work_folder(work: Path) -> None:
    """Refuses a ``--work`` cache (where a command exports its sequences) that
    is, or lies inside, a file, or an export's frames or ground truth (by their
    records): new sequences would be written into an input."""
    work = Path(work).absolute()
    for folder in (work, *work.parents):
        if folder.exists() and not folder.is_dir():  # else mkdir's "File exists", or an error about a folder in it
            where = "is a file" if folder == work else f"lies inside {folder}, a file"
            raise UsageError(f"--work {work} {where}, not a folder; give a folder")
        for record, what in RECORDS:
            if (folder / record).is_file():
                where = "is" if folder == work else f"lies inside {folder}, which is"
                raise UsageError(f"--work {work} {where} an export's {what} ({record}), an input; "
                                 f"give a folder of its own")


def read_record(path: Path) -> dict | None:
    """An export's record, or None where there is none that can be read (no evidence either way)."""
    try:
        data = read_json(path, RECORD_LIMIT)
    except (OSError, JSONInputError):
        return None
    return data if isinstance(data, dict) else None


def check_export_finished(folder: Path, indices: list[int]) -> None:
    """Refuses, in one line, an export's frame folder (by its record) whose frames
    ``indices`` lack some that its spec names: an export still running, or
    stopped, whose frames so far would be taken for the whole sequence."""
    record = read_record(Path(folder) / SEQUENCE_RECORD) or {}
    spec = record.get("spec")
    frames = whole_number(spec.get("frames")) if isinstance(spec, dict) else None
    if frames is None:
        return
    have = set(indices)
    missing = [i for i in range(frames) if i not in have]
    if missing:
        raise UsageError(f"{folder}: {len(missing)} of the {frames} frames its export names are missing (frame "
                         f"{missing[0]} first): the export is still running or was stopped; python -m export "
                         f"resumes it")


def whole_number(value) -> int | None:
    return value if isinstance(value, int) and not isinstance(value, bool) else None


def described(record: dict) -> str:
    """A record's sequence in words: its frame count and size where it has them."""
    spec = record.get("spec") if isinstance(record.get("spec"), dict) else record
    frames, size = whole_number(spec.get("frames")), record.get("size")
    words = [f"{frames} frames"] if frames is not None else []
    if isinstance(size, list) and len(size) == 2:
        words.append(f"{size[0]}x{size[1]}")
    return ", ".join(words) or "other settings"


def check_same_sequence(flag: str, reference: Path, record: dict, frames_flag: str, frames_folder: Path,
                        frames: dict) -> None:
    """Refuses a ground truth whose record names another sequence than the frame folder's record."""
    truth_key = record.get("key")
    if not isinstance(truth_key, str) or frames.get("format") != record.get("format"):
        return  # records of another export format: no evidence either way
    if settings_key(frames) != truth_key:
        named = record.get("frames_folder")
        of = f"the frames {named}" if isinstance(named, str) else "another sequence"
        raise UsageError(f"{flag} {reference} is the ground truth of {of} ({described(record)}), not of "
                         f"{frames_flag} {frames_folder} ({described(frames)}): their records "
                         f"({GROUND_TRUTH_RECORD}, {SEQUENCE_RECORD}) name other sequences")


def check_ground_truth(flag: str, reference: Path, frames_folder: Path | None = None,
                       frames_flag: str = "--frames") -> None:
    """Refuses, in one line, a ``reference`` that is not a ground truth for
    ``frames_folder``'s frames (``frames_flag`` names that folder in the message)."""
    if (reference / SEQUENCE_RECORD).is_file():
        truth = reference_folder(reference)
        hint = f"; its ground truth is {truth}" if truth.is_dir() else ""
        raise UsageError(f"{flag} {reference}: holds an export's noisy frames ({SEQUENCE_RECORD}), "
                         f"not a ground truth{hint}")
    if (reference / "matrix_0.mat").is_file() or (reference / "normal_0.exr").is_file():
        raise UsageError(f"{flag} {reference}: holds frames with G-buffers (matrix_0.mat, normal_0.exr), "
                         "the denoiser's input, not a ground truth")
    record = read_record(reference / GROUND_TRUTH_RECORD) or {}
    truth_spp = whole_number(record.get("spp"))
    frames = read_record(frames_folder / SEQUENCE_RECORD) if frames_folder is not None else None
    if frames is not None:
        frames_spp, judged = whole_number(frames.get("spp")), f"the frames of {frames_folder}"
    else:
        frames_spp, judged = whole_number(record.get("frames_spp")), "its frames"
    if truth_spp is not None and frames_spp is not None and truth_spp <= frames_spp:
        raise UsageError(f"{flag} {reference}: a ground truth of {truth_spp} samples per pixel cannot judge "
                         f"{judged}, rendered at {frames_spp}")
    if frames is not None:
        check_same_sequence(flag, reference, record, frames_flag, frames_folder, frames)
