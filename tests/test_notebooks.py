"""The notebooks: stored with their outputs (plots as PNG), fresh, and re-run
here at the quick size; a figure shown as text or a wrong number fails."""
from __future__ import annotations

from pathlib import Path

import nbformat
import pytest
from nbformat.v4 import new_code_cell, new_notebook

from notebooks import build

ROOT = Path(__file__).resolve().parent.parent
NAMES = sorted(build.NOTEBOOKS)


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
    figures = [c for c in stored.cells if "figure" in c.metadata.get("tags", [])]
    assert figures and all(any("image/png" in o.get("data", {}) for o in c.outputs) for c in figures)
    streams = [o.text for c in stored.cells if c.cell_type == "code" for o in c.outputs
               if o.output_type == "stream"]
    assert not any("\r" in text for text in streams)  # progress bars at their final state


@pytest.mark.slow
@pytest.mark.parametrize("name", NAMES)
def test_notebook_reruns_with_its_plots(name):
    """CI re-executes each notebook (quick size): no error, no failed assert in
    its cells, a PNG from every figure cell."""
    notebook = build.tidy(build.execute(build.make(name), quick=True, timeout=900))
    assert build.problems(notebook) == []


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
