"""What a ground-truth folder is, and the checks before anything is judged against it.

``python -m export`` writes a sequence's frames into ``OUT`` (with
``sequence.json``, its settings) and their ground truth into ``OUT_reference``
(with ``ground_truth.json``: what the folder holds, at how many samples per
pixel). A folder given as the truth is refused when it is a frame folder (an
export's, by its record, or any in the course's layout, by its G-buffers),
or when its record says it has no more samples per pixel than the frames it
would judge: every figure against it would be a figure against noise.
Folders without records (a truth rendered elsewhere) are taken as they are.
"""
from __future__ import annotations

from pathlib import Path

from core.errors import UsageError
from core.json_input import JSONInputError, read_json

#: a frame folder's settings, written by the export
SEQUENCE_RECORD = "sequence.json"
#: a reference folder's contents, written by the export
GROUND_TRUTH_RECORD = "ground_truth.json"
#: the largest record read (they are a few kilobytes)
RECORD_LIMIT = 1 << 20


def reference_folder(target: Path) -> Path:
    """Where the export writes the ground truth of the frame folder ``target``."""
    target = Path(target)
    return target.parent / f"{target.name}_reference"


def read_record(path: Path) -> dict | None:
    """An export's record, or None where there is none that can be read (no evidence either way)."""
    try:
        data = read_json(path, RECORD_LIMIT)
    except (OSError, JSONInputError):
        return None
    return data if isinstance(data, dict) else None


def whole_number(value) -> int | None:
    return value if isinstance(value, int) and not isinstance(value, bool) else None


def check_ground_truth(flag: str, reference: Path, frames_folder: Path | None = None) -> None:
    """Refuses, in one line, a ``reference`` that is not a ground truth for ``frames_folder``'s frames."""
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
