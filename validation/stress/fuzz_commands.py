"""The command-line fuzzer of the denoiser's commands and the scores.

:func:`fuzz_commands` draws argument lists for ``python -m denoise``,
``export``, ``denoise.score``, ``denoise.fit``, ``denoise.live``,
``denoise.methods`` and ``course.score`` from a vocabulary of their flags,
numbers that are fine, odd or absurd, and paths that are fine, missing,
damaged or of the wrong kind (a method file among them, and a broken one).
Besides the flags listed here, every flag a command's ``--help`` shows is
drawn (:func:`help_flags`), so that an option added later is fuzzed too. It
runs each command's ``main`` in-process in
a scratch folder. Each must end in exit 0 (``course.score``: 0 or 1, its
verdict), or exit 2 with one ``PROG: error:`` line; never a traceback or
another exception. What a command would do for long is kept short:
``export`` renders in-process at a few pixels, ``denoise.fit`` takes
a step or two, and ``denoise.live`` is given a port that is in use as its
last flag (it checks the port before anything else, so it never serves).
"""
from __future__ import annotations

import contextlib
import io
import json
import os
import re
import socket
import tempfile
from pathlib import Path

import numpy as np

#: a spec small enough that every valid draw renders in a moment
TINY = {"scene": "lamps", "frames": 2, "size": [12, 8], "spp": 1, "reference_spp": 2, "bounces": 1}
#: words every command's draws share: numbers and paths of every kind
COMMON = ["0", "1", "2", "-1", "3", "1e9", "nan", "inf", "x", "", "-", "--", "--help", "10001", "4294967296",
          "seq", "seq_reference", "den", "missing", "dir", "file.txt", "tiny.json", "bad.json", "empty.json",
          "damaged", "pngs", "out", "new/out", "é", "s.json", "s.png", "r.md", "r.png", "p.json",
          "--variant", "scalar_rgb", "nope_rgb", "mine.py", "broken.py", "cross-bilateral", "modes",
          "odd\nname\x1b[0m"]
#: flags a command's --help shows that the fuzzer must not draw (they write into the checkout)
NEVER = {"--write"}
#: a method of one's own (docs/own_method.md's shape) and a file that is none
METHOD_FILE = """from denoise.methods import DenoisingMethod, Option


class CrossBilateral(DenoisingMethod):
    name = "cross-bilateral"
    description = "a method file of the fuzzer's"
    options = (Option("window", 1, "half width", kind=int, low=1, high=3, step=1, group="cross-bilateral"),)

    def filter(self, arrays, frame):
        return arrays.color
"""
#: per command: its program name, its flags, and a valid start that the drawn words extend or override
COMMANDS = {
    "denoise": ("python -m denoise", ["--method", "atrous", "svgf", "asvgf", "oidn", "oidn-guided", "bilateral",
                                      "bogus", "--png", "--video", "v.mp4", "v.avi", "--reference", "--fps",
                                      "--levels", "--alpha", "--k", "--oidn-quality", "fast", "best",
                                      "--no-temporal", "--radius", "--sigma-color"], ["seq", "out"]),
    "export": ("python -m export", ["--frames", "--size", "--spp", "--reference-spp",
                                                    "--batch-spp", "--whitted", "--data", "--force", "--workers",
                                                    "--scheduler", "tcp://127.0.0.1:1"],
                       ["tiny.json", "out", "--local"]),
    "denoise.score": ("python -m denoise.score", ["--reference", "--frames", "--pattern", "result_{i}.exr",
                                                  "frame_{i:q}.exr", "{j}.exr", "--compare", "svgf", "raw",
                                                  "bogus", "demod+atrous+temporal", "--plot", "--json"],
                      ["den", "--reference", "seq_reference", "--frames", "seq"]),
    "denoise.fit": ("python -m denoise.fit", ["--steps", "--rate", "10", "0.5", "--switch-frame", "--quiet",
                                              "--evaluate", "--out", "--work"],
                    ["tiny.json", "--work", "fitwork", "--out", "p.json", "--steps", "1", "--switch-frame", "1",
                     "--quiet"]),
    "denoise.live": ("python -m denoise.live", ["showcase", "lamps", "scene03", "--size", "--method", "svgf",
                                                "raw", "--port", "65536", "--no-freeze", "--data"], ["showcase"]),
    "denoise.methods": ("python -m denoise.methods", ["--help"], []),  # not --write: it updates docs/
    "course.score": ("python -m course.score", ["--reference", "--report"],
                     ["pngs", "--reference", "pngs", "--report", "r.md"]),
}


def _scratch() -> tuple[Path, Path]:
    """A folder with every path of the vocabulary, and the spec it exported."""
    from core.entry import run  # noqa: PLC0415  the commands load on use
    from export import main as export_main  # noqa: PLC0415  as above
    from imaging.image_io import write_image  # noqa: PLC0415  as above

    folder = Path(tempfile.mkdtemp(prefix="stress-commands-"))
    (folder / "tiny.json").write_text(json.dumps(TINY))
    (folder / "bad.json").write_text('{"scene": "lamps", "frames": "two"}')
    (folder / "empty.json").write_text("")
    (folder / "dir").mkdir()
    (folder / "file.txt").write_text("x")
    (folder / "damaged").mkdir()
    (folder / "damaged" / "beauty_0.exr").write_bytes(b"v/1\x01 not an EXR")
    (folder / "mine.py").write_text(METHOD_FILE)
    (folder / "broken.py").write_text("class A(:\n    pass\n")
    (folder / "pngs").mkdir()
    write_image(folder / "pngs" / "a01.png", np.zeros((6, 8, 3), np.uint8))
    (folder / "modes").mkdir()  # the scores' reader: a transparent PNG, a JPEG under a .png name
    from PIL import Image  # noqa: PLC0415  Pillow loads with the scratch folder
    Image.fromarray(np.zeros((6, 8, 4), np.uint8), "RGBA").save(folder / "modes" / "a01.png")
    Image.fromarray(np.zeros((6, 8, 3), np.uint8)).save(folder / "modes" / "a01n.png", "JPEG")
    with contextlib.redirect_stdout(io.StringIO()):
        if export_main([str(folder / "tiny.json"), str(folder / "seq"), "--local"]):
            raise RuntimeError("the fuzzer's sequence could not be exported")
        from denoise.__main__ import main as denoise_main  # noqa: PLC0415  as above

        if run("fuzz", lambda: denoise_main([str(folder / "seq"), str(folder / "den")])):
            raise RuntimeError("the fuzzer's sequence could not be denoised")
    return folder, folder / "tiny.json"


def _main_of(command: str):
    """The command's ``main(argv)`` (imported on use: Dr.Jit loads after the suite chose its variant)."""
    import importlib  # noqa: PLC0415  only the fuzzer needs it

    module = {"denoise": "denoise.__main__", "export": "export.cli",
              "denoise.live": "denoise.live.app", "denoise.methods": "denoise.methods.__main__"}.get(command, command)
    return importlib.import_module(module).main


def help_flags(main) -> list[str]:
    """Every ``--flag`` that ``main(["--help"])`` prints, less :data:`NEVER` and ``--help``."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        try:
            main(["--help"])
        except SystemExit:
            pass
    return sorted(set(re.findall(r"(?<![\w-])--[a-z][a-z0-9-]*", out.getvalue())) - NEVER - {"--help"})


def contract_problems(prog: str, code, stderr: str, verdicts=(0,)) -> list[str]:
    """Exit 0 (or another verdict), or exit 2 with exactly one ``PROG: error:`` line; never a traceback."""
    lines = [line for line in stderr.splitlines() if line.strip()]
    problems = ["traceback"] if "Traceback" in stderr else []
    if code not in (*verdicts, 2):
        problems.append(f"exit code {code}")
    if code == 2 and (len(lines) != 1 or not lines[0].startswith(f"{prog}: error: ")):
        problems.append(f"exit 2 with {len(lines)} lines, not one {prog} error line")
    return problems


def _checker(folder: Path, command: str, prog: str, template: list[str], runs: list[int]):
    """A hypothesis test body: the command run on ``template`` with the drawn words at ``{words}``
    (``runs[0]`` counts the runs)."""
    main = _main_of(command)
    verdicts = (0, 1) if command == "course.score" else (0,)

    def check(words: list[str]) -> None:
        runs[0] += 1
        at = template.index("{words}")
        argv = [*template[:at], *words, *template[at + 1:]]
        err = io.StringIO()
        cwd = os.getcwd()
        os.chdir(folder)
        try:
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
                try:
                    code = main(argv)
                except SystemExit as stop:  # argparse's --help
                    code = stop.code
        finally:
            os.chdir(cwd)
        problems = contract_problems(prog, code, err.getvalue(), verdicts)
        assert not problems, f"{prog} {argv}: {problems}: {err.getvalue()[-500:]}"

    return check


def fuzz_commands(examples: int) -> int:
    """``examples`` draws per command; returns how many ran. Raises on the first escape."""
    from hypothesis import HealthCheck, given, settings, strategies as st  # noqa: PLC0415  hypothesis loads on use: --help and the paths without it stay quick

    folder, _ = _scratch()
    busy = socket.socket()
    busy.bind(("127.0.0.1", 0))
    busy.listen()
    runs = [0]
    common = settings(max_examples=examples, deadline=None, database=None, derandomize=True,
                      suppress_health_check=list(HealthCheck))
    from denoise.live.methods import refresh  # noqa: PLC0415  as above
    from denoise.methods import METHODS  # noqa: PLC0415  as above

    registered = dict(METHODS)  # --method-file registers in this process: restored below
    try:
        for command, (prog, flags, first) in COMMANDS.items():
            last = ["--port", str(busy.getsockname()[1])] if command == "denoise.live" else []
            check = _checker(folder, command, prog, [*first, "{words}", *last], runs)
            words = COMMON + flags + [f for f in help_flags(_main_of(command)) if f not in flags]
            options = [w for w in words if w.startswith("--") and w not in ("--", "--help")]
            values = [w for w in words if not w.startswith("--")]
            own = st.sampled_from([w for w in flags if not w.startswith("-")] or values)
            # flags with a value (half the time one of this command's own), as a user writes
            # them, and at most one word alone at the end (a positional, a switch, --help)
            pairs = st.lists(st.tuples(st.sampled_from(options), st.one_of(own, st.sampled_from(values))),
                             max_size=4)
            draws = st.tuples(pairs, st.lists(st.sampled_from(words), max_size=1))
            common(given(draws.map(lambda d: [w for pair in d[0] for w in pair] + d[1]))(check))()
    finally:
        busy.close()
        METHODS.clear()
        METHODS.update(registered)
        refresh()
    return runs[0]
