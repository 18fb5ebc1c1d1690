"""Targets of denoise.worker_process.run_in_worker for the tests (standard library only:
the spawned worker imports this module)."""
from __future__ import annotations

import signal


def report_group_signals(connection) -> None:
    """Whether SIGINT and SIGHUP were ignored in the worker from its start (nothing here changes them)."""
    connection.send(("done", {s.name: signal.getsignal(s) == signal.SIG_IGN for s in (signal.SIGINT, signal.SIGHUP)}))
