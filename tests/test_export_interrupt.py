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

pytest.importorskip("distributed")
psutil = pytest.importorskip("psutil")

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.parametrize("where", [["--local"], ["--workers", "2"]], ids=["local", "cluster"])
def test_ctrl_c_during_an_export_is_one_line_and_leaves_no_worker(tmp_path, where):
    spec = tmp_path / "seq.json"
    spec.write_text(json.dumps(dict(TINY, size=[64, 48], frames=3, reference_spp=256)))
    target = tmp_path / "out" / "seq"
    # its own session: the test's SIGINT to the group is what a terminal's Ctrl-C sends
    export = subprocess.Popen([sys.executable, "-m", "export", str(spec), str(target), *where,
                               "--batch-spp", "4"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 300
        batches = target.parent / "seq_reference" / ".batches"
        while not list(batches.glob("*/*.npy")):  # the workers are rendering
            assert export.poll() is None and time.monotonic() < deadline, export.communicate()
            time.sleep(0.05)
        workers = psutil.Process(export.pid).children(recursive=True)
        assert len(workers) >= (2 if "--workers" in where else 0), workers
        os.killpg(export.pid, signal.SIGINT)
        out, err = export.communicate(timeout=60)
    finally:
        if export.poll() is None:
            os.killpg(export.pid, signal.SIGKILL)
    assert export.returncode == 130, err
    assert out == ""
    assert err.count("\n") == 1 and err.startswith("python -m export: interrupted"), err
    gone, alive = psutil.wait_procs(workers, timeout=10)
    assert not alive, alive
    assert not (target / ".export.lock").exists()


def python_started(pid: int) -> bool:
    """Whether process ``pid`` is a Python past its start-up: SIGINT caught (Python's
    handler) or ignored (left so by Python), where a shell or a fresh fork has neither."""
    try:
        status = dict(line.split(":\t", 1) for line in Path(f"/proc/{pid}/status").read_text().splitlines()
                      if ":\t" in line)
        caught, ignored = int(status["SigCgt"], 16), int(status["SigIgn"], 16)
    except (OSError, KeyError, ValueError):
        return False
    return bool((caught | ignored) & (1 << (signal.SIGINT - 1))) and "python" in Path(f"/proc/{pid}/exe").resolve().name


def test_ctrl_c_while_the_workers_start_is_one_line(tmp_path):
    """The terminal's Ctrl-C reaches the whole process group: sent as soon as the
    first worker's Python has set up its signals (it is still importing, long
    before Dask's preload), it is one line, exit 130, from the export alone,
    and no worker is left."""
    spec = tmp_path / "seq.json"
    spec.write_text(json.dumps(dict(TINY, size=[64, 48], frames=3, reference_spp=256)))
    export = subprocess.Popen([sys.executable, "-m", "export", str(spec), str(tmp_path / "out" / "seq"),
                               "--workers", "2"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        workers = []
        while not workers:
            assert export.poll() is None and time.monotonic() < deadline, export.communicate()
            workers = [p for p in psutil.Process(export.pid).children(recursive=True)
                       if "--multiprocessing-fork" in " ".join(p.cmdline()) and python_started(p.pid)]
            time.sleep(0.01)
        os.killpg(export.pid, signal.SIGINT)
        out, err = export.communicate(timeout=60)
    finally:
        if export.poll() is None:
            os.killpg(export.pid, signal.SIGKILL)
    assert export.returncode == 130, err
    assert out == ""
    assert err.count("\n") == 1 and err.startswith("python -m export: interrupted"), err
    gone, alive = psutil.wait_procs(workers, timeout=10)
    assert not alive, alive
