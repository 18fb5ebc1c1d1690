"""One wrapper for every command-line entry point: the error contract.

    def main(argv=None) -> int:
        return run("render.py", lambda: _main(argv))

- a :class:`~core.errors.ToolkitError` prints ``PROG: error: MESSAGE`` (one
  line) and returns 2;
- an ``OSError`` (a file we could not read or write) prints one line naming
  the file and returns 2; ``MemoryError`` one line and 2;
- Ctrl-C (SIGINT) and SIGTERM print one line and return 130 / 143; the
  handler raises :class:`Interrupted` (a ``BaseException``), so every
  ``atomic_path`` on the way out removes its temporary file.

Anything else is a bug and keeps its traceback.
"""
from __future__ import annotations

import signal
import sys
from typing import Callable

from .errors import ToolkitError


class Interrupted(BaseException):
    """SIGTERM (or SIGINT) delivered while the program runs."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def _raise_interrupted(signum, frame):
    raise Interrupted(signum)


def one_line(error: BaseException) -> str:
    """``str(error)`` on one line (messages never span lines)."""
    text = str(error) or type(error).__name__
    return " ".join(text.split())


def run(prog: str, body: Callable[[], int | None]) -> int:
    """Runs ``body`` under the error contract; returns the exit code."""
    previous = signal.getsignal(signal.SIGTERM)
    try:
        signal.signal(signal.SIGTERM, _raise_interrupted)
    except ValueError:  # not the main thread (e.g. under a test runner's worker)
        previous = None
    try:
        return int(body() or 0)
    except ToolkitError as error:
        print(f"{prog}: error: {one_line(error)}", file=sys.stderr)
        return 2
    except MemoryError:
        print(f"{prog}: error: out of memory; try a smaller size or fewer samples", file=sys.stderr)
        return 2
    except OSError as error:
        where = f" {error.filename}" if getattr(error, "filename", None) else ""
        print(f"{prog}: error:{where}: {error.strerror or one_line(error)}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, Interrupted) as stop:
        signum = stop.signum if isinstance(stop, Interrupted) else signal.SIGINT
        print(f"{prog}: interrupted; finished files are complete, unfinished ones were not written",
              file=sys.stderr)
        return 128 + int(signum)
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
