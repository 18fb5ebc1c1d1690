"""One wrapper for every command-line entry point: the error contract.

    def main(argv=None) -> int:
        return run("render.py", lambda: _main(argv))

- a :class:`~core.errors.ToolkitError` prints ``PROG: error: MESSAGE`` (one
  line) and returns 2;
- an ``OSError`` (a file we could not read or write) prints one line naming
  the file and returns 2; ``MemoryError`` one line and 2;
- Ctrl-C (SIGINT), SIGTERM and SIGHUP print one line and return 130 / 143 / 129; the
  handler raises :class:`Interrupted` (a ``BaseException``), so every
  ``atomic_path`` on the way out removes its temporary file. The first
  signal also starts a watchdog, at once (:class:`SignalWakeup`: even while a
  long native call defers the handler): where the process has not ended
  :data:`GRACE_S` after the signal (user code that swallows the interruption,
  a thread that never ends, a long render or EXR write), the watchdog removes
  the temporary files of the writes in progress (:data:`TEMPORARY`), prints
  the line unless it was printed, and ends the process with the same code. An error whose
  chain (``__cause__`` / ``__context__``) holds such an interruption counts
  as one: native extensions (Dr.Jit's start-up) wrap it in an ImportError or
  SystemError. So does any error after a stop signal came: some native code
  (NumPy's import of ``datetime``, a plugin constructor called from C++)
  raises its own error without the interruption in its chain.
- :func:`native_start_up` keeps a native library's own start-up notices
  (Dr.Jit's "could not use ~/.drjit as the kernel cache directory" where
  HOME is unusable) off stderr, unless the start-up fails;
- before ``run`` starts (a script's imports), :func:`core.start_up.exit_on_signals` makes both
  signals print the same line and exit at once (nothing is written yet); :func:`hold_signals`
  defers them past code that must not be interrupted (a native library's initialisation).

Anything else is a bug and keeps its traceback.
"""
from __future__ import annotations

import argparse
import functools
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import NoReturn

from core.errors import UsageError

from .errors import ToolkitError
from .start_up import INTERRUPTED, STOP_SIGNALS


class Interrupted(BaseException):
    """SIGTERM (or SIGINT) delivered while the program runs."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


#: seconds a command has, after a stop signal reached its handler, to end before the watchdog ends it; with
#: :data:`TEARDOWN_S` it leaves 0.6 s of the 2 s to a loaded machine's delays (docs/reliability.md)
GRACE_S = 1.0
#: seconds the teardown has after a stopped command (its files complete): 2 s from the signal at most, in all
TEARDOWN_S = 0.4
#: the temporary files of the atomic writes in progress: the watchdog removes them before it ends the process
TEMPORARY: set[str] = set()
#: seconds after the signal up to which the watchdog waits for our own cleanups (:func:`own_cleanup`)
CLEANUP_S = 10.0
#: the :func:`own_cleanup` blocks running now
CLEANUPS: list[str] = []


@contextmanager
def own_cleanup(what: str) -> Iterator[None]:
    """Marks code of ours that stops in order on its own after a signal (starting or
    closing a Dask cluster, whose workers would otherwise be cut off mid-conversation
    and log errors): the watchdog waits for it, up to :data:`CLEANUP_S` after the
    signal, before it ends the process."""
    CLEANUPS.append(what)
    try:
        yield
    finally:
        CLEANUPS.remove(what)


def end_now(code: int, line: str | None = None) -> NoReturn:
    """Ends the process at once with ``code``, from any thread: the temporary files of
    :data:`TEMPORARY` removed, ``line`` (if any) on stderr, the worker processes of
    :mod:`multiprocessing` (Dask's included) terminated, no teardown."""
    try:
        for path in list(TEMPORARY):
            try:
                os.unlink(path)
            except OSError:
                pass
        if line is not None:
            os.write(2, f"{line}\n".encode())
        processes = sys.modules.get("multiprocessing")
        for child in processes.active_children() if processes is not None else ():
            child.terminate()
    finally:
        os._exit(code)


def watchdog(seconds: float, expire: Callable[[], None]) -> threading.Timer:
    """A started daemon timer that calls ``expire`` after ``seconds``."""
    timer = threading.Timer(seconds, expire)
    timer.daemon = True
    timer.start()
    return timer


class SignalRecord:
    """The stop signals delivered while :func:`run`'s body runs, and the handler that
    records each before it raises: native code that calls back into Python (a
    C extension's import, a plugin constructor called from C++) may replace the
    raised exception with one of its own that does not chain it, so that
    :func:`run` goes by the record, not by the exception alone."""

    def __init__(self, line: str = ""):
        self.received: list[int] = []
        self.finished, self.late = False, []  # the body has ended: record (in late), do not raise
        self.line = line  # the interrupted line, printed once: by run or by the watchdog
        self.lock = threading.Lock()
        self.said = False
        self.over = False  # run has returned: the watchdog no longer acts
        self.watchdog: threading.Timer | None = None
        self.signalled = 0.0  # time.monotonic() at the first stop signal
        self.first = 0  # the first stop signal, known before its handler runs (see arrived)

    def handler(self, signum, frame):
        self.received.append(signum)
        if self.finished:
            self.late.append(signum)
            return
        self.arrived(signum)
        if signum == signal.SIGINT:
            raise KeyboardInterrupt
        raise Interrupted(signum)

    def arrived(self, signum: int) -> None:
        """A stop signal reached the process: the watchdog starts, unless it has (called by
        the handler, and earlier by :class:`SignalWakeup` while a native call defers the handler)."""
        if self.finished or self.watchdog is not None:
            return
        self.first = signum
        self.signalled = time.monotonic()
        self.watchdog = watchdog(GRACE_S, self.expire)

    def say(self) -> None:
        """Prints the interrupted line, unless it was printed."""
        with self.lock:
            if not self.said:
                self.said = True
                print(self.line, file=sys.stderr)

    def expire(self) -> None:
        """The watchdog: the body did not end within the grace period after the signal."""
        with self.lock:  # held to the end: run cannot print the line, nor return, meanwhile
            if self.over:
                return
            if CLEANUPS and time.monotonic() < self.signalled + CLEANUP_S:
                self.watchdog = watchdog(0.1, self.expire)
            else:
                end_now(128 + (self.received[0] if self.received else self.first), None if self.said else self.line)

    def end(self) -> None:
        """The body is over (run returns): the watchdog no longer acts."""
        with self.lock:
            self.over = True
        if self.watchdog is not None:
            self.watchdog.cancel()


class SignalWakeup:
    """Starts a :class:`SignalRecord`'s watchdog the moment a stop signal reaches the process:
    Python runs a handler only between the main thread's bytecodes, which a long native call
    (a render, an EXR write) defers; its C-level handler writes the signal's number to the
    wakeup fd at once, and a thread reading it starts the watchdog (those calls release the
    GIL). Off the main thread (no wakeup fd can be set there) it does nothing."""

    def __init__(self, record: SignalRecord):
        self.record = record
        self.read, self.write = os.pipe()
        os.set_blocking(self.write, False)
        try:
            self.previous = signal.set_wakeup_fd(self.write, warn_on_full_buffer=False)
        except ValueError:  # not the main thread
            os.close(self.read)
            os.close(self.write)
            self.read = None
            return
        threading.Thread(target=self.watch, name="stop signal wakeup", daemon=True).start()

    def watch(self) -> None:
        try:
            while data := os.read(self.read, 64):  # b"": every writer closed (see close)
                for signum in data:
                    if signum in STOP_SIGNALS:
                        self.record.arrived(signum)
        finally:
            os.close(self.read)

    def close(self) -> None:
        """Puts back the wakeup fd there was; the thread ends."""
        if self.read is not None:
            signal.set_wakeup_fd(self.previous)
            os.close(self.write)


#: the records of the :func:`run` bodies in progress, innermost last
ACTIVE: list[SignalRecord] = []


def stop_received() -> int | None:
    """The first stop signal delivered while a :func:`run` body runs, else None: the
    handler's exception may have been caught by code that is not ours (a method
    file's ``except BaseException``), but the record stays."""
    return next((record.received[0] for record in reversed(ACTIVE) if record.received), None)


def check_stopped() -> None:
    """Raises :class:`Interrupted` where a stop signal came during :func:`run`'s body:
    called after code of the user's (a method's hook) and before a result is written."""
    signum = stop_received()
    if signum is not None:
        raise Interrupted(signum)


def message_of(error: BaseException) -> str:
    """``TYPE: str(error)`` (``TYPE`` alone where that is empty), also where the
    exception's ``__str__`` itself raises (an exception class of a user's file)."""
    try:
        text = str(error)
    except BaseException:  # noqa: BLE001  its own __str__ failed: the type still names it
        text = "(its message could not be made: its __str__ raised)"
    return f"{type(error).__name__}: {text}" if text else type(error).__name__


@contextmanager
def hold_signals() -> Iterator[list[int]]:
    """Holds SIGINT and SIGTERM back while the block runs, and delivers them
    (to the handlers they had) right after it. Yields the list of signals
    held so far, so that the block can skip work that would only be thrown away.

    For code that an exception raised by a signal handler would break
    instead of stop: native code that runs Python callbacks (Dr.Jit's
    tracing, its start-up in ``mi.set_variant``) turns the exception into an
    ImportError, RuntimeError or SystemError with a traceback.
    """
    pending: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield pending
        return
    previous = {signum: signal.signal(signum, lambda signum, frame: pending.append(signum))
                for signum in STOP_SIGNALS}
    try:
        yield pending
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        deliver(pending, previous)


def deliver(signums: list[int], handlers: dict) -> None:
    """Each signal of ``signums`` (once) to its handler in ``handlers``, as if it came now."""
    for signum in dict.fromkeys(signums):
        handler = handlers[signum]
        if callable(handler):
            handler(signum, None)  # e.g. Python's SIGINT handler raises KeyboardInterrupt
        elif handler == signal.SIG_DFL:
            signal.raise_signal(signum)


def is_native_notice(line: str) -> bool:
    """A line of Dr.Jit's own logging: ``jit_init(): could not use ...``."""
    name, _, rest = line.partition("(): ")
    return bool(rest) and name.startswith("jit_") and name.replace("_", "").isalnum()


@contextmanager
def native_start_up(quiet: bool = True) -> Iterator[None]:
    """Runs a native library's start-up (``import drjit``) with file
    descriptor 2 captured: Dr.Jit writes its notices there directly, where
    ``sys.stderr`` cannot catch them. Afterwards the captured text is written
    back, less Dr.Jit's own notices when ``quiet``; if the block fails, all of it.

    The capture is an in-memory file (no temporary file on a full disk, and
    no ``tempfile`` import: this module loads before a script's signal handlers)."""
    try:
        sys.stderr.flush()
        capture = os.memfd_create("stderr")
        saved = os.dup(2)
    except (OSError, AttributeError):  # no memfd here: the notices stay
        yield
        return
    failed = True
    try:
        os.dup2(capture, 2)
        try:
            yield
            failed = False
        finally:
            os.dup2(saved, 2)
            os.lseek(capture, 0, os.SEEK_SET)
            chunks = []
            while chunk := os.read(capture, 1 << 16):
                chunks.append(chunk)
            lines = b"".join(chunks).decode(errors="replace").splitlines(keepends=True)
            kept = [line for line in lines if failed or not quiet or not is_native_notice(line)]
            if kept:
                os.write(2, "".join(kept).encode())
    finally:
        os.close(saved)
        os.close(capture)


def interruption(error: BaseException) -> int | None:
    """The signal number of an Interrupted / KeyboardInterrupt that is
    ``error`` or in its chain of causes and contexts, else None."""
    seen = set()
    while error is not None and id(error) not in seen:
        seen.add(id(error))
        if isinstance(error, Interrupted):
            return error.signum
        if isinstance(error, KeyboardInterrupt):
            return int(signal.SIGINT)
        error = error.__cause__ or error.__context__
    return None


class ArgumentParser(argparse.ArgumentParser):
    """argparse whose errors are :class:`core.errors.UsageError` (one line, exit 2
    under :func:`run`), not a usage block; every user-facing command parses with it.
    A path argument may not be empty (``Path("")`` is the current folder; no "give ." advice: most name a file)."""

    def error(self, message: str):
        raise UsageError(" ".join(message.split()))

    def _get_value(self, action, arg_string):  # argparse's one conversion point, groups' arguments included
        if action.type is Path and arg_string == "":
            self.error(f"{'/'.join(action.option_strings) or action.metavar}: an empty path, not a name "
                       "(an unset shell variable?)")
        return super()._get_value(action, arg_string)


def one_line(error: BaseException) -> str:
    """``str(error)`` on one line (messages never span lines), with any other
    control character (a NUL from a format spec, an escape sequence in a file
    name) shown escaped, not sent to the terminal."""
    return printable(" ".join((str(error) or type(error).__name__).split()))


def printable(value: object) -> str:
    """``str(value)`` (a path, a file's name) as printable text: a newline, a tab, an escape
    sequence or another control character is shown escaped (``\\n``, ``\\x1b``) and a byte of a
    file name that is not UTF-8 as ``\\xff``, so that a name the user chose never splits a line
    on stdout or drives the terminal. Every path a command echoes goes through it."""
    return "".join(c if c.isprintable() else f"\\x{ord(c) - 0xDC00:02x}" if "\udc80" <= c <= "\udcff"
                   else c.encode("unicode_escape").decode("ascii") for c in str(value))


def swallowed(record: SignalRecord, unraisable: Callable, info) -> None:
    """``sys.unraisablehook`` while :func:`run`'s body runs: the handler's interruption,
    raised inside a finalizer or a weakref callback (where Python prints "Exception
    ignored" and goes on), is not printed but raised again, by the same signal
    delivered anew from another thread a moment later (at once, the handler would
    raise inside this hook); anything else goes to ``unraisable``."""
    if isinstance(info.exc_value, (KeyboardInterrupt, Interrupted)) and record.received:
        threading.Timer(0.05, os.kill, (os.getpid(), record.received[-1])).start()
        return
    unraisable(info)


def run(prog: str, body: Callable[[], int | None], interrupted: str = INTERRUPTED) -> int:
    """Runs ``body`` under the error contract; returns the exit code. ``interrupted``:
    the line after ``PROG: `` when a signal stops it (a command that writes no files says so)."""
    record = SignalRecord(f"{prog}: {interrupted}")
    wakeup = SignalWakeup(record)  # before the handlers: a signal meanwhile is Python's default, not ours raised here
    handlers = dict.fromkeys((signal.SIGINT, signal.SIGTERM, signal.SIGHUP), record.handler)
    try:
        previous = {signum: signal.signal(signum, handler) for signum, handler in handlers.items()}
    except ValueError:  # not the main thread (e.g. under a test runner's worker)
        previous = {}
    ACTIVE.append(record)
    unraisable = sys.unraisablehook
    sys.unraisablehook = functools.partial(swallowed, record, unraisable)
    try:
        return int(body() or 0)
    except BaseException as error:
        signum = interruption(error)
        if signum is None and record.received:  # whatever native code made of the handler's exception
            signum = record.received[0]
        if signum is not None:
            record.say()
            return 128 + int(signum)
        if isinstance(error, ToolkitError):
            print(f"{prog}: error: {one_line(error)}", file=sys.stderr)
            return 2
        if isinstance(error, MemoryError):
            # no remedy by name: not every command has a size or a sample count
            print(f"{prog}: error: out of memory: this work needs more than the memory available", file=sys.stderr)
            return 2
        if isinstance(error, BrokenPipeError) and not error.filename:
            # stdout's reader went away (``| head``): the interpreter's last flush must not fail again
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
            os.close(devnull)
            print(f"{prog}: error: standard output was closed by its reader (broken pipe)", file=sys.stderr)
            return 2
        if isinstance(error, OSError):
            where = f" {error.filename}:" if getattr(error, "filename", None) else ""
            print(f"{prog}: error:{where} {error.strerror or one_line(error)}", file=sys.stderr)
            return 2
        raise
    finally:
        # first, before any call: a call lets a pending handler run, which would raise out of this block
        record.finished = True  # a stop signal from here on is recorded (record.late), not raised
        sys.unraisablehook = unraisable
        record.end()
        ACTIVE.remove(record)
        try:
            restore_handlers(record, previous)
        finally:
            wakeup.close()


def restore_handlers(record: SignalRecord, previous: dict) -> None:
    """Puts back the handlers :func:`run` replaced; a stop signal recorded once the body had ended is given
    to the handler put back, unless one had stopped the body (the late one is that stop sent again)."""
    record.finished = True
    if not previous:
        return
    for signum, handler in previous.items():
        signal.signal(signum, handler)
    deliver(record.late if len(record.received) == len(record.late) else [], previous)


def finish(code: int) -> NoReturn:
    """Ends a command with ``code`` once :func:`run` has returned it: every file is complete, so a stop
    signal during the interpreter's teardown (Dr.Jit's shutdown takes a moment, and Python restores the
    default handlers there, which would end the process by the signal without a word) is ignored. After a
    stop signal (``code`` 128 + one), a teardown not ended :data:`TEARDOWN_S` later (a thread that never
    ends, an exit handler that waits) is cut short with that code."""
    for signum in STOP_SIGNALS:
        signal.signal(signum, signal.SIG_IGN)
    if code - 128 in STOP_SIGNALS:
        watchdog(TEARDOWN_S, lambda: end_now(code))
    sys.exit(code)
