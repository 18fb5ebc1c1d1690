"""Measurements: render speed, cross-validation, error against time, stress."""
from __future__ import annotations

import json
from pathlib import Path


def write_json(path: Path, data) -> None:
    """Writes ``data`` as indented JSON, atomically (temporary name, then rename)."""
    from imaging.image_io import atomic_path

    with atomic_path(path, ".json") as tmp:
        tmp.write_text(json.dumps(data, indent=2) + "\n")
