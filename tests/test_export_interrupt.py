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
