"""A crash-safe export: killed (SIGKILL) at any instant of its file work, a
rerun ends with the bytes of an uninterrupted run; two exports into one
folder, and a dataset whose folders collide, are refused before anything is
written; a folder in the way is named."""
from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_export import BATCH_SPP, TINY

ROOT = Path(__file__).resolve().parent.parent

#: Runs the CLI on the tiny sequence, counting every file operation on the
#: output (creating, renaming, flushing, removing); at operation number
#: $EXPORT_KILL_AT it SIGKILLs itself, as a power cut or ``kill -9`` would.
#: Without it, it writes the list of operations to $EXPORT_EVENTS.
CHILD = r"""
import json, os, signal, sys
from renderer import variants
variants.set_variant(None, quiet=True)  # llvm_ad_rgb where usable
from export.cli import main

out = os.path.dirname(os.path.abspath(sys.argv[2]))
kill_at = int(os.environ.get("EXPORT_KILL_AT", "0"))
events = []

def counted(name, call):
    def wrapper(*args, **kwargs):
        path = str(args[0]) if args and not isinstance(args[0], int) else ""
        if name == "fsync" or out in path or kwargs.get("dir_fd") is not None:
            events.append(f"{name} {os.path.basename(os.path.dirname(path))}/{os.path.basename(path)}")
            if len(events) == kill_at:
                os.kill(os.getpid(), signal.SIGKILL)
        return call(*args, **kwargs)
    return wrapper

for name in ("open", "replace", "fsync", "unlink", "rmdir", "mkdir"):
    setattr(os, name, counted(name, getattr(os, name)))
code = main(sys.argv[1:])
if "EXPORT_EVENTS" in os.environ:
    with open(os.environ["EXPORT_EVENTS"], "w") as file:
        json.dump(events, file)
sys.exit(code)
"""


def tree(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` by its relative path, but the manifest
    (its timings and run ids differ from run to run)."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name != "dataset.json"}


def run_child(work: Path, kill_at: int = 0, events: Path | None = None) -> subprocess.CompletedProcess:
    spec = work / "seq.json"
    spec.write_text(json.dumps(TINY))
    (work / "child.py").write_text(CHILD)
    env = dict(os.environ, EXPORT_KILL_AT=str(kill_at), PYTHONPATH=str(ROOT))
    if events:
        env["EXPORT_EVENTS"] = str(events)
    return subprocess.run([sys.executable, str(work / "child.py"), str(spec), str(work / "out" / "seq"), "--local",
                           "--batch-spp", str(BATCH_SPP)], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=600)


def rerun(work: Path) -> None:
    from export import main

    assert main([str(work / "seq.json"), str(work / "out" / "seq"), "--local", "--batch-spp", str(BATCH_SPP)]) == 0


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    """(the files of an uninterrupted run, the file operations it made)."""
    from renderer import variants

    variants.set_variant(None, quiet=True)  # llvm_ad_rgb where usable
    work = tmp_path_factory.mktemp("whole")
    finished = run_child(work, events=work / "events.json")
    assert finished.returncode == 0, finished.stderr
    return tree(work / "out"), json.loads((work / "events.json").read_text())


def kind(event: str) -> str:
    """An operation and the kind of file, without frame, batch and random parts."""
    return re.sub(r"\d+", "N", re.sub(r"\.[0-9a-f]{8}\.", ".R.", event))


def instants(events: list[str], every_kind: bool) -> list[int]:
    """Operation numbers (1-based) to kill at: before each kind of file is
    renamed into place (its staging file complete), before the image writer's
    temporary file becomes the staging file, just after that temporary file is
    made, and while batches are removed; ``every_kind``: the first of every kind
    of operation too, and all the frame's buffers (else only the beauty, as
    the others are written by the same code)."""
    chosen = {}
    for number, event in enumerate(events, 1):
        operation, path = event.split(" ", 1)
        name = path.rsplit("/", 1)[-1]
        if every_kind:
            chosen.setdefault(kind(event), number)
        elif re.search(r"(normal|position|depth|ID|albedo)_\d", name):
            continue
        if operation == "replace":
            # before the rename of a complete staging file into place, or of the image
            # writer's complete temporary file into the staging name
            chosen.setdefault(kind(event), number)
        elif operation == "open" and name.startswith("..") and ".partial." in name:
            chosen.setdefault(kind(event), number)  # the image writer's temporary file just made
        elif operation == "unlink" and name.startswith("batch_"):
            chosen.setdefault("removing batches", number + 1)  # one batch removed, the others left
    return sorted(set(chosen.values()))


def check_kills(tmp_path: Path, uninterrupted, every_kind: bool, part: int = 0, parts: int = 1) -> None:
    """Kills at the :func:`instants` (every ``parts``-th of them from ``part`` on), each followed by a rerun."""
    expected, events = uninterrupted
    numbers = instants(events, every_kind)
    assert len(numbers) >= (40 if every_kind else 10), numbers
    for number in numbers[part::parts]:
        work = tmp_path / f"kill{number}"
        work.mkdir()
        killed = run_child(work, kill_at=number)
        assert killed.returncode == -signal.SIGKILL, (number, events[number - 1], killed.stderr[-2000:])
        rerun(work)
        files = tree(work / "out")
        assert sorted(files) == sorted(expected), (number, events[number - 1], set(files) ^ set(expected))
        assert files == expected, (number, events[number - 1])
        manifest = json.loads((work / "out" / "seq" / "dataset.json").read_text())
        assert {f["status"] for f in manifest["sequences"][0]["frames"]} <= {"rendered", "resumed"}


def test_kill_at_each_kind_of_write_then_rerun_gives_the_same_bytes(tmp_path, uninterrupted):
    check_kills(tmp_path, uninterrupted, every_kind=False)


@pytest.mark.slow
@pytest.mark.parametrize("part", range(4))  # four shorter tests: a worker waits less for one to end
def test_kill_at_every_kind_of_file_operation_then_rerun_gives_the_same_bytes(tmp_path, uninterrupted, part):
    check_kills(tmp_path, uninterrupted, every_kind=True, part=part, parts=4)


def test_the_uninterrupted_run_leaves_no_staging_or_batches(uninterrupted):
    files, events = uninterrupted
    assert sum(e.startswith("fsync") for e in events) >= 2 * (7 + 4 + 3)  # every file flushed
    assert not [name for name in files if "/." in "/" + name]  # no staging or lock file
    assert not [name for name in files if ".batches" in name]


def test_second_export_into_a_busy_folder_is_refused(tmp_path, capsys):
    """An export runs in another process; one more into its folder is one line
    and exit 2, writes nothing there, and the first one's files are whole."""
    from export import main

    big = dict(TINY, size=[64, 48], reference_spp=64)
    spec = tmp_path / "seq.json"
    spec.write_text(json.dumps(big))
    target = tmp_path / "out" / "seq"
    first = subprocess.Popen([sys.executable, "-m", "export", str(spec), str(target), "--local",
                              "--batch-spp", "4"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True)
    try:
        deadline = time.monotonic() + 300
        while not (target / "sequence.json").exists():
            assert first.poll() is None and time.monotonic() < deadline, first.communicate()
            time.sleep(0.05)
        assert main([str(spec), str(target), "--local", "--batch-spp", "4"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "another export is writing into this folder" in err, err
        assert first.poll() is None, "the first export ended before the second one was tried"
        out, err = first.communicate(timeout=600)
    finally:
        if first.poll() is None:
            first.kill()
    assert first.returncode == 0 and err == "", err
    assert main([str(spec), str(target), "--local", "--batch-spp", "4"]) == 0  # the lock went with its process
    assert "0 frames rendered" in capsys.readouterr().out


def test_colliding_dataset_folders_are_refused_before_anything_is_written(tmp_path, capsys):
    from export import main

    paths = []
    for name in ("a", "a_reference"):
        paths.append(tmp_path / f"{name}.json")
        paths[-1].write_text(json.dumps(TINY))
    assert main([str(p) for p in paths] + [str(tmp_path / "set"), "--local"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "would be both a's ground truth and a_reference's frame folder" in err, err
    assert not (tmp_path / "set").exists()


def test_ground_truth_without_its_frame_folder_names_the_ground_truth(tmp_path, capsys):
    """A reference folder left behind (its frame folder deleted) is what is
    in the way, and the message names it, not the frame folder."""
    from export import main

    spec = tmp_path / "seq.json"
    spec.write_text(json.dumps(TINY))
    target = tmp_path / "out" / "seq"
    assert main([str(spec), str(target), "--local", "--batch-spp", str(BATCH_SPP)]) == 0
    shutil.rmtree(target)
    assert main([str(spec), str(target), "--local", "--batch-spp", str(BATCH_SPP)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"error: {target}_reference: holds ground truth" in err, err
    assert not target.exists()
