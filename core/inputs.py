"""Reading a user's input files (scenes, meshes, batch files): regular files
of a bounded size only.

A device such as ``/dev/zero`` or ``/dev/urandom`` never ends, and reading
it whole ran the machine out of memory; a folder or a missing file is the
usual ``OSError``. Callers turn the error into their own located message.
"""
from __future__ import annotations

import stat
from pathlib import Path

from .errors import UsageError

#: no scene, mesh or batch file is larger (the course's largest mesh is a few MB)
MAX_INPUT_BYTES = 1 << 30


class NotAnInputFile(ValueError):
    """The path is a device, a socket, a pipe where none is allowed, or too large."""


def read_input(path: Path, limit: int = MAX_INPUT_BYTES, allow_pipe: bool = False) -> bytes:
    """The bytes of ``path``, a regular file (or, with ``allow_pipe``, a pipe
    such as a shell's ``<(...)``) of at most ``limit`` bytes. Raises ``OSError``
    (missing, a folder, no permission) or :class:`NotAnInputFile`."""
    mode = Path(path).stat().st_mode
    if stat.S_ISDIR(mode):
        raise IsADirectoryError(21, "is a folder", str(path))
    if not (stat.S_ISREG(mode) or (allow_pipe and stat.S_ISFIFO(mode))):
        kind = "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "a pipe" if stat.S_ISFIFO(mode) \
            else "a socket" if stat.S_ISSOCK(mode) else "not a regular file"
        raise NotAnInputFile(f"{kind}, not a regular file")
    with open(path, "rb") as file:
        data = file.read(limit + 1)
    if len(data) > limit:
        raise NotAnInputFile(f"larger than {limit} bytes")
    return data


def check_outside(outputs: dict[str, Path | None], inputs: dict[str, Path | None]) -> None:
    """Raises :class:`UsageError` when an output (label -> path) is an input
    folder (label -> folder) or lies inside one, before any work: a command
    never writes into what it reads (a second run would read its own outputs)."""
    for out_label, output in outputs.items():
        if output is None:
            continue
        where = Path(output).resolve()
        for in_label, folder in inputs.items():
            base = None if folder is None else Path(folder).resolve()
            if base is not None and where == base:
                raise UsageError(f"{out_label} {output} is the input {in_label} {folder}; write outputs elsewhere")
            if base is not None and base in where.parents:
                # a flag or metavar is "the input folder --work"; a label that says what it is, as
                # "frame folder (--work) of x", is not said to be a folder twice
                kind = "" if " " in in_label else "folder "
                raise UsageError(f"{out_label} {output} is inside the input {kind}{in_label} {folder}; "
                                 f"write outputs elsewhere")
