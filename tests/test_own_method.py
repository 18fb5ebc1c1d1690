"""A method of one's own (docs/own_method.md): the page's example, saved to a
scratch folder, runs through every surface that runs methods; a broken method
file is one line naming the file and line, exit 2."""
from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import assert_loading_is_one_line, live_server_stopping

ROOT = Path(__file__).resolve().parent.parent
PAGE = ROOT / "docs" / "own_method.md"


def page_code() -> str:
    return re.search(r"```python\n(.*?)```", PAGE.read_text(), re.S).group(1)


@pytest.fixture
def my_filter(tmp_path, registry):
    path = tmp_path / "scratch" / "my_filter.py"
    path.parent.mkdir()
    path.write_text(page_code())
    return path



def test_the_page_is_about_thirty_lines():
    assert 25 <= len(page_code().strip().splitlines()) <= 45


def test_the_pages_method_runs_through_every_surface(my_filter, exported, tmp_path, capsys):
    from denoise.__main__ import main as denoise
    from denoise.live.methods import SLIDERS, describe, refresh
    from denoise.methods.user import load_method_file
    from denoise.score import main as score
    from export import reference_folder
    from imaging.image_io import read_exr_rgb

    files = ["--method-file", str(my_filter)]
    with pytest.raises(SystemExit):  # 1. --help lists it and its options
        denoise(files + ["--help"])
    text = capsys.readouterr().out
    assert "cross-bilateral" in text and "--sigma-space" in text and "--window" in text
    out = tmp_path / "mine"  # 2. python -m denoise runs it, with its parameter
    assert denoise([str(exported), str(out), *files, "--method", "cross-bilateral", "--window", "2"]) == 0
    first = read_exr_rgb(out / "result_0.exr")
    assert first.shape == (18, 32, 3) and np.isfinite(first).all()
    assert not np.array_equal(first, read_exr_rgb(exported / "beauty_0.exr"))
    assert denoise([str(exported), str(tmp_path / "bad"), *files, "--method", "cross-bilateral", "--window", "20"]) == 2
    assert capsys.readouterr().err == ("python -m denoise: error: cross-bilateral: --window must be a whole number "
                                       "from 1 to 8, got 20\n")
    # 3. denoise.score --compare runs it beside the results
    assert score([str(out), "--reference", str(reference_folder(exported)), "--frames", str(exported), *files,
                  "--compare", "cross-bilateral", "raw"]) == 0
    assert "cross-bilateral" in capsys.readouterr().out
    # 4. the benchmark runs it under --methods (a command of its own: tests do not import benchmarks)
    done = subprocess.run([sys.executable, "-m", "benchmarks.denoise", "--quick", "--no-timing", "--sequences",
                           "glossy_shadow", "--work", str(tmp_path / "bench"), *files, "--methods", "cross-bilateral",
                           "raw"], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    lines = [line for line in done.stdout.splitlines() if line.startswith("| glossy_shadow |")]
    assert [line.split(" | ")[1] for line in lines] == ["cross-bilateral", "raw"]
    # 5. the live page lists it, with a slider per option that declares a step
    load_method_file(my_filter)
    refresh()
    assert [s.name for s in SLIDERS["cross-bilateral"]] == ["window", "sigma_space", "sigma_range"]
    sliders = describe("cross-bilateral", 32, {"window": 2})
    assert [(s["name"], s["low"], s["high"], s["value"]) for s in sliders] == [
        ("window", 1, 8, 2), ("sigma_space", 0.1, 8.0, 2.0), ("sigma_range", 0.01, 4.0, 0.5)]


BROKEN = {
    "syntax": ("import drjit\n\nclass A(:\n    pass\n", r"my_filter.py:3: syntax error: "),
    "no class": ("X = 1\n", r"my_filter.py:1: no method class"),
    "at import": ("import drjit\nimport no_such_module_here\n", r"my_filter.py:2: ModuleNotFoundError: "),
    "declaration": ("from denoise.methods import DenoisingMethod, Option\n\n\nclass A(DenoisingMethod):\n"
                    "    name, description = 'a', 'b'\n    options = (Option('w', 9, 'w', kind=int, high=4),)\n",
                    r"my_filter.py:6: option 'w': its default is out of its range"),
    "conflict": ("from denoise.methods import DenoisingMethod, Option\n\n\nclass A(DenoisingMethod):\n"
                 "    name, description = 'a', 'b'\n    options = (Option('radius', 2, 'my radius', kind=int),)\n",
                 r"my_filter.py:6: A declares --radius differently from bilateral at .*bilateral.py:\d+"),
}


def method_file(body: str = "return arrays.tensor(arrays.color)", options: str = "()", name: str = "mine") -> str:
    """A method file whose ``filter`` (line 11) is ``body`` (line 12)."""
    return ("import drjit as dr\nimport mitsuba as mi\nimport numpy as np\nfrom denoise.methods import "
            f"DenoisingMethod, Option\n\n\nclass M(DenoisingMethod):\n    name, description = {name!r}, 'mine'\n"
            f"    options = {options}\n\n    def filter(self, arrays, frame, index, valid):\n        {body}\n")


BROKEN.update({
    "exit at import": ("import sys\nraise SystemExit(0)\n", r"my_filter.py:2: SystemExit: 0"),
    "exit(3) at import": ("import sys\nsys.exit(3)\n", r"my_filter.py:2: SystemExit: 3"),
    "key twice": (method_file(options="(Option('w', 1, 'w', kind=int),\n               Option('w', 2, 'w', kind=int))"),
                  r"my_filter.py:10: M declares the option 'w' twice \(first at .*my_filter.py:9\)"),
    "span outside": (method_file(options="(Option('w', 1.0, 'w', low=0.0, high=2.0, step=0.1, span=(0.0, 5.0)),)"),
                     r"my_filter.py:9: option 'w': span \(0.0, 5.0\) reaches outside the range"),
    "keyword key": (method_file(options="(Option('class', 1.0, 'w'),)"),
                    r"my_filter.py:9: option 'class': the key must be a Python name that is not a keyword"),
    "dashed key": (method_file(options="(Option('my-key', 1.0, 'w'),)"),
                   r"my_filter.py:9: option 'my-key': the key must be a Python name"),
    **{f"flag {flag}": (method_file(options=options),
                        rf"my_filter.py:9: mine declares --{flag}, which is python -m denoise's own option")
       for flag, options in (("help", "(Option('help', 1.0, 'h'),)"),
                             ("method", "(Option('method', 'x', 'm', kind=str),)"),
                             ("png", "(Option('png', False, 'p', kind=None, action='store_true'),)"))},
    **{f"name {name}": (method_file(name=name), rf"my_filter.py:7: M: the method name '{re.escape(name)}' ")
       for name in ("atrous+temporal", "raw", "oidn-fast", "svgf", "demod+outliers+atrous+temporal", "my+temporal",
                    "My", "a b", "temporal")},
})


@pytest.mark.parametrize("case", list(BROKEN))
def test_a_broken_method_file_is_one_line(case, tmp_path, capsys, registry):
    assert_loading_is_one_line(*BROKEN[case], tmp_path, capsys)



#: what filter() does (line 12 of method_file) and the one line that says so
BAD_FILTERS = {
    "raises": ("raise ValueError('boom')", r"mine \(.*my_filter.py:12\): filter\(\) raised ValueError: boom"),
    "exits": ("raise SystemExit(0)", r"mine \(.*my_filter.py:12\): filter\(\) raised SystemExit: 0"),
    "None": ("return None", r"my_filter.py:11\): filter\(\) must return a mi.TensorXf .*got builtins.NoneType"),
    "str": ("return 'image'", r"my_filter.py:11\): filter\(\) must return a mi.TensorXf .*got builtins.str"),
    "numpy": ("return np.zeros(frame.beauty.shape, np.float32)", r"must return a mi.TensorXf .*numpy.ndarray"),
    "float64": ("return mi.TensorXf64(np.zeros(frame.beauty.shape))", r"must return a mi.TensorXf .*TensorXf64"),
    "5x2": ("return mi.TensorXf(np.zeros((5, 2), np.float32))",
            r"mine \(.*my_filter.py:11\): filter\(\) must return the frame's shape \(18, 32, 3\), got \(5, 2\)"),
    "3 rows": ("return mi.TensorXf(np.zeros((3, 32, 3), np.float32))", r"got \(3, 32, 3\)"),
    "nan": ("return mi.TensorXf(np.full(frame.beauty.shape, np.nan, np.float32))",
            r"mine \(.*my_filter.py:11\): filter\(\) returned 1728 NaN or infinite values"),
    "inf": ("return arrays.tensor(arrays.color / 0.0)", r"filter\(\) returned \d+ NaN or infinite values"),
}


@pytest.mark.parametrize("case", list(BAD_FILTERS))
def test_a_bad_filter_is_one_line(case, exported, tmp_path, capsys, registry):
    """python -m denoise and denoise.score --compare: a filter that raises, exits or returns
    anything but a finite TensorXf of the frame's shape is one line naming the method and its line."""
    from denoise.__main__ import main as denoise
    from denoise.score import main as score
    from export import reference_folder

    body, expected = BAD_FILTERS[case]
    path = tmp_path / "my_filter.py"
    path.write_text(method_file(body))
    files = ["--method-file", str(path)]
    out = tmp_path / "out"
    assert denoise([str(exported), str(out), *files, "--method", "mine"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert re.search(r"^python -m denoise: error: mine \(.*my_filter.py:1[12]\): filter\(\) ", err), err
    assert re.search(expected, err), err
    assert not (out / "result_0.exr").exists()
    results = tmp_path / "results"  # the noisy frames as results to score
    results.mkdir()
    for beauty in exported.glob("beauty_*.exr"):
        shutil.copy(beauty, results / beauty.name.replace("beauty", "result"))
    assert score([str(results), "--reference", str(reference_folder(exported)), "--frames", str(exported), *files,
                  "--compare", "mine", "raw"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and re.search(r"^python -m denoise.score: error: mine \(", err), err
    assert re.search(expected, err), err


def test_a_good_filter_still_runs(exported, tmp_path, capsys, registry):
    from denoise.__main__ import main as denoise

    path = tmp_path / "my_filter.py"
    path.write_text(method_file())
    assert denoise([str(exported), str(tmp_path / "out"), "--method-file", str(path), "--method", "mine"]) == 0


@pytest.mark.parametrize("command", ["denoise", "denoise.score", "benchmarks.denoise", "denoise.live"])
def test_a_flag_clash_is_one_line_in_every_command(command, tmp_path):
    """A method file's option named as a command's own option: one line (python -m denoise, the
    one command that adds methods' options), never argparse's traceback."""
    path = tmp_path / "my_filter.py"
    path.write_text(method_file(options="(Option('help', 1.0, 'h'),\n               Option('png', 1.0, 'p'))"))
    done = subprocess.run([sys.executable, "-m", command, "--method-file", str(path), "--help"], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    assert "Traceback" not in done.stderr and "ArgumentError" not in done.stderr, done.stderr
    if command == "denoise":
        assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
        assert "my_filter.py:9: mine declares --help, which is python -m denoise's own option" in done.stderr
    else:
        assert done.returncode == 0, done.stderr


@pytest.mark.parametrize("case", ["raises", "None", "nan"])
def test_a_bad_filter_stops_the_live_server_in_one_line(case, tmp_path):
    """python -m denoise.live: the first frame that the method cannot filter stops the
    server with the same one line (exit 2; the page loses its connection), no traceback."""
    from core.libllvm import find_libllvm

    if find_libllvm() is None:
        pytest.skip("no usable libLLVM: the live page needs a JIT variant")
    body, expected = BAD_FILTERS[case]
    path = tmp_path / "my_filter.py"
    path.write_text(method_file(body))
    code, err = live_server_stopping(path, "mine")
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err, err
    assert re.search(r"^python -m denoise.live: error: mine \(.*my_filter.py:1[12]\): filter\(\) ", err), err
    assert re.search(expected, err.replace("(18, 32, 3)", "")), err


@pytest.mark.parametrize(("body", "expected"), [
    ("return None", r"spatial\(\) must return a mi.TensorXf .*got builtins.NoneType"),
    ("return mi.TensorXf(np.zeros((5, 2), np.float32))", r"spatial\(\) must return the frame's shape"),
    ("raise KeyError('x')", r"my_filter.py:10\): spatial\(\) raised KeyError: 'x'"),
])
def test_a_bad_spatial_hook_is_one_line(body, expected, exported, tmp_path, capsys, registry):
    """A SpatialFilterMethod of one's own: its spatial() is checked before the accumulation reads it."""
    from denoise.__main__ import main as denoise

    path = tmp_path / "my_filter.py"
    path.write_text(spatial_file(body))
    assert denoise([str(exported), str(tmp_path / "out"), "--method-file", str(path), "--method", "mine"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and re.search(r"^python -m denoise: error: mine \(.*my_filter.py:(9|10)\): ", err), err
    assert re.search(expected, err), err


def test_a_spatial_method_without_options_accumulates(exported, tmp_path, registry):
    """SpatialFilterMethod's --alpha and --k are added where the class declares none (NAME+temporal reads them)."""
    from denoise.__main__ import main as denoise

    path = tmp_path / "my_filter.py"
    path.write_text(spatial_file("return arrays.tensor(arrays.color)"))
    assert denoise([str(exported), str(tmp_path / "out"), "--method-file", str(path), "--method", "mine+temporal",
                    "--alpha", "0.5"]) == 0


def spatial_file(body: str) -> str:
    """A SpatialFilterMethod of one's own whose spatial() (line 9) is ``body`` (line 10)."""
    return ("import mitsuba as mi\nimport numpy as np\nfrom denoise.methods import SpatialFilterMethod\n\n\n"
            "class S(SpatialFilterMethod):\n    name, description = 'mine', 'mine'\n\n"
            f"    def spatial(self, arrays):\n        {body}\n")
