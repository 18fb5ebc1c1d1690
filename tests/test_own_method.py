"""A method of one's own (docs/own_method.md): the page's example, saved to a
scratch folder, runs through every surface that runs methods; a broken method
file is one line naming the file and line, exit 2."""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from denoise.methods import METHODS

ROOT = Path(__file__).resolve().parent.parent
PAGE = ROOT / "docs" / "own_method.md"


def page_code() -> str:
    return re.search(r"```python\n(.*?)```", PAGE.read_text(), re.S).group(1)


@pytest.fixture
def registry():
    """The registry (and the live page's lists) as they were, after the test."""
    from denoise.live.methods import refresh

    before = dict(METHODS)
    yield
    METHODS.clear()
    METHODS.update(before)
    refresh()


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


@pytest.mark.parametrize("case", list(BROKEN))
def test_a_broken_method_file_is_one_line(case, tmp_path, capsys, registry):
    from denoise.__main__ import main

    source, expected = BROKEN[case]
    path = tmp_path / "my_filter.py"
    path.write_text(source)
    assert main(["--method-file", str(path), "--help"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert re.search(f"^python -m denoise: error: {re.escape(str(tmp_path))}/{expected}", err), err
