"""Generated sections of Markdown pages: the one writer every benchmark uses.

A section is the text between two HTML comments, which Markdown renders as
nothing::

    <!-- denoise:start -->
    ... written by python -m benchmarks.denoise --write-results ...
    <!-- denoise:end -->

:func:`replace_section` puts new text between a named pair and leaves the
rest of the page as it is, so a page can hold hand-written prose around
generated tables. Standard library only (``core`` is the lowest layer).
"""
from __future__ import annotations

import os
import re
import tempfile
from pathlib import Path

from core.entry import TEMPORARY
from core.errors import OutputError, write_failure

#: A section name: letters, digits, ``-`` and ``_`` (it is spelt into the markers)
NAME = re.compile(r"[A-Za-z0-9_-]+")


def markers(name: str) -> tuple[str, str]:
    """The start and end comments of section ``name``."""
    if not NAME.fullmatch(name):
        raise ValueError(f"section name {name!r}: only letters, digits, '-' and '_'")
    return f"<!-- {name}:start -->", f"<!-- {name}:end -->"


def read_section(path: str | Path, name: str) -> str | None:
    """The text between the markers of ``name`` in ``path`` (without them),
    or None where the file or the section does not exist."""
    path = Path(path)
    if not path.is_file():
        return None
    start, end = markers(name)
    found = re.search(re.escape(start) + r"\n?(.*?)" + re.escape(end), path.read_text(), flags=re.S)
    return found.group(1) if found else None


def replace_section(path: str | Path, name: str, text: str) -> Path:
    """Writes ``text`` as section ``name`` of the Markdown file ``path``; returns the path.

    The section's old text is replaced, markers kept. A page without the
    section gets it appended at its end; a missing page is created (its
    folder too). A page holding the start marker without its end marker, or
    either marker twice, is refused with :class:`~core.errors.OutputError`
    (one line under ``core.entry.run``): replacing from there would eat the
    rest of the page. The file is written to a temporary name beside it and
    renamed, so a reader never sees half a page and a failed write (a full
    disk) leaves the old page.
    """
    path = Path(path)
    start, end = markers(name)
    body = text.strip("\n")
    section = f"{start}\n{body}\n{end}" if body else f"{start}\n{end}"
    old = path.read_text() if path.exists() else ""
    counts = (old.count(start), old.count(end))
    if counts == (0, 0):
        new = (old.rstrip("\n") + "\n\n" if old.strip() else "") + section + "\n"
    elif counts == (1, 1) and old.index(start) < old.index(end):
        head, rest = old.split(start, 1)
        new = head + section + rest.split(end, 1)[1]
    else:
        raise OutputError(f"{path}: section {name!r} has {counts[0]} start and {counts[1]} end markers "
                         "(in that order it needs exactly one of each)")
    write_text_atomically(path, new)
    return path


def write_text_atomically(path: str | Path, text: str) -> None:
    """Writes ``text`` to a temporary file beside ``path`` and renames it onto
    ``path`` (the temporary file is removed on any failure)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.exists():
        mode = path.stat().st_mode & 0o777
    else:  # what open() would give a new file: 0o666 less the umask
        umask = os.umask(0)
        os.umask(umask)
        mode = 0o666 & ~umask
    try:
        handle, tmp = tempfile.mkstemp(prefix=".", suffix=".tmp", dir=path.parent)
    except OSError as error:
        raise OutputError(f"{path}: cannot write into {path.parent}: {write_failure(error)}") from None
    TEMPORARY.add(tmp)  # removed by core.entry's watchdog where it ends the process meanwhile
    try:
        with os.fdopen(handle, "w", encoding="utf-8") as file:
            file.write(text)
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException as error:
        Path(tmp).unlink(missing_ok=True)
        why = write_failure(error) if isinstance(error, OSError) else None
        if why is not None:  # a full disk: name the page, not the temporary file
            raise OutputError(f"{path}: {why}") from None
        raise
    finally:
        TEMPORARY.discard(tmp)
