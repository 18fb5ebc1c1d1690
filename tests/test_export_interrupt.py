"""Ctrl-C during an export, in this process (``--local``) or on a cluster
(``--workers N``): exit 130, one line on stderr, nothing on stdout (no
Mitsuba warning from the workers), no worker process left."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_export import TINY

from validation.stress.system import python_started

pytest.importorskip("distributed")
psutil = pytest.importorskip("psutil")

ROOT = Path(__file__).resolve().parent.parent


def export_interrupted(tmp_path, flags: list[str], ready, command: str = "export") -> tuple[list, str]:
    """Starts an export of a small sequence (``command``: ``export``, or
    ``denoise.train``, which renders its sequence first) in a session of its
    own and sends SIGINT to its process group (what a terminal's Ctrl-C sends)
    once ``ready(pid, target)`` gives its worker processes (None: not yet);
    checks the one line and exit 130; returns (the workers, stderr). stderr is
    read until every process that holds it has ended, multiprocessing's
    resource tracker included."""
    spec = tmp_path / "seq.json"
    tiny = dict(TINY, size=[64, 48], frames=3, reference_spp=256)
    if command != "export":  # a training takes no benchmark scene
        tiny = {k: v for k, v in tiny.items() if k != "objects"} | {"scene": "showcase"}
    spec.write_text(json.dumps(tiny))
    target = tmp_path / "out" / "seq"
    where = [str(target)] if command == "export" else ["--work", str(target.parent), "--out",
                                                        str(tmp_path / "w.json")]
    export = subprocess.Popen([sys.executable, "-m", command, str(spec), *where, *flags], cwd=ROOT,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 300
        workers = None
        while workers is None:
            assert export.poll() is None and time.monotonic() < deadline, export.communicate()
            workers = ready(export.pid, target)
            time.sleep(0.01)
        os.killpg(export.pid, signal.SIGINT)
        out, err = export.communicate(timeout=60)
    finally:
        if export.poll() is None:
            os.killpg(export.pid, signal.SIGKILL)
    assert export.returncode == 130, err
    assert out == ""
    assert err.count("\n") == 1 and err.startswith(f"python -m {command}: interrupted"), err
    gone, alive = psutil.wait_procs(workers, timeout=10)
    assert not alive, alive
    assert not (target / ".export.lock").exists()
    return workers, err


@pytest.mark.parametrize("where", [["--local"], ["--workers", "2"]], ids=["local", "cluster"])
def test_ctrl_c_during_an_export_is_one_line_and_leaves_no_worker(tmp_path, where):
    def rendering(pid, target):  # its ground truth's first batch written: the workers are rendering
        batches = target.parent / "seq_reference" / ".batches"
        return psutil.Process(pid).children(recursive=True) if list(batches.glob("*/*.npy")) else None

    workers, _ = export_interrupted(tmp_path, [*where, "--batch-spp", "4"], rendering)
    assert len(workers) >= (2 if "--workers" in where else 0), workers


def test_ctrl_c_during_a_trainings_render_is_one_line(tmp_path):
    """The training renders its sequences on a cluster and ends at once on a
    signal (the workers terminated, no teardown): one line, exit 130, no worker
    left, nothing after the line from multiprocessing's resource tracker."""
    def rendering(pid, target):
        batches = target.parent / "seq_reference" / ".batches"
        return psutil.Process(pid).children(recursive=True) if list(batches.glob("*/*.npy")) else None

    workers, _ = export_interrupted(tmp_path, ["--workers", "2"], rendering, command="denoise.train")
    assert len(workers) >= 2, workers


def test_ctrl_c_while_the_workers_start_is_one_line(tmp_path):
    """The terminal's Ctrl-C reaches the whole process group: sent as soon as the
    first worker's Python has set up its signals (it is still importing, long
    before Dask's preload), it is one line, exit 130, from the export alone,
    and no worker is left."""
    def starting(pid, target):
        workers = [p for p in psutil.Process(pid).children(recursive=True)
                   if "--multiprocessing-fork" in " ".join(p.cmdline()) and python_started(p.pid)]
        return workers or None

    export_interrupted(tmp_path, ["--workers", "2"], starting)


#: a LocalCluster of one worker whose scheduler stops without a word to it (as
#: when the export's process ends first); the process then ends without closing
WORKER_WITHOUT_SCHEDULER = """
import os, sys, time
from export.cluster import dask_client

async def stop(dask_scheduler):
    dask_scheduler.stop()

if __name__ == "__main__":
    with dask_client(workers=1) as (client, _):
        client.run_on_scheduler(stop)
        time.sleep(4)  # the worker's heartbeat is due about every second and fails after 1 s
        print("END", file=sys.stderr, flush=True)  # after it: Python's notes on ending this way
        os._exit(0)
"""


def test_a_worker_that_loses_its_scheduler_logs_nothing(tmp_path):
    """After a Ctrl-C the scheduler may close before a worker's heartbeat: the
    worker's traceback would come before the export's one line."""
    script = tmp_path / "lose_scheduler.py"
    script.write_text(WORKER_WITHOUT_SCHEDULER)
    # a refused connection is retried for this long (30 s by default) before the worker logs
    env = dict(os.environ, PYTHONPATH=str(ROOT), DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT="1s")
    result = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True,
                            text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stderr.startswith("END\n"), result.stderr[-2000:]


#: a frame whose ground-truth batch is one render of several seconds (about 90 M samples)
LONG_FRAME = dict(TINY, size=[1200, 1200], frames=1, reference_spp=128)
#: the stop contract's 2 s, and the moment the OS takes to free a render's memory (about 1 s for this one)
LONG_FRAME_STOP_S = 3.0


@pytest.mark.timed
@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_signal_during_a_long_render_ends_the_export_at_once(tmp_path, signum):
    """A frame's render is one native call, during which Python cannot run the handler:
    the watchdog starts when the signal arrives (core.entry.SignalWakeup), not when the
    render returns, and ends the export with the one line and no temporary file."""
    from export.files import LOCK_NAME
    from validation.stress.system import interrupt, temporary_files

    spec = tmp_path / "long.json"
    spec.write_text(json.dumps(LONG_FRAME))
    target = tmp_path / "out" / "long"
    result = interrupt([sys.executable, "-m", "export", str(spec), str(target), "--local"], delay=8.0,
                       signum=signum, cwd=ROOT, timeout=120, after_handler=True)
    print(f"{signal.Signals(signum).name}: exit {result.seconds:.2f} s after the signal, code {result.code}")
    assert result.running, "the export ended before the signal"
    assert result.code == 128 + signum, result.stderr[-2000:]
    assert result.seconds <= LONG_FRAME_STOP_S
    lines = result.stderr.strip().splitlines()
    assert lines and "interrupted" in lines[-1], result.stderr[-2000:]
    # no file of a write in progress; the lock file may stay (an flock, released with the process)
    assert [p for p in temporary_files(tmp_path / "out") if p.name != LOCK_NAME] == []
