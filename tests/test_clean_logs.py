"""A redirected stderr holds nothing on success and exactly the error line on failure.

Each command runs with stderr to a file, as a grading script or a cron job
runs it. ``--quiet`` also keeps Dr.Jit's own start-up notice off it when
``HOME`` is unusable (Dr.Jit then cannot keep its kernel cache there).
"""
from __future__ import annotations

import os
import subprocess

import pytest

from validation.stress.cases_system import RENDER, SHOWCASE
from validation.stress.scene import scene
from validation.stress.system import python

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


# -- the denoiser's commands, on a tiny exported sequence ------------------------------------
TINY = {"scene": "lamps", "frames": 2, "size": [32, 18], "spp": 1, "reference_spp": 4, "bounces": 1}
SEQUENCE_COMMANDS = {
    "python -m export": ["-m", "export", "{spec}", "seq2", "--local"],
    "python -m export, Dask workers": ["-m", "export", "{spec}", "seq3", "--workers", 1],
    "python -m denoise": ["-m", "denoise", "{seq}", "den", "--png", "--video", "v.mp4", "--reference",
                          "{seq}_reference"],
    "python -m denoise --method svgf": ["-m", "denoise", "{seq}", "den", "--method", "svgf"],
    "python -m denoise.score": ["-m", "denoise.score", "{den}", "--reference", "{seq}_reference", "--frames", "{seq}",
                                "--compare", "svgf", "raw", "--json", "s.json", "--plot", "s.png"],
    "python -m course.score": ["-m", "course.score", "{png}", "--reference", "{png}", "--report", "r.md"],
    "python -m denoise.fit": ["-m", "denoise.fit", "{spec}", "--work", "fit", "--steps", 2, "--switch-frame", 1,
                              "--out", "p.json"],
    "python -m denoise.methods": ["-m", "denoise.methods"],
}


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    """Paths the commands above name: a spec, its exported sequence, results, PNG images."""
    import json

    import numpy as np

    from imaging.image_io import write_image

    folder = tmp_path_factory.mktemp("sequence")
    (folder / "seq.json").write_text(json.dumps(TINY))
    for argv in (["-m", "export", folder / "seq.json", folder / "seq", "--local"],
                 ["-m", "denoise", folder / "seq", folder / "den"]):
        done = subprocess.run(python(*argv), cwd=folder, capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr
    (folder / "png").mkdir()
    write_image(folder / "png" / "a01.png", np.random.default_rng(1).integers(0, 256, (20, 30, 3), np.uint8))
    return {"spec": folder / "seq.json", "seq": folder / "seq", "den": folder / "den", "png": folder / "png"}


@pytest.mark.parametrize("name", SEQUENCE_COMMANDS)
def test_the_denoisers_commands_keep_stderr_empty_on_success(tmp_path, name, sequence):
    argv = [str(a).format(**sequence) for a in SEQUENCE_COMMANDS[name]]
    code, log = run_logged(tmp_path, python(*argv))
    assert code == 0 and log == "", log


def test_the_live_server_logs_nothing_but_its_stop_line(tmp_path):
    """Serving a viewer frames, then SIGTERM: stderr holds the one interrupted line, nothing before it."""
    import asyncio
    import signal
    import time

    from core.libllvm import find_libllvm

    if find_libllvm() is None:
        pytest.skip("no usable libLLVM: the live page needs a JIT variant")
    log = tmp_path / "stderr.log"
    with open(log, "wb") as err:
        process = subprocess.Popen(python("-m", "denoise.live", "showcase", "--size", 64, 36, "--port", 0),
                                   stdout=subprocess.PIPE, stderr=err, text=True, cwd=tmp_path,
                                   env={**os.environ, "PYTHONPATH": str(RENDER.parent)})
        try:
            url = process.stdout.readline().split("open ", 1)[1].split()[0]

            async def watch(frames: int) -> None:
                import aiohttp

                async with aiohttp.ClientSession() as session:
                    async with session.ws_connect(url + "ws", headers={"Origin": url.rstrip("/")}) as ws:
                        while frames:
                            message = await asyncio.wait_for(ws.receive(), 240)
                            if message.type == aiohttp.WSMsgType.BINARY:
                                frames -= 1
                                await ws.send_json({"type": "ack", "frame": 10 ** 6})
                        await ws.send_json({"type": "method", "name": "svgf"})
                        await ws.send_json({"type": "pause", "paused": True})
                        await asyncio.sleep(0.5)

            asyncio.run(watch(3))
            assert log.read_text() == ""
            process.send_signal(signal.SIGTERM)
            start = time.perf_counter()
            assert process.wait(10) == 143
            assert time.perf_counter() - start < 2
        finally:
            if process.poll() is None:
                process.kill()
                process.wait()
    assert log.read_text().splitlines() == [
        "python -m denoise.live: stopped (it writes no files)"]


def test_mitsubas_warnings_go_to_stderr_not_stdout(tmp_path):
    """Mitsuba's default appender writes to stdout; every command sets its
    variant through ``set_variant``, which sends Mitsuba's log to stderr, so
    stdout carries only the command's output (here the stress suite's summary
    while a case's sphere, scaled away, makes Mitsuba warn)."""
    done = subprocess.run(python("-m", "benchmarks.stress", "--only", "scene scaled by 1e-10",
                                 "--fuzz", 0), cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout == '{"cases": 1, "passed": 1, "fuzz_inputs": 0}\n', done.stdout
    assert "non-uniform scaling" in done.stderr
