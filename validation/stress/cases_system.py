"""Stress cases for the system around a command: full disks, signals, links, logs.

Each :class:`SystemCase` runs real commands in subprocesses (see
:mod:`validation.stress.system`) and states what must happen:

- a full disk under every writer: one ``PROG: error: FILE: no space left on
  device`` line, exit 2, no temporary file, the previous file intact;
- SIGINT / SIGTERM / SIGHUP while facing mirrors render with ``-bounces 1000``: exit
  128 + the signal within 2 s, at most one line, nothing written, no process left;
- the converter's output through a symbolic link: the XML loads in Mitsuba;
- an empty ``--batch`` file: one line;
- clean logs: stderr empty on success, also with an unusable ``HOME``;
- SIGINT to the process group while ``export --workers 2`` starts its Dask workers:
  exit 130 within 2 s, one line, no process left.
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from validation.stress.scene import scene
from validation.stress.system import (
    ROOT,
    full_disk,
    interrupt,
    python,
    python_started,
    run_command,
    session_processes,
    temporary_files,
)

#: Two parallel mirrors with the camera between them: every ray bounces as often as -bounces allows
FACING_MIRRORS = """PerspectiveCamera { center 0 0 0 direction 0 0.05 -1 up 0 1 0 angle 60 }
Lights { numLights 2
  PointLight { position 0 0.5 0 color 1 1 1 falloff 0.2 }
  DirectionalLight { direction 0 -1 -0.2 color 0.3 0.3 0.3 } }
Background { color 0.1 0.2 0.3 ambientLight 0.1 0.1 0.1 }
Materials { numMaterials 1
  Material { diffuseColor 0.05 0.05 0.05 specularColor 0.99 0.99 0.99 shininess 100 } }
Group { numObjects 2
  MaterialIndex 0
  Plane { normal 0 0 1 offset -2 }
  Plane { normal 0 0 -1 offset -2 } }
"""
RENDER = ROOT / "render.py"
SHOWCASE = ROOT / "scenes" / "showcase.txt"
OLD = b"the previous file"


def one_error_line(code: int, stderr: str, prog: str, expect: str) -> list[str]:
    """Problems with a refusal: exit 2 and exactly one ``PROG: error: ...`` line holding ``expect``."""
    lines = [line for line in stderr.splitlines() if line.strip()]
    problems = [] if code == 2 else [f"exit code {code}"]
    if len(lines) != 1:
        problems.append(f"{len(lines)} lines on stderr")
    elif not lines[0].startswith(f"{prog}: error: ") or expect not in lines[0]:
        problems.append(f"not a {prog} error line with {expect!r}")
    return problems


@dataclass(frozen=True)
class SystemCase:
    """A check that runs commands; ``run(folder)`` returns its problems (none: passed)."""
    name: str
    run: Callable[[Path], list[str]]
    fast: bool = False  # tests/test_full_disk.py, test_interrupts.py and test_clean_logs.py run them in CI
    kind: str = "system"

    def check(self) -> tuple[bool, str]:
        with tempfile.TemporaryDirectory() as tmp:
            try:
                problems = self.run(Path(tmp))
            except Exception as error:  # noqa: BLE001 - a check that cannot run has failed
                problems = [f"{type(error).__name__}: {error}"]
        return not problems, "; ".join(problems) or "as stated"


def full_disk_case(name: str, prog: str, argv: Callable[[Path], list], previous: str) -> SystemCase:
    """``argv(disk)`` writes ``disk/previous`` (which exists) onto a full file system."""
    def run(folder: Path) -> list[str]:
        with full_disk(folder) as disk:
            (disk.path / previous).parent.mkdir(parents=True, exist_ok=True)
            (disk.path / previous).write_bytes(OLD)
            disk.fill()
            code, _, stderr = run_command([str(a) for a in argv(disk.path)], cwd=folder, preexec=disk.limit)
            problems = one_error_line(code, stderr, prog, disk.expect)
            if (disk.path / previous).read_bytes() != OLD:
                problems.append(f"{previous} was changed")
            problems += [f"temporary file {p.name} left" for p in temporary_files(disk.path)]
            return problems + ([stderr.strip()[-300:]] if problems else [])
    return SystemCase(name, run)


def interrupt_case(variant: str, size: int, signum: int, group: bool = False) -> SystemCase:
    def run(folder: Path) -> list[str]:
        (folder / "m.txt").write_text(FACING_MIRRORS)
        command = python(RENDER, "-input", "m.txt", "-bounces", 1000, "-shadows", "--variant", variant)
        start = time.perf_counter()
        code, _, stderr = run_command([*command, "-size", 4, 4, "-output", "warm.png"], cwd=folder)
        if code:
            return [f"the warm-up render failed: {stderr.strip()[-300:]}"]
        out = folder / "out"
        out.mkdir()
        result = interrupt([*command, "-size", size, size, "-output", out / "m.png"], cwd=folder,
                           delay=time.perf_counter() - start + 1.5, signum=signum, group=group)
        lines = result.stderr.strip().splitlines()
        problems = [] if result.running else ["finished before the signal"]
        if result.code != 128 + signum:
            problems.append(f"exit code {result.code}")
        if result.seconds > 2.0:
            problems.append(f"exited {result.seconds:.2f} s after the signal")
        if len(lines) > 1:
            problems.append(f"{len(lines)} lines on stderr")
        problems += [f"{p.name} written" for p in out.iterdir()]
        problems += [f"process left: {p}" for p in result.left]
        return problems
    name = (f"{signal.Signals(signum).name}{' to the process group' if group else ''} to {variant} facing "
            "mirrors, -bounces 1000")
    return SystemCase(name, run)


def _linked_xml(folder: Path) -> list[str]:
    """``python -m converters`` into a folder reached through a link: the XML loads."""
    for part in ("tex", "meshes"):  # the scenes near the output: relative paths from it stay short
        shutil.copytree(ROOT / "scenes" / part, folder / "src" / part)
    real = folder / "real" / "deep" / "er"
    real.mkdir(parents=True)
    (folder / "link").symlink_to(real)
    problems = []
    for name in ("mirrors", "transforms"):
        source = Path(shutil.copy(ROOT / "scenes" / f"{name}.txt", folder / "src"))
        target = folder / "link" / f"{name}.xml"
        code, _, stderr = run_command(python("-m", "converters", source, "-o", target, "-size", 8, 6), cwd=folder)
        if code:
            problems.append(f"converter exit {code}: {stderr.strip()[-200:]}")
            continue
        load = ("import sys, mitsuba as mi; mi.set_variant('scalar_rgb'); import mi_plugins; "
                "mi_plugins.register(); mi.load_file(sys.argv[1], optimize=False); print('ok')")
        code, out, stderr = run_command(python("-c", load, target), cwd=folder, env={"PYTHONPATH": str(ROOT)})
        if code or "ok" not in out:
            problems.append(f"{source.name}: the XML does not load: {stderr.strip().splitlines()[-1:]}")
    return problems


def _clean_logs(folder: Path) -> list[str]:
    """Commands that succeed print nothing on a redirected stderr (an unusable HOME too)."""
    (folder / "s.txt").write_text(scene())
    (folder / "b.sh").write_text("a2 -input s.txt -size 8 6 -output b.png\n")
    commands = {
        "render.py": python(RENDER, "-input", "s.txt", "-size", 8, 6, "-output", "a.png", "--exr", "a.exr"),
        "render.py --quiet, HOME unusable": python(RENDER, "-input", "s.txt", "-size", 8, 6, "-output", "q.png",
                                                   "--quiet"),
        "render.py --batch": python(RENDER, "--batch", "b.sh"),
        "python -m converters": python("-m", "converters", "s.txt", "-o", "s.xml"),
    }
    problems = []
    for name, argv in commands.items():
        env = {"HOME": "/nonexistent", "XDG_CACHE_HOME": ""} if "HOME" in name else None
        code, _, stderr = run_command(argv, cwd=folder, env=env)
        if code or stderr:
            problems.append(f"{name}: exit {code}, stderr {stderr.strip()[-200:]!r}")
    return problems


def _ctrl_c_while_workers_start(folder: Path) -> list[str]:
    """SIGINT to the process group of ``export --workers 2`` as soon as a worker's
    Python has started (still importing, before Dask's preload): a terminal's Ctrl-C."""
    spec = folder / "seq.json"
    spec.write_text(json.dumps({"scene": "lamps", "frames": 3, "size": [64, 48], "spp": 1, "reference_spp": 256,
                                "bounces": 1}))
    with tempfile.TemporaryFile() as err:
        process = subprocess.Popen(python("-m", "export", spec, folder / "seq", "--workers", 2), cwd=ROOT,
                                   stdout=subprocess.DEVNULL, stderr=err, start_new_session=True)
        try:
            end = time.perf_counter() + 120
            while not [line for line in session_processes(process.pid) if "multiprocessing.spawn" in line
                       and python_started(int(line.split()[0]))]:
                if process.poll() is not None or time.perf_counter() > end:
                    return ["no worker process started"]
                time.sleep(0.01)
            os.killpg(process.pid, signal.SIGINT)
            sent = time.perf_counter()
            code = process.wait(timeout=30)
            seconds = time.perf_counter() - sent
            time.sleep(0.5)  # the workers see their parent gone
            left = session_processes(process.pid)
        finally:
            for line in session_processes(process.pid):  # never leave anything behind a failed check
                os.kill(int(line.split()[0]), signal.SIGKILL)
        err.seek(0)
        lines = err.read().decode(errors="replace").strip().splitlines()
    problems = [] if code == 130 else [f"exit code {code}"]
    if seconds > 2.0:
        problems.append(f"exited {seconds:.2f} s after the signal")
    if len(lines) != 1:
        problems.append(f"{len(lines)} lines on stderr: {lines[-1][:200] if lines else ''}")
    return problems + [f"process left: {p}" for p in left]


def system_cases() -> list[SystemCase]:
    def render(*flags):
        return lambda disk: python(RENDER, "-input", SHOWCASE, "-size", 64, 48, "--quiet",
                                   *[str(f).replace("{disk}", str(disk)) for f in flags])
    cases = [
        full_disk_case("full disk: render.py PNG", "render.py", render("-output", "{disk}/a.png"), "a.png"),
        full_disk_case("full disk: render.py EXR", "render.py", render("--exr", "{disk}/a.exr"), "a.exr"),
        full_disk_case("full disk: render.py --png preview", "render.py",
                       render("-output", "{disk}/a.exr", "--exr", "{disk}/b.exr", "--png"), "b.png"),
        full_disk_case("full disk: python -m converters", "python -m converters",
                       lambda disk: python("-m", "converters", SHOWCASE, "-o", disk / "s.xml"), "s.xml"),
        full_disk_case("full disk: benchmark --json", "python -m benchmarks.stress",
                       lambda disk: python("-m", "benchmarks.stress", "--only", "empty file", "--fuzz", 0,
                                           "--json", disk / "r.json"), "r.json"),
        full_disk_case("full disk: python -m export", "python -m export",
                       lambda disk: python("-m", "export", ROOT / "scenes" / "sequences" / "dolly_lamps.json",
                                           disk / "seq", "--frames", 1, "--size", 16, 9, "--reference-spp", 4,
                                           "--local"), "seq/dataset.json"),
        SystemCase("converter output through a symbolic link loads", _linked_xml),
        SystemCase("clean logs: stderr empty on success", _clean_logs),
        SystemCase("SIGINT to the process group while export's Dask workers start", _ctrl_c_while_workers_start),
    ]
    for variant, size in (("llvm_ad_rgb", 1024), ("scalar_rgb", 256)):
        for signum in (signal.SIGINT, signal.SIGTERM):
            cases.append(interrupt_case(variant, size, signum))
        cases.append(interrupt_case(variant, size, signal.SIGHUP, group=True))
    return cases
