"""A command's first line of defence against signals, standard library only.

A script imports this before anything else (``core.entry`` itself takes a
moment to import on a loaded machine): from then on SIGINT, SIGTERM and SIGHUP
print the interrupted line and exit with 128 + the signal at once, until
``core.entry.run`` installs its own handlers. Earlier than this a signal lands
in Python's own start-up, which no program can handle, but for a command that
:mod:`core.launcher` re-executed: it blocks them across the ``exec``.
"""
import atexit
import os
import signal

#: What an interrupted command prints (after ``PROG: ``)
INTERRUPTED = "interrupted; finished files are complete, unfinished ones were not written"
#: What a command that writes no files (the live page) prints instead
NOTHING_WRITTEN = "stopped (it writes no files)"
#: SIGHUP too: a closed terminal or SSH session would otherwise kill the
#: process at once, leaving an unfinished write's temporary file behind
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


def exit_on_signals(prog: str, stopped: str = INTERRUPTED) -> None:
    """The stop signals print ``PROG: stopped`` (the interrupted line) and exit
    (128 + signal) at once: for a script's start-up, before ``core.entry.run``
    installs its handlers (a KeyboardInterrupt there would be a traceback from inside some import)."""
    line = f"{prog}: {stopped}\n".encode()

    def stop(signum, frame):
        os.write(2, line)
        os._exit(128 + signum)

    for signum in STOP_SIGNALS:
        signal.signal(signum, stop)
    # blocked by a launcher that re-executed this command (core.launcher): a signal
    # that came during this Python's start-up is pending, and is handled now
    signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)
    atexit.register(ignore_stop_signals)


def ignore_stop_signals() -> None:
    """The last of a command's exit hooks: the stop signals ignored for the rest of
    the interpreter's teardown, where Python puts the default action back for
    any signal a Python handler took (a signal would then end the process
    without a word). A command that ends by ``sys.exit`` (argparse's
    ``--help`` among them) has written all it writes by then."""
    for signum in STOP_SIGNALS:
        signal.signal(signum, signal.SIG_IGN)
