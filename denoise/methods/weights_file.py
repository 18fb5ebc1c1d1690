"""Reading a trained network's JSON weights file: every problem is one line
naming the file and the command that writes it (a :class:`UsageError`, exit 2)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from core.errors import UsageError
from core.json_input import JSONInputError, read_json

#: the largest magnitude of a weight a weights file (or a training's checkpoint) may hold
WEIGHT_LIMIT = 1e6
#: the largest weights file read, in bytes
MAX_WEIGHTS_BYTES = 2 << 20


def bad_weights(path: Path | str, problem: str, command: str) -> UsageError:
    return UsageError(f"{path}: {problem}; make it with {command}")


def not_a_number(value, place: str) -> str | None:
    """Where nested lists ``value`` hold something other than a number (a string,
    ``true``, ``null``, an object), said as ``w1[0][2] is "0.5", not a number``; None if nowhere.
    NumPy would read ``"0.5"`` and ``true`` as numbers."""
    if isinstance(value, list):
        for index, item in enumerate(value):
            found = not_a_number(item, f"{place}[{index}]")
            if found is not None:
                return found
        return None
    if value is None and "[" not in place:
        return None  # a missing key: the shape check says so
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return None
    shown = json.dumps(value)
    return f"{place} is {shown if len(shown) <= 40 else shown[:37] + '...'}, not a number"


def open_weights(path: Path | str, file_format: str, command: str) -> dict:
    """The JSON object of weights file ``path`` whose ``"format"`` is ``file_format``."""
    if str(path) == "":
        raise bad_weights("''", "an empty path, not a weights file", command)
    path = Path(path)
    if path.is_dir():
        raise bad_weights(path, "a folder, not a weights file", command)
    if path.is_symlink() and not path.exists():
        raise bad_weights(path, "a symbolic link that leads to no file", command)
    if path.exists() and not path.is_file():
        raise bad_weights(path, "not a regular file (a pipe, a device or a socket)", command)
    if not path.is_file():
        raise bad_weights(path, "no such weights file", command)
    try:
        data = read_json(path, MAX_WEIGHTS_BYTES)
    except JSONInputError as error:
        raise bad_weights(path, f"not a weights file ({str(error).removeprefix(f'{path}: ')})", command) from None
    if not isinstance(data, dict) or data.get("format") != file_format:
        raise bad_weights(path, f"not a {file_format} weights file (no \"format\": \"{file_format}\")", command)
    return data


def check_names(path: Path, data: dict, key: str, allowed: tuple[str, ...], command: str) -> tuple[str, ...]:
    """``data[key]``: some of ``allowed``, in that order, none twice."""
    names = data.get(key)
    if (not isinstance(names, list) or not names or len(set(map(str, names))) != len(names)
            or [f for f in allowed if f in names] != names):
        raise bad_weights(path, f"its {key} must be some of {', '.join(allowed)}, in that order, got {names!r}",
                          command)
    return tuple(names)


def check_count(path: Path, data: dict, key: str, most: int, command: str) -> int:
    """``data[key]``: a whole number from 1 to ``most``."""
    count = data.get(key)
    if isinstance(count, bool) or not isinstance(count, int) or not 1 <= count <= most:
        raise bad_weights(path, f"{key} must be a whole number from 1 to {most}, got {count!r}", command)
    return count


def weight_arrays(path: Path, data: dict, shapes: dict[str, tuple], sizes: str, command: str) -> dict:
    """``data``'s arrays of ``shapes`` as float32, each finite and within
    :data:`WEIGHT_LIMIT`; ``sizes`` says what the shapes follow from."""
    arrays = {}
    for key, shape in shapes.items():
        place = not_a_number(data.get(key), key)
        if place is not None:
            raise bad_weights(path, place, command)
        try:
            array = np.array(data.get(key), dtype=np.float64)
        except (TypeError, ValueError):
            array = None
        if array is None or array.shape != shape:
            found = "missing" if data.get(key) is None else (
                "not a numeric array" if array is None else f"it has shape {array.shape}")
            raise bad_weights(path, f"{key} must have shape {shape} for {sizes}, {found}", command)
        if not np.all(np.isfinite(array)) or np.any(np.abs(array) > WEIGHT_LIMIT):
            raise bad_weights(path, f"{key} has a value that is not finite or beyond {WEIGHT_LIMIT:g}", command)
        arrays[key] = array.astype(np.float32)
    return arrays
