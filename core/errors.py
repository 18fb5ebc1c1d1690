"""The error types a user can see, one per failure class.

Every entry point (``render.py``, ``--batch``, ``python -m converters``,
``python -m denoise``, ``python -m export``) turns a
:class:`ToolkitError` into exactly one line on stderr and exit code 2 (see
:func:`core.entry.run`). ``str(error)`` is that line without the program
name, so a message must say what was wrong and where (a file, a line, a flag).
"""
from __future__ import annotations

import errno
import os
from pathlib import Path


class ToolkitError(Exception):
    """Base class: a problem with what the user gave us, not a bug.

    A message may end in a remedy that names one command's means (its flags:
    ``--force``, ``--batch-spp``, ``--data``). Such an error is made of its
    ``problem`` and that ``remedy`` (``str(error)`` is ``problem; remedy``) and
    says what the remedy provides (``need``, one of the ``NEED_*`` names
    below), so that a command that runs another's code, and has other means,
    gives its own (:meth:`with_remedy`) instead of rewriting the text."""

    def __init__(self, problem: str = "", remedy: str | None = None, need: str | None = None):
        super().__init__(f"{problem}; {remedy}" if remedy else problem)
        self.problem, self.remedy, self.need = problem, remedy, need

    def __reduce__(self):  # pickled whole (Dask sends a worker's errors back), whatever the subclass's __init__
        return rebuild, (type(self), self.args, self.__dict__)

    def with_remedy(self, remedy: str) -> ToolkitError:
        """The same error with ``remedy`` in place of its own."""
        return rebuild(type(self), (f"{self.problem}; {remedy}",), {**self.__dict__, "remedy": remedy})


#: what a remedy provides (:attr:`ToolkitError.need`): the course's scenes found,
NEED_COURSE = "the course's scenes"
#: fewer samples in one render,
NEED_SMALLER_RENDER = "fewer samples per render"
#: a folder no other export wrote into
NEED_OWN_FOLDER = "a folder of its own"


def rebuild(kind: type, args: tuple, state: dict) -> ToolkitError:
    """A :class:`ToolkitError` of type ``kind`` with these ``args`` and attributes, not
    through its ``__init__`` (whose parameters differ between subclasses)."""
    error = kind.__new__(kind)
    error.args = args
    error.__dict__.update(state)
    return error


class SceneError(ToolkitError):
    """A problem in a scene, mesh or cube-map file, located as ``file:line:col``.

    ``str(error)`` is the one line shown to the user, e.g.
    ``scene.txt:12:5: expected a number, found 'radius'``.
    """

    def __init__(self, path: str | Path, line: int, col: int, message: str):
        super().__init__(f"{path}:{line}:{col}: {message}")
        self.path, self.line, self.col, self.message = str(path), line, col, message


class UsageError(ToolkitError):
    """A command-line flag or parameter out of range, or a combination that makes no sense."""


class LimitError(ToolkitError):
    """Work the machine or the variant cannot do: too many samples to index,
    more memory than is available. Raised before any work starts."""


class OutputError(ToolkitError):
    """An output path that cannot be written: no permission, unknown format,
    two outputs on one file, a folder where a file should be."""


class FrameError(ToolkitError):
    """A damaged, missing or inconsistent frame folder (names the file)."""


class ClusterError(ToolkitError):
    """A Dask cluster that could not finish an export's tasks: its scheduler
    went away, or a task's workers died more often than Dask allows."""


class SpecError(ToolkitError):
    """A sequence/export spec that is malformed, out of range, or does not
    match the folder it would be resumed into."""


def describe(text: str | None) -> str:
    """How a found token is quoted in messages."""
    if text is None:
        return "end of file"
    if len(text) > 40:
        text = text[:37] + "..."
    return repr(text)


#: Errors that mean the data did not fit, and what the user is told
NO_ROOM = {errno.ENOSPC: "no space left on device", errno.EDQUOT: "disk quota exceeded",
           errno.EFBIG: "file too large (over the file-size limit)"}


def write_failure(error: BaseException) -> str | None:
    """Why a write failed, in a few words, for errors that are the disk's and
    not a bug: an ``OSError`` with an errno, or a library's error (OpenEXR's
    RuntimeError, FFmpeg's message) whose text holds a full disk's strerror."""
    if isinstance(error, OSError) and error.errno is not None:
        return NO_ROOM.get(error.errno) or (error.strerror or os.strerror(error.errno)).lower()
    text = str(error).lower()
    for code, words in NO_ROOM.items():
        if os.strerror(code).lower() in text:
            return words
    return None
