"""The machine under a command: full disks, signals, processes left behind.

Shared by the system stress cases (:mod:`validation.stress.cases_system`)
and the tests that check each class (``tests/test_full_disk.py``,
``tests/test_interrupts.py``, ``tests/test_clean_logs.py``):

- :func:`full_disk`: a folder on a file system that is full, or has a few
  pages of room: a small tmpfs where mounting works (root), else a
  file-size limit (``RLIMIT_FSIZE``) for the commands run there;
- :func:`run_command`: a command in a subprocess, its exit code and stderr;
- :func:`interrupt`: a command signalled after a delay: its exit code, how
  long it took to exit, its stderr and the processes it left behind;
- :func:`temporary_files`: what an atomic writer would leave (dot files).
"""
from __future__ import annotations

import os
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: Size of the test file system: a few previous files and one page of room fit
DISK_BYTES = 256 * 1024
PAGE = 4096


@dataclass
class Disk:
    """A folder whose file system is full (:meth:`fill`) or nearly so.

    ``limit``: a ``preexec_fn`` for commands that write there (the file-size
    limit of the fallback; None on a tmpfs); ``expect``: the words the one
    error line must hold."""
    path: Path
    limit: Callable[[], None] | None
    expect: str
    mounted: bool

    def fill(self, room: int = 0) -> None:
        """Fills the file system, then frees ``room`` bytes (whole pages)."""
        if not self.mounted:
            self.room = room
            return
        filler = self.path / "filler"
        with open(filler, "ab", buffering=0) as file:
            try:
                while True:
                    file.write(b"\0" * PAGE)
            except OSError:  # full
                pass
        size = filler.stat().st_size
        os.truncate(filler, max(size - (room + PAGE - 1) // PAGE * PAGE, 0))

    room: int = 0


def _mount(folder: Path) -> bool:
    if os.geteuid() != 0 or shutil.which("mount") is None:
        return False
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={DISK_BYTES}", "tmpfs", str(folder)],
                          capture_output=True)
    return done.returncode == 0


@contextmanager
def full_disk(parent: Path | None = None) -> Iterator[Disk]:
    """A :class:`Disk` under ``parent`` (a temporary folder if None); unmounted afterwards."""
    with tempfile.TemporaryDirectory(dir=parent) as tmp:
        folder = Path(tmp) / "disk"
        folder.mkdir()
        mounted = _mount(folder)
        disk = Disk(folder, None, "no space left on device", mounted)
        if not mounted:  # the fallback: every file a command writes may hold `room` bytes
            def limit() -> None:
                size = max(disk.room, 1)
                resource.setrlimit(resource.RLIMIT_FSIZE, (size, size))
            disk.limit, disk.expect = limit, "file too large"
        try:
            yield disk
        finally:
            if mounted:
                subprocess.run(["umount", "-l", str(folder)], capture_output=True)


def run_command(argv: list, cwd: Path = ROOT, env: dict | None = None,
                preexec: Callable[[], None] | None = None, timeout: float = 300) -> tuple[int, str, str]:
    """``argv`` run to its end: (exit code, stdout, stderr)."""
    done = subprocess.run([str(a) for a in argv], cwd=cwd, capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, **(env or {})}, preexec_fn=preexec)
    return done.returncode, done.stdout, done.stderr


def python(*args: str) -> list[str]:
    """A command of this project run by this Python: ``python(ROOT/'render.py', ...)``."""
    return [sys.executable, *map(str, args)]


def temporary_files(folder: Path) -> list[Path]:
    """Files an interrupted or failed atomic write would leave: ``.name.xxxx.suffix``."""
    return [path for path in Path(folder).rglob(".*") if path.is_file()]


def session_processes(session: int) -> list[str]:
    """Live processes of a session (zombies aside: those have exited and wait for init)."""
    live = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            state, sid = fields[0], int(fields[3])
            if sid == session and state != "Z":
                command = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
                live.append(f"{entry.name} {command[:120]}")
        except (OSError, IndexError, ValueError):
            continue
    return live


@dataclass
class Interrupted:
    code: int | None  # None: it did not exit in time (then it was killed)
    seconds: float  # from the signal to the exit
    stderr: str
    left: list[str]  # live processes of its session once it exited
    running: bool  # still running when the signal was sent


def catches(pid: int, signum: int) -> bool:
    """Whether process ``pid`` has a handler of its own for ``signum`` (its SigCgt mask)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    for line in status.splitlines():
        if line.startswith("SigCgt:"):
            return bool(int(line.split()[1], 16) >> (signum - 1) & 1)
    return False


def python_started(pid: int) -> bool:
    """Whether process ``pid`` is a Python past its start-up: SIGINT caught (Python's
    handler) or ignored (left so by Python), where a shell or a fresh fork has neither."""
    try:
        status = dict(line.split(":\t", 1) for line in Path(f"/proc/{pid}/status").read_text().splitlines()
                      if ":\t" in line)
        masks = int(status["SigCgt"], 16) | int(status["SigIgn"], 16)
        return bool(masks >> (signal.SIGINT - 1) & 1) and "python" in Path(f"/proc/{pid}/exe").resolve().name
    except (OSError, KeyError, ValueError):
        return False


def wait_for_handler(process: subprocess.Popen, timeout: float = 30) -> None:
    """Waits until ``process`` catches SIGTERM, which Python leaves alone and
    :func:`core.start_up.exit_on_signals` (a command's first line) takes: the
    first instant at which any line of the command's own has run."""
    end = time.perf_counter() + timeout
    while not catches(process.pid, signal.SIGTERM) and process.poll() is None and time.perf_counter() < end:
        time.sleep(0.002)


def interrupt(argv: list, delay: float, signum: int, cwd: Path = ROOT, timeout: float = 30,
              env: dict | None = None, group: bool = False, after_handler: bool = False,
              ready: Callable[[], bool] | None = None) -> Interrupted:
    """Starts ``argv`` in a session of its own, sends ``signum`` after ``delay``
    seconds (``group``: to its whole process group, as a terminal's Ctrl-C
    does), and waits (up to ``timeout``) for it to exit. ``after_handler``:
    the delay counts from the command's first line (:func:`wait_for_handler`),
    not from Python's own start-up, which no program can handle. ``ready``:
    the delay counts from the moment it holds (say, a first output written:
    a point in the work that no machine's speed moves), polled up to ``timeout``."""
    with tempfile.TemporaryFile() as err:
        process = subprocess.Popen([str(a) for a in argv], cwd=cwd, stdout=subprocess.DEVNULL, stderr=err,
                                   start_new_session=True, env={**os.environ, **(env or {})})
        try:
            if after_handler:
                wait_for_handler(process)
            end = time.perf_counter() + timeout
            while ready is not None and not ready() and process.poll() is None and time.perf_counter() < end:
                time.sleep(0.002)
            time.sleep(delay)
            running = process.poll() is None
            if group:
                os.killpg(process.pid, signum)
            else:
                process.send_signal(signum)
            sent = time.perf_counter()
            try:
                code = process.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                code = None
            seconds = time.perf_counter() - sent
            time.sleep(0.2)  # what it started sees its pipes close
            left = session_processes(process.pid)
        finally:
            if process.poll() is None:
                process.kill()
                process.wait()
            for line in session_processes(process.pid):  # never leave anything behind a failed check
                os.kill(int(line.split()[0]), signal.SIGKILL)
        err.seek(0)
        return Interrupted(code, seconds, err.read().decode(errors="replace"), left, running)
