"""Reader for the OBJ subset the course's meshes use.

Supported: ``v x y z``, ``vt u v``, ``vn``, ``f a b c`` with ``a``, ``a/t``,
``a/t/n`` or ``a//n`` vertex references (1-based or negative), polygons
(fan-triangulated), and the grouping/material statements (``o g s usemtl
mtllib``), which are ignored. Anything else is a :class:`SceneError`.
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from core.errors import SceneError, describe
from core.inputs import NotAnInputFile, read_input

#: The renderer stores coordinates as float32
FLOAT32_MAX = float(np.finfo(np.float32).max)

_IGNORED = {"vn", "vp", "o", "g", "s", "usemtl", "mtllib", "l"}


def read_obj(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Returns ``(positions (V,3) float64, faces (F,3) uint32)``, 0-based."""
    try:
        data = read_input(path)
    except OSError as error:
        raise SceneError(path, 1, 1, f"cannot read mesh: {error.strerror or error}") from None
    except NotAnInputFile as error:
        raise SceneError(path, 1, 1, f"cannot read mesh: {error}") from None
    try:
        text = data.decode("utf-8-sig")  # a byte-order mark (Windows editors) is not text, as in scenes
    except UnicodeDecodeError as error:
        line = data[: error.start].count(b"\n") + 1
        raise SceneError(path, line, 1, "expected UTF-8 text, found binary data") from None

    positions: list[tuple[float, float, float]] = []
    faces: list[tuple[int, int, int]] = []
    for line_no, line in enumerate(text.splitlines(), start=1):
        stripped = line.split("#", 1)[0]
        matches = list(re.finditer(r"\S+", stripped))
        if not matches:
            continue
        fields = [m.group() for m in matches]

        def col(i: int, matches=matches) -> int:
            return matches[i].start() + 1

        key = fields[0]
        if key == "v" or key == "vt":
            need = 3 if key == "v" else 2
            if len(fields) - 1 < need:
                raise SceneError(path, line_no, len(stripped) + 1,
                                 f"expected {need} numbers after '{key}', found {len(fields) - 1}")
            values = []
            for i in range(1, need + 1):
                try:
                    value = float(fields[i])
                except ValueError:
                    raise SceneError(path, line_no, col(i),
                                     f"expected a number, found {describe(fields[i])}") from None
                if not math.isfinite(value):
                    raise SceneError(path, line_no, col(i),
                                     f"expected a finite number, found {describe(fields[i])}")
                if abs(value) > FLOAT32_MAX:
                    raise SceneError(path, line_no, col(i), f"expected a number of magnitude at most "
                                     f"{FLOAT32_MAX:.7g} (float32), found {describe(fields[i])}")
                values.append(value)
            if key == "v":
                positions.append(tuple(values))
        elif key == "f":
            if len(fields) < 4:
                raise SceneError(path, line_no, len(stripped) + 1,
                                 f"expected at least 3 vertices after 'f', found {len(fields) - 1}")
            indices = []
            for i in range(1, len(fields)):
                ref = fields[i].split("/")[0]
                try:
                    index = int(ref)
                except ValueError:
                    raise SceneError(path, line_no, col(i),
                                     f"expected a vertex index, found {describe(fields[i])}") from None
                resolved = index - 1 if index > 0 else len(positions) + index
                if index == 0 or not 0 <= resolved < len(positions):
                    raise SceneError(path, line_no, col(i),
                                     f"expected a vertex index in 1..{len(positions)}, found {index}")
                indices.append(resolved)
            for k in range(1, len(indices) - 1):
                faces.append((indices[0], indices[k], indices[k + 1]))
        elif key not in _IGNORED:
            raise SceneError(path, line_no, col(0), f"expected an OBJ statement (v, vt, f), found {describe(key)}")

    if not faces:
        raise SceneError(path, max(1, text.count("\n")), 1, "expected at least one face ('f'), found none")
    return np.asarray(positions, np.float64), np.asarray(faces, np.uint32)
