"""core.entry's watchdog: whatever the code does after a stop signal reached the
handler (swallows the interruption in a loop, leaves a thread that never ends), the
command ends within 2 s with 130 / 143, one line, and no temporary file left behind."""
from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

#: a command whose body writes through atomic_path and, inside the write, swallows every interruption
SWALLOWING_WRITE = """
import sys, time
from core.entry import finish, run
from imaging.image_io import atomic_path

def body():
    with atomic_path(sys.argv[1], ".txt") as temporary:
        temporary.write_text("half")
        print("writing", flush=True)
        while True:
            try:
                time.sleep(0.2)
            except BaseException:
                pass

finish(run("prog", body))
"""

#: a command that returns at once on the signal, leaving a thread that never ends
ENDLESS_THREAD = """
import threading, time
from core.entry import finish, run

def body():
    threading.Thread(target=lambda: time.sleep(1000)).start()  # not a daemon: the teardown waits for it
    print("writing", flush=True)
    time.sleep(100)

finish(run("prog", body))
"""


def stopped(source: str, signum: int, *args: str) -> tuple[int, str, float]:
    process = subprocess.Popen([sys.executable, "-c", source, *args], cwd=ROOT, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    try:
        assert process.stdout.readline() == "writing\n", process.communicate(timeout=10)
        time.sleep(0.3)  # into the loop (or the sleep) that follows the line
        process.send_signal(signum)
        sent = time.monotonic()
        err = process.communicate(timeout=15)[1]
        return process.returncode, err, time.monotonic() - sent
    finally:
        if process.poll() is None:
            process.kill()
            process.wait(10)


@pytest.mark.timed
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_body_that_swallows_the_signal_inside_a_write_is_ended_without_its_temporary_file(signum, tmp_path):
    code, err, took = stopped(SWALLOWING_WRITE, signum, str(tmp_path / "out.txt"))
    assert code == 128 + signum and err == f"prog: {__import__('core.start_up').start_up.INTERRUPTED}\n", err
    assert took < 2.0, took
    assert list(tmp_path.iterdir()) == []


@pytest.mark.timed
def test_a_teardown_that_waits_for_a_thread_is_ended_with_the_code(tmp_path):
    code, err, took = stopped(ENDLESS_THREAD, signal.SIGINT)
    assert code == 130 and err.count("\n") == 1 and "Traceback" not in err, err
    assert took < 2.0, took


#: a command whose cleanup of its own (a Dask cluster's close) takes 2.5 s after the signal
SLOW_OWN_CLEANUP = """
import time
from core.entry import finish, own_cleanup, run

def body():
    try:
        print("writing", flush=True)
        time.sleep(100)
    finally:
        with own_cleanup("closing"):
            end = time.monotonic() + 2.5
            while time.monotonic() < end:
                time.sleep(0.05)
        print("closed", flush=True)

finish(run("prog", body))
"""


def test_the_watchdog_waits_for_a_cleanup_of_ours():
    process = subprocess.Popen([sys.executable, "-c", SLOW_OWN_CLEANUP], cwd=ROOT, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    try:
        assert process.stdout.readline() == "writing\n", process.communicate(timeout=10)
        time.sleep(0.3)
        process.send_signal(signal.SIGINT)
        out, err = process.communicate(timeout=15)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait(10)
    assert process.returncode == 130 and out == "closed\n" and err.count("\n") == 1, (out, err)


#: ``run`` on a body that stops by SIGINT (argv[1] "stopped") or returns 0 ("finished"), with a
#: SIGINT arriving once the body has ended and before the handlers are put back (as a stop
#: signal that the unraisable hook sends anew): prints run's exit code, or what escaped it
LATE_SIGNAL = """
import os, signal, sys
from core import entry

def body():
    if sys.argv[1] == "stopped":
        os.kill(os.getpid(), signal.SIGINT)
    return 0

def end_then_signal(self):
    os.kill(os.getpid(), signal.SIGINT)  # recorded as late: the body has finished

entry.SignalRecord.end = end_then_signal
try:
    print(entry.run("prog", body))
except KeyboardInterrupt:
    print("KeyboardInterrupt")
"""


@pytest.mark.parametrize("body, expected", [("stopped", "130"), ("finished", "KeyboardInterrupt")])
def test_a_stop_signal_after_the_body_is_dropped_only_where_one_had_stopped_it(body, expected):
    """A run stopped by SIGINT returns 130 even where that SIGINT comes again after the
    body (it had ended by SIGINT itself, after its line, once in 40 stops); a run that
    finished still gets a late signal from the handler put back."""
    done = subprocess.run([sys.executable, "-c", LATE_SIGNAL, body], cwd=ROOT, capture_output=True, text=True,
                          timeout=60)
    assert done.stdout.split() == [expected], (done.stdout, done.stderr)
