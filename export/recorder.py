"""Recording task results as they come, and the dataset's manifest
(``dataset.json``: per frame its status, seeds and the timings of its tasks)."""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from core.json_input import JSONInputError, read_json

from .ground_truth import SEQUENCE_RECORD
from .sequence import EXPORT_FORMAT, Sequence, seed, settings_key
from .store import (
    MAX_RECORD_BYTES,
    assemble_reference,
    batch_path,
    frame_done,
    reference_done,
    save_batch,
    write_frame_files,
    write_record,
)
from .tasks import Task


class Recorder:
    """Writes task results as they come (atomically) and keeps the manifest."""

    def __init__(self, sequences: list[Sequence], manifest: Path | None):
        self.sequences = {s.name: s for s in sequences}
        self.manifest = manifest
        self.run_id = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
        self.timings: dict[tuple[str, int], list[dict]] = {}
        self.rendered: dict[str, set[int]] = {s.name: set() for s in sequences}
        self.record_s: list[float] = []  # this process's time writing each result
        self.complete = {(s.name, i) for s in sequences for i in range(s.spec.frames)
                         if frame_done(Path(s.target), i) and reference_done(Path(s.target), i)}
        #: the earlier runs' entries of the sequences this run leaves alone, whose folders still hold them
        self.earlier: list[dict] = []
        if manifest is not None and manifest.exists():  # keep the timings of an interrupted run
            try:
                old = read_json(manifest, MAX_RECORD_BYTES)
                for entry in old.get("sequences", []):
                    if entry.get("name") in self.sequences and entry.get("key") == self.sequences[entry["name"]].key:
                        for frame in entry.get("frames", []):
                            self.timings[(entry["name"], frame["index"])] = frame.get("tasks", [])
                    elif entry.get("name") not in self.sequences and still_there(entry):
                        self.earlier.append(entry)
            except (JSONInputError, KeyError, TypeError, AttributeError):
                pass

    def record(self, task: Task, result, timing: dict) -> None:
        start = time.perf_counter()
        self._record(task, result, timing)
        self.record_s.append(time.perf_counter() - start)

    def _record(self, task: Task, result, timing: dict) -> None:
        sequence = task.sequence
        timing = dict(timing, run=self.run_id)
        self.timings.setdefault((sequence.name, task.frame), []).append(timing)
        self.rendered[sequence.name].add(task.frame)
        target = Path(sequence.target)
        if task.kind == "frame":
            write_frame_files(target, task.frame, result)
        else:
            save_batch(batch_path(sequence, task.frame, task.batch), result)
            assemble_reference(sequence, task.frame)
        if frame_done(target, task.frame) and reference_done(target, task.frame):
            self.complete.add((sequence.name, task.frame))

    def frames_done(self) -> int:
        return len(self.complete)

    def write(self, extra: dict) -> None:
        if self.manifest is None:
            return
        entries = []
        for sequence in self.sequences.values():
            frames = []
            for i in range(sequence.spec.frames):
                target = Path(sequence.target)
                done = frame_done(target, i) and reference_done(target, i)
                status = ("rendered" if i in self.rendered[sequence.name] else "resumed") if done else "missing"
                batches = sum(batch_path(sequence, i, b).exists() for b in range(len(sequence.batches())))
                frames.append({"index": i, "status": status, "noisy_seed": seed(sequence.key, i, "noisy"),
                               "batches_waiting": batches, "tasks": self.timings.get((sequence.name, i), [])})
            entries.append({"name": sequence.name, "key": sequence.key, "folder": sequence.target,
                            "reference": str(sequence.reference), "settings": sequence.settings(), "frames": frames})
        if self.record_s:
            extra = dict(extra, writing_s_per_task=round(float(np.median(self.record_s)), 4))
        write_record(self.manifest, dict(extra, format=EXPORT_FORMAT, sequences=self.earlier + entries))


def still_there(entry: dict) -> bool:
    """Whether the folder of an earlier manifest's ``entry`` still holds that sequence (its key)."""
    folder = entry.get("folder")
    if not isinstance(folder, str):
        return False
    try:
        record = read_json(Path(folder) / SEQUENCE_RECORD, MAX_RECORD_BYTES)
    except JSONInputError:
        return False
    return isinstance(record, dict) and settings_key(record) == entry.get("key")


def progress_bar(total: int, frames: int):
    """tqdm over tasks, on stderr only when it is a terminal."""
    return tqdm(total=total, desc="frames+batches", unit="task", file=sys.stderr,
                disable=not sys.stderr.isatty(), postfix={"frames": f"0/{frames}"}, leave=False)
