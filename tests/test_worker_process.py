"""The worker process of a training or a fit (denoise.worker_process)."""
from __future__ import annotations

from worker_targets import report_group_signals

from denoise.worker_process import run_in_worker


def test_the_worker_starts_with_the_group_signals_ignored():
    """A Ctrl-C to the terminal's group while the worker imports must not end it
    with a traceback (5 of 36 tries did, while its mask had them blocked): its
    Python starts with SIGINT and SIGHUP ignored, before any import."""
    (ignored,) = run_in_worker(report_group_signals, (), "the probe")
    assert ignored == {"SIGINT": True, "SIGHUP": True}
