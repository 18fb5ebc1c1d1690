"""What every benchmark writes: its JSON record (checked before the
measurement, written atomically), the machine and the command it ran on."""
from __future__ import annotations

import datetime as dt
import json
from pathlib import Path

from core.errors import OutputError
from core.inputs import check_outside
from core.machine import machine
from denoise.methods import data_files
from export.ground_truth import check_outside_exports
from imaging.image_io import atomic_path, check_writable


def write_json(path: Path, data) -> None:
    """Writes ``data`` as indented JSON, atomically (temporary name, then rename)."""
    with atomic_path(path, ".json") as tmp:
        tmp.write_text(json.dumps(data, indent=2) + "\n")


def stamp(command: list[str]) -> dict:
    """Where and when a measurement was taken, and by which command (without --json's path)."""
    words = [w for k, w in enumerate(command) if w != "--json" and (k == 0 or command[k - 1] != "--json")]
    return {"command": " ".join(words), "machine": machine(), "date": dt.date.today().isoformat()}


def check_json(path: Path | None) -> None:
    """A ``--json`` target, checked before the measurement (which may take hours):
    not a folder, not a file a method reads, and a file we may write."""
    if path is None:
        return

    if path.is_dir():
        raise OutputError(f"--json {path}: a folder; give a file name such as {path / 'results.json'}")
    check_outside({"--json": path}, data_files())
    check_outside_exports({"--json": path})
    check_writable("--json", path)
    # its folder made now: where that fails (e.g. under /proc, which root may "write"),
    # the OSError names it at once, not after the measurement
    path.parent.mkdir(parents=True, exist_ok=True)
