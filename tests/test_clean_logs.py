"""A redirected stderr holds nothing on success and exactly the error line on failure.

Each command runs with stderr to a file, as a grading script or a cron job
runs it. ``--quiet`` also keeps Dr.Jit's own start-up notice off it when
``HOME`` is unusable (Dr.Jit then cannot keep its kernel cache there).
"""
from __future__ import annotations

import os
import subprocess

import pytest

from validation.stress_cases_system import RENDER, SHOWCASE
from validation.stress_scene import scene
from validation.stress_system import python

COMMANDS = {
    "render.py -input": ["-input", "s.txt", "-size", 16, 12, "-output", "a.png", "-normals", "n.png",
                         "-depth", 1, 9, "d.png", "--exr", "a.exr", "--png"],
    "render.py named scene": [SHOWCASE, "-size", 16, 12, "--out", "out", "--exr"],
    "render.py --batch": ["--batch", "b.sh"],
    "render.py scalar_rgb": ["-input", "s.txt", "-size", 16, 12, "-output", "s.png", "--variant", "scalar_rgb"],
    "render.py scalar_rgb in workers": ["-input", "s.txt", "-size", 120, 90, "-bounces", 2, "-output", "w.png",
                                        "--variant", "scalar_rgb"],
}
OTHERS = {
    "python -m converters": ["-m", "converters", "s.txt", "-o", "s.xml", "-size", 16, 12],
    "python -m benchmarks.stress": ["-m", "benchmarks.stress", "--only", "empty file", "--fuzz", 0,
                                    "--json", "stress.json"],
}


def run_logged(tmp_path, argv, env=None):
    (tmp_path / "s.txt").write_text(scene())
    (tmp_path / "b.sh").write_text("# grading\nmkdir -p res\na2 -input s.txt -size 8 6 -output res/b.png\n")
    log = tmp_path / "stderr.log"
    with open(log, "wb") as err:
        code = subprocess.run([str(a) for a in argv], cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=err,
                              env={**os.environ, **(env or {})}, timeout=300).returncode
    return code, log.read_text()


@pytest.mark.parametrize("name", list(COMMANDS) + list(OTHERS))
def test_stderr_is_empty_on_success(tmp_path, name):
    argv = python(RENDER, *COMMANDS[name]) if name in COMMANDS else python(*OTHERS[name])
    code, log = run_logged(tmp_path, argv)
    assert code == 0 and log == "", log


@pytest.mark.parametrize("home", ["file", "/nonexistent"])
def test_quiet_keeps_dr_jit_notices_off_stderr(tmp_path, home):
    """With HOME a file (or missing), Dr.Jit says it cannot keep its kernel cache: --quiet drops it."""
    if home == "/nonexistent" and os.geteuid() == 0:
        pytest.skip("root: Dr.Jit creates /nonexistent/.drjit (the HOME-is-a-file case covers it)")
    if home == "file":
        home = tmp_path / "home"
        home.write_text("not a folder")
    env = {"HOME": str(home), "XDG_CACHE_HOME": ""}
    for variant in ("llvm_ad_rgb", "scalar_rgb"):
        code, log = run_logged(tmp_path, python(RENDER, "-input", "s.txt", "-size", 16, 12, "-output", "q.png",
                                                "--quiet", "--variant", variant), env)
        assert code == 0 and log == "", log
    code, log = run_logged(tmp_path, python("-m", "converters", "s.txt", "-o", "s.xml"), env)
    assert code == 0 and log == "", log


def test_a_failure_is_exactly_its_error_line(tmp_path):
    code, log = run_logged(tmp_path, python(RENDER, "-input", "missing.txt", "-size", 8, 6, "-output", "a.png"))
    assert code == 2 and log.splitlines() == ["render.py: error: scene file missing.txt: no such file"], log
    assert "\r" not in log
