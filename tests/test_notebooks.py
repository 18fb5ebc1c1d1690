"""The notebooks: stored with their outputs (plots as PNG) at the full size,
fresh, and re-run here at the quick size; a figure shown as text, a wrong
number or a stored quick run fails."""
from __future__ import annotations

import re
import resource
import subprocess
import sys
from pathlib import Path

import nbformat
import pytest
from nbformat.v4 import new_code_cell, new_notebook

from notebooks import build

#: these and the README's Jupyter command (which may install the notebook extra) take turns (tests/conftest.py)
pytestmark = pytest.mark.xdist_group("notebooks")
ROOT = Path(__file__).resolve().parent.parent
NAMES = sorted(build.NOTEBOOKS)
#: the smallest image side of a full-size notebook
FULL_PIXELS = 200
#: "200×200 pixels", as the notebooks print the size of what they rendered
PIXELS = re.compile(r"(\d+)×(\d+) pixels")


def text_outputs(notebook) -> list[str]:
    texts = []
    for cell in notebook.cells:
        for output in cell.get("outputs", []):
            text = output.get("text", "") if output.output_type == "stream" else \
                output.get("data", {}).get("text/markdown", "")
            texts.append(text if isinstance(text, str) else "".join(text))
    return texts


def full_size_problems(notebook) -> list[str]:
    """Why ``notebook`` is not a full-size run: its recorded size, what its set-up
    cell printed, and the image sizes it printed (each at least FULL_PIXELS)."""
    found = []
    if build.stored_size(notebook) != "full":
        found.append(f"recorded size {build.stored_size(notebook)!r}")
    texts = text_outputs(notebook)
    if not any("| size: full" in text for text in texts):
        found.append("the set-up cell did not run at the full size")
    sizes = [int(side) for text in texts for match in PIXELS.finditer(text) for side in match.groups()]
    if not sizes:
        found.append("no image size printed")
    elif min(sizes) < FULL_PIXELS:
        found.append(f"images of {min(sizes)} pixels (full size: at least {FULL_PIXELS})")
    return found


def test_every_notebook_is_built():
    assert sorted(p.stem for p in (ROOT / "notebooks").glob("*.ipynb")) == NAMES


@pytest.mark.parametrize("name", NAMES)
def test_committed_notebook_has_its_outputs(name):
    """What a code-hosting site shows: every code cell ran, every figure cell
    holds a PNG, no errors; and the cells are those that build.py writes."""
    stored = nbformat.read(ROOT / "notebooks" / f"{name}.ipynb", as_version=4)
    fresh = build.make(name)
    assert [c.source for c in stored.cells] == [c.source for c in fresh.cells], \
        "run: python -m notebooks.build"
    assert all(c.execution_count is not None for c in stored.cells if c.cell_type == "code")
    assert build.problems(stored) == []
    assert full_size_problems(stored) == [], "run: python -m notebooks.build (the full size)"
    figures = [c for c in stored.cells if "figure" in c.metadata.get("tags", [])]
    assert figures and all(any("image/png" in o.get("data", {}) for o in c.outputs) for c in figures)
    streams = [o.text for c in stored.cells if c.cell_type == "code" for o in c.outputs
               if o.output_type == "stream"]
    assert not any("\r" in text for text in streams)  # progress bars at their final state


def test_stored_error_against_time_has_slopes_near_minus_one():
    """What the error-against-time notebook claims at the full size, read back
    from its stored table: every curve spans two decades of time, and its
    fitted slope over log seconds is within 0.15 of -1."""
    stored = nbformat.read(ROOT / "notebooks" / "error_vs_time.ipynb", as_version=4)
    rows = [re.match(r"\| (\S+) \| (\w+) \| (-?[\d.]+) \[(-?[\d.]+), (-?[\d.]+)\] \| ([\d.]+) \|", line)
            for text in text_outputs(stored) for line in text.splitlines()]
    rows = [row for row in rows if row]
    assert len(rows) >= 6  # three scenes, two methods
    for row in rows:
        slope, low, high, decades = map(float, row.groups()[2:])
        assert abs(slope + 1) <= 0.15 and low <= slope <= high and decades >= 2, row.group(0)


@pytest.mark.parametrize("name", NAMES)
def test_notebook_reruns_with_its_plots(name, tmp_path):
    """CI re-executes each notebook (quick size) in a scratch copy: no error, no
    failed assert in its cells, a PNG from every figure cell; and the quick run,
    stored, would fail the full-size check."""
    notebook = build.tidy(build.execute(build.make(name), quick=True, timeout=900))
    assert build.problems(notebook) == []
    build.write(notebook, tmp_path / f"{name}.ipynb", "quick")
    found = full_size_problems(nbformat.read(tmp_path / f"{name}.ipynb", as_version=4))
    assert "recorded size 'quick'" in found and any("pixels (full size" in line for line in found), found


WRITE_A_BIG_NOTEBOOK = """import sys
from pathlib import Path
import nbformat
from core import entry
from notebooks import build
notebook = nbformat.v4.new_notebook(cells=[nbformat.v4.new_markdown_cell("x" * 1_000_000)])
sys.exit(entry.run(build.PROG, lambda: build.write(notebook, Path(sys.argv[1]), "full")))
"""


def _mounted_tmpfs(folder: Path) -> bool:
    folder.mkdir()
    return subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(folder)],
                          capture_output=True).returncode == 0


@pytest.mark.parametrize("limit", ["full disk", "file size limit"])
def test_a_failed_write_is_one_line_and_exit_2(tmp_path, limit):
    """A full disk (a 64 KiB tmpfs, where this user may mount one) or a file size
    limit stops the write: one line, exit 2, the old notebook as it was and no
    temporary file left."""
    folder = tmp_path / "disk"
    if limit == "full disk":
        if not _mounted_tmpfs(folder):
            pytest.skip("cannot mount a tmpfs here (not root); the file size limit is the same path")
        preexec = None
    else:
        folder.mkdir()

        def preexec():
            resource.setrlimit(resource.RLIMIT_FSIZE, (1 << 16, 1 << 16))
    target = folder / "crossval.ipynb"
    target.write_text("old")
    try:
        result = subprocess.run([sys.executable, "-c", WRITE_A_BIG_NOTEBOOK, str(target)], cwd=ROOT,
                                capture_output=True, text=True, timeout=120, preexec_fn=preexec)
        assert result.returncode == 2, result.stderr
        lines = result.stderr.strip().splitlines()
        reasons = ("no space left on device", "file too large")
        assert len(lines) == 1 and lines[0].startswith(f"{build.PROG}: error: {target}: "), lines
        assert any(reason in lines[0] for reason in reasons), lines
        assert target.read_text() == "old" and sorted(p.name for p in folder.iterdir()) == ["crossval.ipynb"]
    finally:
        if limit == "full disk":
            subprocess.run(["umount", str(folder)], check=False)


def test_build_writes_the_size_it_ran_at(tmp_path):
    """build.write records the size; a notebook without the record is not full."""
    notebook = build.make("crossval")
    assert build.stored_size(notebook) is None and full_size_problems(notebook)
    build.write(notebook, tmp_path / "crossval.ipynb", "full")
    assert build.stored_size(nbformat.read(tmp_path / "crossval.ipynb", as_version=4)) == "full"


def test_a_figure_shown_as_text_is_caught():
    """The issue's failure: a library that switches matplotlib to Agg before
    pyplot loads leaves the notebook without its inline formatter, and the
    figure cell shows `<Figure size ...>`: problems() reports that cell."""
    broken = new_code_cell("import matplotlib\nmatplotlib.use('Agg')\nimport matplotlib.pyplot as plt\n"
                           "figure, ax = plt.subplots()\nax.plot([0, 1])\nfigure",
                           metadata={"tags": ["figure"]})
    working = new_code_cell("from matplotlib.figure import Figure\nfigure = Figure()\n"
                            "figure.add_subplot().plot([0, 1])\nfrom IPython.display import display\n"
                            "%matplotlib inline\ndisplay(figure)", metadata={"tags": ["figure"]})
    notebook = build.execute(new_notebook(cells=[broken]), quick=True, timeout=120)
    found = build.problems(notebook)
    assert len(found) == 1 and "without an image/png" in found[0] and "Figure size" in found[0]
    notebook = build.execute(new_notebook(cells=[working]), quick=True, timeout=120)
    assert build.problems(notebook) == []


@pytest.mark.slow
def test_the_notebook_asserts_catch_errors_that_do_not_converge():
    """The error-against-time notebook's own checks, on a tiny version: they
    pass as is, and fail when the error no longer falls with the sample count."""
    shrink = ("from pathlib import Path\nimport validation.crossval as cv, validation.convergence as convergence\n"
              "cv.scene_paths = lambda course, quick: [Path('scenes/lamps.txt')]\n"
              "convergence.settings = lambda quick: (16, {'whitted': [1, 4, 16], 'path': [1, 4, 16]}, 256)\n")
    for broken, expected in (("", []), ("convergence.relmse = lambda image, reference: 0.01\n", ["AssertionError"])):
        notebook = build.make("error_vs_time")
        notebook.cells.insert(2, new_code_cell(shrink + broken))
        found = build.problems(build.execute(notebook, quick=True, timeout=600))
        assert [line.split(": ")[1] for line in found if "AssertionError" in line][:1] == expected, found
