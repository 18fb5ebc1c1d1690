"""The folders of an export: what is done, claiming and resuming them, and
writing results into them.

A sequence writes its frames into ``target`` and its ground truth into
``target_reference``; reference batches wait in ``target_reference/.batches``
until a frame's last one is in, and are then summed (in batch order, in
float64) into the halves and the reference. ``target/sequence.json`` records
the settings: an export with other settings is refused;
``target_reference/ground_truth.json`` says what that folder is (the ground
truth of ``target``, at how many samples), so that a scorer can refuse the
noisy frames, or a thinner truth, given as its reference.

Every file is written crash-safely (:func:`export.files.publish`), and
the file that marks a part complete is written last: ``matrix_i.mat`` for a
frame's buffers, ``beauty_i.exr`` for its reference (after both halves). So
after a kill at any instant a rerun (:func:`recover`, then :func:`plan`)
ends with the bytes of an uninterrupted run.
"""
from __future__ import annotations

import io
import json
import re
import shutil
from pathlib import Path

import numpy as np

from core.errors import NEED_OWN_FOLDER, SpecError
from core.json_input import JSONInputError, read_json
from imaging.image_io import write_exr

from .files import publish, remove_staging
from .frames import BUFFERS, FrameData, write_matrices
from .ground_truth import GROUND_TRUTH_RECORD, SEQUENCE_RECORD
from .sequence import EXPORT_FORMAT, Sequence, reference_folder, seed
from .tasks import Task

#: the largest record or manifest read back, in bytes (a manifest grows by a few hundred per frame)
MAX_RECORD_BYTES = 256 << 20


def batch_path(sequence: Sequence, frame: int, batch: int) -> Path:
    """Where a reference batch waits until its frame's batches are all in."""
    return sequence.reference / ".batches" / f"{frame}" / f"batch_{batch}.npy"


def frame_done(target: Path, index: int) -> bool:
    """The frame's buffers are written (not its reference); ``matrix_i.mat`` comes last."""
    files = [target / f"{name}_{index}.exr" for name in BUFFERS] + [target / f"matrix_{index}.mat",
                                                                   target / f"albedo_{index}.exr"]
    return all(f.exists() for f in files)


REFERENCE_FILES = ("beauty", "half_a", "half_b")


def reference_done(target: Path, index: int) -> bool:
    """The frame's reference and both its halves are written; ``beauty_i.exr`` comes last."""
    return all((reference_folder(target) / f"{name}_{index}.exr").exists() for name in REFERENCE_FILES)


def _json_bytes(data) -> bytes:
    return (json.dumps(data, indent=2, sort_keys=True) + "\n").encode()


def write_record(path: Path, data) -> None:
    """Writes ``data`` as sorted, indented JSON (crash-safely)."""
    publish(path, lambda staging: staging.write_bytes(_json_bytes(data)))


def write_frame_files(target: Path, index: int, frame: FrameData) -> None:
    """Writes one frame's buffers in the course's layout (and ``albedo_i.exr``),
    ``matrix_i.mat`` last: its presence marks the frame complete."""
    for name, data in (("beauty", frame.beauty), ("normal", frame.normal), ("position", frame.position),
                       ("depth", frame.depth), ("ID", frame.ids.astype(np.float32)), ("albedo", frame.albedo)):
        publish(target / f"{name}_{index}.exr", lambda staging, data=data: write_exr(staging, {"": data}))
    publish(target / f"matrix_{index}.mat", lambda staging: write_matrices(
        staging, frame.object_to_world, frame.world_to_camera, frame.world_to_screen))


def _our_files(sequence: Sequence) -> list[Path]:
    target, reference = Path(sequence.target), sequence.reference
    names = "|".join(BUFFERS + ("albedo",))
    found = []
    if target.is_dir():
        found += [p for p in target.iterdir() if re.fullmatch(rf"(?:{names})_\d+\.exr|matrix_\d+\.mat", p.name)]
    if reference.is_dir():
        found += [p for p in reference.iterdir() if re.fullmatch(r"(?:beauty|half_a|half_b)_\d+\.exr", p.name)]
    return found


def start_over(sequence: Sequence) -> None:
    """``--force``: removes what an earlier export wrote (only files we name)."""
    for path in _our_files(sequence):
        path.unlink()
    shutil.rmtree(sequence.reference / ".batches", ignore_errors=True)
    (Path(sequence.target) / SEQUENCE_RECORD).unlink(missing_ok=True)
    (sequence.reference / GROUND_TRUTH_RECORD).unlink(missing_ok=True)


def _differences(old: dict, new: dict, prefix: str = "") -> list[str]:
    found = []
    for key in sorted(set(old) | set(new)):
        a, b = old.get(key), new.get(key)
        if isinstance(a, dict) and isinstance(b, dict):
            found += _differences(a, b, f"{prefix}{key}.")
        elif a != b:
            found.append(f"{prefix}{key} {shortened(json.dumps(a))} -> {shortened(json.dumps(b))}")
    return found


#: the most characters of a value in a message (a list of a million batches is 3 MB of text)
VALUE_CHARS = 60


def shortened(text: str) -> str:
    """``text`` cut to :data:`VALUE_CHARS` characters, the cut said."""
    return text if len(text) <= VALUE_CHARS else f"{text[:VALUE_CHARS - 25]}... ({len(text)} characters)"


def _comparable(settings: dict, other: dict) -> dict:
    """``settings`` as compared with ``other``: without the scene's path (a
    checkout elsewhere, e.g. another git worktree, holds the same scene under
    another path) but with its content's hash where both record one, and its
    samples per render where they matter."""
    settings = {k: v for k, v in settings.items() if k != "scene_file"}
    if "scene_sha256" not in other:
        settings.pop("scene_sha256", None)
    # a folder from before passes were split renders the same while no pass is split
    if "spp_per_render" not in other and "spp_per_render" in settings:
        if max([settings["spp"], *settings["batches"]]) <= settings["spp_per_render"]:
            settings.pop("spp_per_render")
    return settings


class FolderInUseError(SpecError):
    """A sequence's folder holds what another export wrote: ``problem`` says
    what; the remedy is the export's (``--force``), which a command that uses
    the folder as its cache replaces with its own (:meth:`ToolkitError.with_remedy`)."""

    def __init__(self, problem: str, remedy: str = "use --force to start over, or another folder"):
        super().__init__(problem, remedy, NEED_OWN_FOLDER)


def check_folder(sequence: Sequence) -> None:
    """Raises :class:`FolderInUseError` unless ``sequence`` may write into its
    folders: they are new, or were made with the same settings. Writes nothing."""
    target = Path(sequence.target)
    record = target / SEQUENCE_RECORD
    settings = sequence.settings()
    if record.exists():
        try:
            old = read_json(record, MAX_RECORD_BYTES)
        except JSONInputError:
            old = None
        if not isinstance(old, dict):  # damaged: other settings than any
            old = {"unreadable": True}
        if _comparable(old, settings) != _comparable(settings, old):
            changed = _differences(_comparable(old, settings), _comparable(settings, old))
            raise FolderInUseError(f"{target}: made with other settings ({'; '.join(changed[:4])}"
                                   f"{'; ...' if len(changed) > 4 else ''})")
    elif _our_files(sequence):
        folders = sorted({path.parent for path in _our_files(sequence)})
        if folders == [sequence.reference]:
            raise FolderInUseError(f"{sequence.reference}: holds ground truth, but its frame folder {target} has "
                                   "no sequence.json (made by an older export or by hand)")
        raise FolderInUseError(f"{target}: holds frames without a sequence.json (made by an older export or by hand)")


def claim_folder(sequence: Sequence, force: bool = False) -> None:
    """Checks that ``sequence`` may write into its folders (:func:`check_folder`;
    ``force``: removes what an earlier export wrote instead) and records its settings there."""
    if force:
        start_over(sequence)
    check_folder(sequence)
    record = Path(sequence.target) / SEQUENCE_RECORD
    if not record.exists():
        write_record(record, sequence.settings())


def ground_truth_record(sequence: Sequence) -> dict:
    """What the reference folder holds: the ground truth of which frames, at how many samples per pixel."""
    return {"format": EXPORT_FORMAT, "holds": "ground truth", "frames_folder": Path(sequence.target).name,
            "key": sequence.key, "spp": sequence.spec.reference_spp, "frames_spp": sequence.spec.spp,
            "frames": sequence.spec.frames, "size": list(sequence.spec.size)}


def recover(sequence: Sequence) -> None:
    """Finishes what an interrupted export left: removes its staging files,
    sums the frames whose batches are all in, removes the batches of frames
    whose reference is written."""
    target = Path(sequence.target)
    batches = sequence.reference / ".batches"
    for folder in (target, sequence.reference, *(sorted(batches.iterdir()) if batches.is_dir() else [])):
        remove_staging(folder)
    for frame in range(sequence.spec.frames):
        if reference_done(target, frame):
            shutil.rmtree(batches / f"{frame}", ignore_errors=True)
        else:
            assemble_reference(sequence, frame)
    try:
        batches.rmdir()  # once no frame waits
    except OSError:
        pass


def plan(sequence: Sequence, threads: int | None = None) -> list[Task]:
    """The tasks still to do for ``sequence``, frame by frame."""
    target = Path(sequence.target)
    tasks = []
    key = sequence.key
    for frame in range(sequence.spec.frames):
        if not frame_done(target, frame):
            tasks.append(Task(sequence, frame, "frame", spp=sequence.spec.spp, seed=seed(key, frame, "noisy"),
                              threads=threads))
        if reference_done(target, frame):
            continue
        for batch, (_, spp) in enumerate(sequence.batches()):
            if not batch_path(sequence, frame, batch).exists():
                tasks.append(Task(sequence, frame, "batch", batch, spp, seed(key, frame, "reference", batch), threads))
    return tasks


def save_batch(path: Path, image: np.ndarray) -> None:
    """Writes one reference batch's mean (float32 .npy, crash-safely)."""
    def write(staging: Path) -> None:
        # through memory: np.save onto a full disk reports a short write without its errno
        data = io.BytesIO()
        np.save(data, np.ascontiguousarray(image, np.float32))
        staging.write_bytes(data.getvalue())

    publish(path, write)


def assemble_reference(sequence: Sequence, frame: int) -> bool:
    """Sums a frame's batches (all present) into its halves and reference, in
    batch order, the reference last; removes the batches. False when a batch is still missing."""
    paths = [batch_path(sequence, frame, b) for b in range(len(sequence.batches()))]
    if not all(p.exists() for p in paths):
        return False
    half_spp = sequence.spec.reference_spp // 2
    halves = {}
    for (half, spp), path in zip(sequence.batches(), paths):
        image = np.load(path).astype(np.float64) * (spp / half_spp)
        halves[half] = image if half not in halves else halves[half] + image
    folder = sequence.reference
    for name, image in (("half_a", halves["a"]), ("half_b", halves["b"]), ("beauty", (halves["a"] + halves["b"]) / 2)):
        publish(folder / f"{name}_{frame}.exr", lambda staging, image=image: write_exr(
            staging, {"": image.astype(np.float32)}))
    if not (folder / GROUND_TRUTH_RECORD).exists():  # after a frame's truth: the folder now holds one
        write_record(folder / GROUND_TRUTH_RECORD, ground_truth_record(sequence))
    shutil.rmtree(paths[0].parent, ignore_errors=True)
    try:
        paths[0].parent.parent.rmdir()  # .batches, once no frame waits
    except OSError:
        pass
    return True
