"""A stop signal during OIDN's execute (seconds of native code at 1280x720 ``high``)
is taken at once: the execute runs on a worker thread the main thread waits on."""
from __future__ import annotations

import ctypes
import os
import signal
import threading
import time

import numpy as np
import pytest


class NativeSleep:
    """A filter whose execute is native code that holds no GIL and sees no signal (as OIDN's)."""

    def __init__(self, real, seconds: float):
        self.real, self.seconds = real, seconds

    def execute(self):
        blocked = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})  # no EINTR cuts the sleep short
        try:
            ctypes.CDLL(None).usleep(int(self.seconds * 1e6))
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, blocked)

    def __getattr__(self, name):
        return getattr(self.real, name)


def test_a_stop_signal_during_an_oidn_execute_is_taken_at_once():
    from denoise.methods.oidn import OIDN

    oidn = OIDN()
    oidn.set_inputs(np.ones((16, 16, 3), np.float32))
    real = oidn.filter
    oidn.filter = NativeSleep(real, 3.0)

    def stop(signum, frame):
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGINT, stop)
    timer = threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGINT))
    start = time.monotonic()
    try:
        timer.start()
        with pytest.raises(KeyboardInterrupt):
            oidn.execute()
        took = time.monotonic() - start
    finally:
        timer.cancel()
        signal.signal(signal.SIGINT, previous)
    assert took < 1.0, took
    oidn.filter = real  # the next execute waits for the one left running, then runs
    assert oidn(np.ones((16, 16, 3), np.float32)).shape == (16, 16, 3)
