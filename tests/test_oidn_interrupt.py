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

#: each test here bounds a wall-clock time (see conftest.time_alone)
pytestmark = pytest.mark.timed


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


class HeldRelease(NativeSleep):
    """As :class:`NativeSleep`, and its release waits for the execute to end, as OIDN's
    ``oidnReleaseFilter`` does (it takes the device's lock that the execute holds)."""

    def __init__(self, real, seconds: float):
        super().__init__(real, seconds)
        self.lock = threading.Lock()

    def execute(self):
        with self.lock:
            super().execute()

    def release(self):
        with self.lock:
            self.real.release()


def test_an_oidn_left_running_by_a_stop_signal_is_dropped_at_once():
    """The interrupted execute goes on in its thread; dropping the OIDN object (the
    interpreter's teardown does) leaves the filter to it rather than waiting for it.
    Python 3.11's ``Thread.join`` marks a thread stopped when a signal's exception cuts
    the join short, so that the thread's own state cannot tell."""
    import gc

    from denoise.methods.oidn import OIDN

    oidn = OIDN()
    oidn.set_inputs(np.ones((16, 16, 3), np.float32))
    held = oidn.filter = HeldRelease(oidn.filter, 2.0)

    def stop(signum, frame):
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGINT, stop)
    timer = threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGINT))
    try:
        timer.start()
        with pytest.raises(KeyboardInterrupt):
            oidn.execute()
    finally:
        timer.cancel()
        signal.signal(signal.SIGINT, previous)
    gc.collect()  # the suite's other garbage first: collecting it took 0.8 s on a slow machine
    start = time.monotonic()
    gc.collect()  # what a full collection of this worker's heap takes by itself (0.66 s in a CI run)
    heap = time.monotonic() - start
    start = time.monotonic()
    del oidn
    gc.collect()
    took = time.monotonic() - start - heap
    with held.lock:  # the execute ends in its thread (then nothing else runs on it)
        pass
    assert took < 0.5, took  # a drop that waited for the held release would take 2 s more
