"""export on Dask: the same bytes with 1 and 2 workers as in one
process, a killed worker's tasks redone, a scheduler that goes away, several
specs into one dataset, and the scale-out benchmark's figures (at a tiny size)."""
from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path

import pytest
from test_export import BATCH_SPP, TINY, folder_bytes

pytest.importorskip("distributed")

# 2 frames x (1 frame task + 6 batches) = 14 tasks: enough for both workers to
# be busy when one is killed, small enough for CI
SPEC = dict(TINY, reference_spp=12)


def export_with(target: Path, **where):
    from export import Spec, export

    return export(Spec.from_dict(dict(SPEC)), target, batch_spp=BATCH_SPP, **where)


@pytest.fixture(scope="module")
def in_process(tmp_path_factory):
    from renderer import variants

    variants.set_variant(None, quiet=True)  # llvm_ad_rgb where usable
    target = tmp_path_factory.mktemp("local") / "seq"
    assert export_with(target, local=True) == [0, 1]
    return target


def test_one_and_two_workers_give_the_bytes_of_one_process(tmp_path, in_process):
    one, two = tmp_path / "one" / "seq", tmp_path / "two" / "seq"
    assert export_with(one, workers=1) == [0, 1]
    assert export_with(two, workers=2) == [0, 1]
    expected = folder_bytes(in_process)
    assert len(expected) == 2 * 7 + 2 * 3  # 7 files per frame, 3 per reference
    assert folder_bytes(one) == expected
    assert folder_bytes(two) == expected
    manifest = json.loads((two / "dataset.json").read_text())
    workers = {t["worker"] for f in manifest["sequences"][0]["frames"] for t in f["tasks"]}
    assert len(workers) == 2 and "local" not in workers  # really ran on both workers
    assert manifest["runner"] == "dask" and manifest["tasks"] == 14


def test_byte_comparison_fails_on_order_dependent_sums(tmp_path, in_process, monkeypatch):
    """The comparison above on purpose-broken code: the halves summed in float32
    from the last batch to the first (as completion order might have it)
    change the bytes, so a sum that depended on the order would be caught."""
    import numpy as np

    import export.recorder as export_module
    from imaging.image_io import write_exr

    def sums_last_first(sequence, frame):
        paths = [export_module.batch_path(sequence, frame, b) for b in range(len(sequence.batches()))]
        if not all(p.exists() for p in paths):
            return False
        halves = {h: np.zeros(sequence.spec.size[::-1] + (3,), np.float32) for h in "ab"}
        for (half, spp), path in reversed(list(zip(sequence.batches(), paths))):
            halves[half] += np.load(path) * np.float32(2 * spp / sequence.spec.reference_spp)
        write_exr(sequence.reference / f"half_a_{frame}.exr", {"": halves["a"]})
        write_exr(sequence.reference / f"half_b_{frame}.exr", {"": halves["b"]})
        write_exr(sequence.reference / f"beauty_{frame}.exr", {"": (halves["a"] + halves["b"]) / 2})
        return True

    monkeypatch.setattr(export_module, "assemble_reference", sums_last_first)
    broken = tmp_path / "seq"
    export_with(broken, local=True)
    assert folder_bytes(broken) != folder_bytes(in_process)


@contextmanager
def killing_a_busy_worker():
    """Beside an export in this process: SIGKILLs, once, a worker process the
    scheduler has tasks on, as soon as there is one; yields what it killed.
    The scheduler's view is what decides KilledWorker and retries (a dead
    worker's ``processing`` tasks are the suspicious ones). It watches from a
    thread of its own from the start: a hook run after each result saw nothing
    busy at times, since tasks this small can all finish before the first
    result is recorded."""
    from distributed import default_client

    killed, done = {}, threading.Event()

    def watch():
        while not done.is_set():
            try:
                client = default_client()
                busy = [address for address, keys in client.processing().items() if keys]
                pids = client.run(os.getpid) if busy else {}
            except Exception:  # noqa: BLE001  no client yet, or one starting or closing
                busy = []
            for address in busy:
                if address in pids:
                    keys = client.processing().get(address, ())
                    os.kill(pids[address], signal.SIGKILL)
                    killed.update(address=address, pid=pids[address], keys=[str(k) for k in keys])
                    return
            time.sleep(0.005)

    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    try:
        yield killed
    finally:
        done.set()
        watcher.join()


def test_killed_worker_is_replaced_and_the_result_is_unchanged(tmp_path, in_process):
    """SIGKILL one of two worker processes while it holds tasks; Dask (its
    nanny restarts the process) reruns them; the files equal one process's."""
    target = tmp_path / "seq"
    with killing_a_busy_worker() as killed:
        assert export_with(target, workers=2) == [0, 1]
    assert killed, "no worker was busy after any result: the test did not kill anything"
    with pytest.raises(ProcessLookupError):
        os.kill(killed["pid"], 0)
    assert folder_bytes(target) == folder_bytes(in_process)
    manifest = json.loads((target / "dataset.json").read_text())
    frames = manifest["sequences"][0]["frames"]
    assert [f["status"] for f in frames] == ["rendered", "rendered"]
    assert sum(len(f["tasks"]) for f in frames) == 14
    entry = manifest["sequences"][0]

    def name(frame, task):
        tail = "frame" if task["kind"] == "frame" else f"batch{task['batch']}"
        return f"{entry['name']}-{entry['key'][:8]}-{frame['index']}-{tail}"

    finished_by = {name(f, t): t["worker"] for f in frames for t in f["tasks"]}
    # the task it was running was finished by another process (the restarted one has a new
    # address), unless the kill lost a race with that task's own result (a short batch can
    # finish between the look at the worker and the SIGKILL); that Dask retries at all is
    # shown by test_kill_check_fails_when_dask_may_not_retry
    raced = all(finished_by.get(key) == killed["address"] for key in killed["keys"])
    assert raced or any(finished_by.get(key) not in (None, killed["address"]) for key in killed["keys"]), \
        (killed, finished_by)


def test_kill_check_fails_when_dask_may_not_retry(tmp_path, in_process):
    """The kill test on purpose-broken fault tolerance (no retries allowed):
    the same kill ends the export with KilledWorker instead (one line: a
    ClusterError that names the task and the remedy). A kill can lose
    the race with its task's own result (a short batch finishes between the
    look at the worker and the SIGKILL; then nothing is lost), so it is
    tried up to three times: one KilledWorker shows the check bites."""
    import dask
    from distributed import KilledWorker

    from core.errors import ClusterError

    outcomes = []
    for attempt in range(3):
        with dask.config.set({"distributed.scheduler.allowed-failures": 0}), killing_a_busy_worker() as killed:
            try:
                export_with(tmp_path / f"seq{attempt}", workers=2)
            except ClusterError as error:
                assert isinstance(error.__cause__, KilledWorker), error
                assert "lost a worker on task" in str(error) and "resumes" in str(error), error
                return
        assert killed, "no worker was busy after any result: the test did not kill anything"
        outcomes.append(killed)
    pytest.fail(f"no KilledWorker in three kills without retries: {outcomes}")


ROOT = Path(__file__).resolve().parent.parent


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def worker_env() -> dict:
    """A user's environment: without the PYTHONPATH the test session gives its children (the checkout)."""
    return {name: value for name, value in os.environ.items() if name != "PYTHONPATH"}


@contextmanager
def own_cluster(tmp_path: Path, worker_python: str | None = sys.executable):
    """A Dask scheduler and (unless ``worker_python`` is None) one worker of that
    Python, as a user starts them (docs/dataset.md); yields (address, scheduler's process)."""
    address = f"tcp://127.0.0.1:{free_port()}"
    quiet = dict(stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    processes = [subprocess.Popen([Path(sys.executable).with_name("dask"), "scheduler", "--host", "127.0.0.1",
                                   "--port", address.rsplit(":", 1)[1], "--no-dashboard"], **quiet)]
    if worker_python is not None:
        processes.append(start_worker(tmp_path, address, worker_python))
    try:
        yield address, processes[0]
    finally:
        for process in processes:
            process.kill()
            process.wait()


def start_worker(tmp_path: Path, address: str, worker_python: str = sys.executable) -> subprocess.Popen:
    """One Dask worker of ``worker_python`` on the scheduler at ``address``, as a user starts one."""
    return subprocess.Popen([worker_python, "-m", "distributed.cli.dask_worker", address, "--nthreads", "1",
                             "--no-dashboard"], cwd=tmp_path, env=worker_env(), stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)


def start_export(tmp_path: Path, address: str) -> tuple[subprocess.Popen, Path]:
    spec = tmp_path / "seq.json"
    spec.write_text(json.dumps(dict(TINY, size=[64, 48], frames=3, reference_spp=512)))
    target = tmp_path / "out" / "seq"
    export = subprocess.Popen([sys.executable, "-m", "export", str(spec), str(target), "--scheduler", address,
                               "--batch-spp", "4"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True)
    return export, target


#: run on workers; a lambda travels by value (a user's worker cannot import this module)
parse_is_serialized = lambda: getattr(__import__("ast").parse, "serialized", False)  # noqa: E731


@pytest.mark.parametrize("cluster", ["LocalCluster", "own"])
def test_every_worker_parses_python_one_call_at_a_time(tmp_path, cluster):
    """CPython 3.11 keeps the AST constructor's recursion depth per interpreter:
    a worker's event loop parsing a task's signature while the task thread's
    first Mitsuba import parsed its integrators failed the task ("AST
    constructor recursion depth mismatch", 1 of 22 runs of the killed-worker
    test under load). Our LocalCluster's workers (by their preload) and those
    of a user's cluster (by the plugin the export registers, a worker that joins
    later too) serialize ast.parse."""
    from distributed import Client

    from export.cluster import dask_client

    if cluster == "LocalCluster":
        with dask_client(workers=2) as (client, _):
            assert list(client.run(parse_is_serialized).values()) == [True, True]
        return
    with own_cluster(tmp_path) as (address, _):
        with Client(address, timeout="15s") as client:
            client.wait_for_workers(1, timeout=60)
            assert list(client.run(parse_is_serialized).values()) == [False]  # a user's worker as it starts
        with dask_client(address) as (client, _):
            assert list(client.run(parse_is_serialized).values()) == [True]
            late = start_worker(tmp_path, address)  # a worker that joins after the export started
            try:
                client.wait_for_workers(2, timeout=60)
                assert list(client.run(parse_is_serialized).values()) == [True, True]
            finally:
                late.kill()
                late.wait()


def test_a_scheduler_that_goes_away_is_one_line(tmp_path):
    """``--scheduler`` on a cluster of its own whose scheduler is killed while the
    export renders: exit 2 and one line that says so and how to resume (Dask
    reports the loss as cancelled futures, which the export took for results)."""
    with own_cluster(tmp_path) as (address, scheduler):
        export, target = start_export(tmp_path, address)
        batches = target.parent / "seq_reference" / ".batches"
        deadline = time.monotonic() + 120
        while not list(batches.glob("*/*.npy")):
            assert export.poll() is None and time.monotonic() < deadline, export.communicate()
            time.sleep(0.05)
        scheduler.kill()
        out, err = export.communicate(timeout=120)
    assert export.returncode == 2, err[-3000:]
    assert err.count("\n") == 1 and "Dask scheduler" in err and "resumes" in err, err[-3000:]
    assert "Traceback" not in err


def test_an_unreachable_scheduler_leaves_no_folder(tmp_path, capsys):
    """``--scheduler`` where no scheduler listens: one line, exit 2, and nothing of the
    folders the export made before it looked for the cluster (their claim named a
    sequence that never rendered); a folder that was there before keeps its claim."""
    from export.cli import main

    spec = tmp_path / "seq.json"
    spec.write_text(json.dumps(dict(TINY, frames=1)))
    address = f"127.0.0.1:{free_port()}"
    assert main([str(spec), str(tmp_path / "set" / "seq"), "--scheduler", address]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cannot reach a Dask scheduler" in err, err
    assert not (tmp_path / "set").exists()
    kept = tmp_path / "kept" / "seq"
    assert main([str(spec), str(kept), "--local"]) == 0
    (kept / "beauty_0.exr").unlink()  # a frame to render again
    capsys.readouterr()
    assert main([str(spec), str(kept), "--scheduler", address]) == 2
    assert "cannot reach a Dask scheduler" in capsys.readouterr().err
    assert (kept / "sequence.json").is_file() and (kept / "depth_0.exr").is_file()


@contextmanager
def not_a_scheduler(answer: bytes | None):
    """A TCP server on a free port that accepts and sends ``answer`` (None: stays
    silent), as a web server or another service at a mistyped address would; yields its address."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen()
    held = []

    def serve():
        while True:
            try:
                connection, _ = server.accept()
            except OSError:  # closed
                return
            held.append(connection)
            if answer is not None:
                connection.sendall(answer)

    threading.Thread(target=serve, daemon=True).start()
    try:
        yield f"tcp://127.0.0.1:{server.getsockname()[1]}"
    finally:
        server.close()
        for connection in held:
            connection.close()


@pytest.mark.parametrize("answer", [None, b"\xff" * 4096, b"HTTP/1.0 400 Bad Request\r\n\r\n"],
                         ids=["silent", "other-bytes", "http"])
def test_an_address_that_is_no_dask_scheduler_is_one_line(tmp_path, answer):
    """--scheduler at a server of another kind: one line and exit 2 within the
    connection's bound (a silent one held the export forever; other bytes ended it in
    a traceback, or in an "out of memory" line), and no folder left behind. In a
    process of its own: the attempt it gives up on stays behind in its thread, and
    a later Dask client of the same process waited on it."""
    from export.cluster import CONNECT_GRACE_S, CONNECT_S

    spec = tmp_path / "seq.json"
    spec.write_text(json.dumps(dict(TINY, frames=1)))
    with not_a_scheduler(answer) as address:
        start = time.monotonic()
        result = subprocess.run([sys.executable, "-m", "export", str(spec), str(tmp_path / "set" / "seq"),
                                 "--scheduler", address], cwd=ROOT, capture_output=True, text=True, timeout=120)
        took = time.monotonic() - start
    err = result.stderr
    assert result.returncode == 2 and err.count("\n") == 1 and "cannot reach a Dask scheduler" in err, err
    assert "Traceback" not in err and "memory" not in err, err
    assert took < CONNECT_S + CONNECT_GRACE_S + 15, took  # the bound, and the command's start
    assert not (tmp_path / "set").exists()


def test_a_worker_without_the_project_is_one_line(tmp_path):
    """A worker whose Python has Dask and Mitsuba but not this project (a venv of
    its own that sees the packages, started outside the checkout): the export's
    first call on it fails, and the user is told what every worker needs."""
    from distributed import Client

    foreign = tmp_path / "foreign"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(foreign)], check=True)
    packages = next(Path(sys.prefix).glob("lib/python3*/site-packages"))
    next(foreign.glob("lib/python3*/site-packages")).joinpath("packages.pth").write_text(f"{packages}\n")
    with own_cluster(tmp_path, str(foreign / "bin" / "python")) as (address, _):
        probe = subprocess.run([foreign / "bin" / "python", "-c", "import distributed, mitsuba; import core"],
                               capture_output=True, text=True, cwd=tmp_path, env=worker_env())
        assert "No module named 'core'" in probe.stderr, probe.stderr  # what the worker lacks, and only that
        with Client(address, timeout="15s") as client:  # its worker registered: the export's first call reaches it
            client.wait_for_workers(1, timeout=60)
        export, _ = start_export(tmp_path, address)
        out, err = export.communicate(timeout=120)
    assert export.returncode == 2, err[-3000:]
    assert err.count("\n") == 1 and "a worker cannot run the export's code" in err, err[-3000:]
    assert "No module named 'export'" in err and "every worker needs this project" in err, err
    assert "Traceback" not in err


def test_a_scheduler_without_workers_says_so(tmp_path):
    """A scheduler with no worker: the export says once that it waits, and why, and
    Ctrl-C ends it as ever (it waited in silence)."""
    with own_cluster(tmp_path, None) as (address, _):
        export, _ = start_export(tmp_path, address)
        lines = []
        reader = threading.Thread(target=lambda: lines.extend(export.stderr), daemon=True)
        reader.start()
        deadline = time.monotonic() + 30
        while not any("has no workers" in line for line in lines) and time.monotonic() < deadline:
            time.sleep(0.1)
        export.send_signal(signal.SIGINT)
        export.wait(timeout=60)
        reader.join(timeout=10)
    said = "".join(lines)
    assert export.returncode == 130, said
    assert said.count("\n") == 2 and f"the Dask scheduler at {address} has no workers" in said, said
    assert "interrupted" in said.splitlines()[-1]


def test_the_manifest_keeps_the_sequences_of_earlier_exports(tmp_path):
    """Sequences exported into one set one at a time (as train and validate add
    what is missing to their --work): dataset.json lists them all, each entry as
    the run that made it recorded it, until its folder no longer holds that sequence."""
    import shutil

    from export import Spec
    from export.runners import export_sequences, sequences_into
    from renderer import variants

    variants.set_variant(None, quiet=True)
    out = tmp_path / "set"
    specs = {"first": Spec.from_dict(dict(SPEC, frames=1)),
             "second": Spec.from_dict(dict(SPEC, frames=1, camera={"pan": [0.3, 0, 0]}))}

    def export_one(name):
        sequences = sequences_into([(specs[name], out / name)])
        export_sequences(sequences, local=True, manifest=out / "dataset.json")
        return [s["name"] for s in json.loads((out / "dataset.json").read_text())["sequences"]]

    assert export_one("first") == ["first"]
    assert export_one("second") == ["first", "second"]
    assert export_one("second") == ["first", "second"]  # nothing to do
    shutil.rmtree(out / "first")
    assert export_one("second") == ["second"]


def test_dataset_of_two_specs_and_the_cli(tmp_path, capsys):
    """Two specs -> OUT/<name> and OUT/<name>_reference each, and one manifest
    (the layout does not depend on where tasks run: here in this process)."""
    from export import main

    paths = []
    for name, change in (("first", {}), ("second", {"frames": 1, "camera": {"pan": [0.3, 0, 0]}})):
        path = tmp_path / f"{name}.json"
        path.write_text(json.dumps(dict(SPEC, **change)))
        paths.append(str(path))
    out = tmp_path / "set"
    assert main(paths + [str(out), "--local", "--batch-spp", str(BATCH_SPP)]) == 0
    assert "2 frames rendered into" in capsys.readouterr().out
    manifest = json.loads((out / "dataset.json").read_text())
    assert [s["name"] for s in manifest["sequences"]] == ["first", "second"]
    assert [len(s["frames"]) for s in manifest["sequences"]] == [2, 1]
    for entry in manifest["sequences"]:
        assert {"spec", "variant", "versions", "seeds", "reference_spp", "batch_spp"} <= set(entry["settings"])
        for frame in entry["frames"]:
            assert frame["status"] == "rendered" and frame["tasks"]
            assert all(t["seconds"] > 0 for t in frame["tasks"])
    assert sorted(p.name for p in (out / "second_reference").iterdir()) == [
        "beauty_0.exr", "ground_truth.json", "half_a_0.exr", "half_b_0.exr"]
    assert (out / "first" / "sequence.json").exists() and (out / "second" / "matrix_0.mat").exists()
    # the same name twice would share a folder
    assert main([paths[0], paths[0], str(tmp_path / "dup"), "--local"]) == 2
    assert "would share one folder" in capsys.readouterr().err


@pytest.mark.slow
def test_scaleout_benchmark_reports_its_figures(tmp_path):
    import subprocess
    import sys

    path = tmp_path / "scaleout.json"
    finished = subprocess.run([sys.executable, "-m", "benchmarks.scaleout", "--json", str(path), "--frames", "1",
                               "--size", "16", "12", "--reference-spp", "4", "--batch-spp", "1"],
                              cwd=Path(__file__).resolve().parent.parent, capture_output=True, text=True, timeout=1800)
    assert finished.returncode == 0, finished.stderr[-3000:]
    result = json.loads(path.read_text())
    assert result["identical"] is True
    assert result["tasks"] == 2 * (1 + 4)
    # (the JSON rounds times to milliseconds: a tiny run's ratio is only that precise)
    assert result["efficiency"] == pytest.approx(result["local_s"] / result["cluster_s"], rel=2e-2)
    assert 0 < result["overhead_s"] < result["cluster_s"] and result["task_median_s"] > 0
