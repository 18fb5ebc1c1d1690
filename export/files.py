"""Crash-safe files for the export: every file appears complete or not at all,
stale staging files are recognised, and one export at a time holds a folder.

A kill at any instant (``kill -9``, a power cut after the fsyncs) leaves each
file either absent, as it was, or complete under its final name: it is
written under a staging name beside it, flushed to disk, renamed into place,
and the folder flushed. What a kill leaves behind is a staging file, which
the next run removes (:func:`remove_staging`).
"""
from __future__ import annotations

import fcntl
import hashlib
import os
import re
import tempfile
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path

from core.entry import TEMPORARY
from core.errors import OutputError, write_failure

#: ends the name of a file being written (``.beauty_0.exr.partial``)
STAGING = ".partial"
#: the lock file an export holds in each folder it writes
LOCK_NAME = ".export.lock"
#: a staging file, or the temporary file ``imaging.image_io.atomic_path`` makes
#: beside a target (``.NAME.1a2b3c4d.exr``), of a file the export writes
_STAGED = re.compile(r"\.\.?(?:beauty|normal|position|depth|ID|albedo|matrix|half_a|half_b|batch|sequence|ground_truth"
                     r"|dataset)[\w.]*?(?:\.partial(?:\.[0-9a-f]{8}\.\w+)?|\.[0-9a-f]{8}\.\w+)")


def _fsync(path: Path, flags: int = os.O_RDONLY) -> None:
    descriptor = os.open(path, flags)
    try:
        os.fsync(descriptor)
    finally:
        os.close(descriptor)


def publish(path: Path, write: Callable[[Path], None]) -> None:
    """Writes ``path`` crash-safely: ``write(staging)`` fills a staging file
    beside it, which is flushed, renamed to ``path``, and the folder flushed.
    A failure removes the staging file, keeps an earlier ``path`` and is an
    :class:`OutputError` naming ``path``."""
    path = Path(path)
    staging = path.with_name(f".{path.name}{STAGING}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write(staging)
        _fsync(staging)
        os.replace(staging, path)
        _fsync(path.parent, os.O_RDONLY | os.O_DIRECTORY)
    except BaseException as error:
        staging.unlink(missing_ok=True)
        if isinstance(error, OutputError):  # the writer's own, naming the staging file: name the user's
            raise OutputError(str(error).replace(str(staging), str(path))) from None
        why = write_failure(error) if isinstance(error, Exception) else None
        if why is not None:
            raise OutputError(f"{path}: cannot write: {why}") from None
        raise


def is_staging(name: str) -> bool:
    """A file name that only a write the export did not finish leaves."""
    return _STAGED.fullmatch(name) is not None


def remove_staging(folder: Path) -> list[Path]:
    """Removes the staging files an interrupted export left in ``folder``; returns them."""
    if not folder.is_dir():
        return []
    stale = [p for p in folder.iterdir() if p.is_file() and is_staging(p.name)]
    for path in stale:
        path.unlink(missing_ok=True)
    return stale


class FolderBusy(OutputError):
    """Another export holds a folder's lock."""


def lock_file(path: Path, busy: str, cannot: str) -> int:
    """The descriptor of the lock file ``path`` (made where missing), locked; raises
    :class:`FolderBusy` saying ``busy`` where another process holds it, and
    :class:`OutputError` (``cannot``, then why) where it cannot be made."""
    while True:
        try:
            descriptor = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
        except OSError as error:
            raise OutputError(f"{cannot}: {error.strerror or error}") from None
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(descriptor)
            raise FolderBusy(busy) from None
        try:
            if os.stat(path).st_ino == os.fstat(descriptor).st_ino:
                TEMPORARY.add(str(path))  # a watchdog that ends the process removes it too
                return descriptor
        except FileNotFoundError:
            pass
        os.close(descriptor)  # the holder removed that file as it finished: lock the new one


def unlock_file(path: Path, descriptor: int) -> None:
    """Removes the lock file ``path`` while still holding it (so that no one waits on
    a file no one else sees), then releases it."""
    try:
        path.unlink(missing_ok=True)
    finally:
        TEMPORARY.discard(str(path))
        os.close(descriptor)


def _lock(folder: Path, doing: str, remedy: str | None = None) -> int:
    """The descriptor of ``folder``'s lock file, locked; raises :class:`FolderBusy`
    (``doing``: what holds it, "export" or "denoise", and ``remedy``, what
    else to do than wait, for the message)."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise OutputError(f"{folder}: cannot write there: {error.strerror or error}") from None
    return lock_file(folder / LOCK_NAME, f"{folder}: another {doing} is writing into this folder; wait for it to "
                                         f"finish, or {remedy or f'{doing} into another folder'}",
                     f"{folder}: cannot write there")


def name_lock_file(path: Path) -> Path:
    """The lock file of :func:`name_locked` for ``path``: in the system's temporary folder,
    named by the hash of the resolved name."""
    key = hashlib.sha256(str(Path(path).resolve()).encode("utf-8", "surrogateescape")).hexdigest()[:32]
    return Path(tempfile.gettempdir()) / f"toolkit-{key}.lock"


@contextmanager
def name_locked(path: Path, doing: str, remedy: str) -> Iterator[None]:
    """Holds a lock on the file name ``path`` (as resolved) for the block: an ``flock``
    on a file in the system's temporary folder named by the name's hash, so that
    no lock file lands beside ``path`` (a file of the repository, say); raises
    :class:`FolderBusy` (``doing`` and ``remedy`` as :func:`locked`'s) where
    another process holds it. The lock file goes when the block ends; the lock
    itself goes with its process, however it ends."""
    lock = name_lock_file(path)
    descriptor = lock_file(lock, f"{path}: another {doing} is writing this file; wait for it to finish, or {remedy}",
                           f"{lock}: cannot lock {path} there")
    try:
        yield
    finally:
        unlock_file(lock, descriptor)


@contextmanager
def locked(folders: list[Path], doing: str = "export", remedy: str | None = None) -> Iterator[None]:
    """Holds the writer's lock (``flock`` on :data:`LOCK_NAME`) in every folder
    of ``folders`` (made where missing); raises :class:`FolderBusy` naming the
    first folder another process holds (``doing``: the command that writes,
    and ``remedy``, what else to do than wait, for its message). The lock
    file goes when the writer ends; the lock itself goes with its process,
    however it ends (a lock file a killed export left behind locks nothing)."""
    with ExitStack() as stack:
        for folder in sorted({Path(f).absolute() for f in folders}):
            descriptor = _lock(folder, doing, remedy)
            stack.callback(unlock_file, folder / LOCK_NAME, descriptor)
        yield
