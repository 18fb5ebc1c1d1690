"""What the notebooks use besides the library: progress bars (one over the
steps of a long library call), and figures shown exactly once."""
from __future__ import annotations

import sys
from contextlib import contextmanager
from functools import wraps
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from IPython.display import display
from tqdm import tqdm

from validation import convergence


def progress_bar(total: int | None, desc: str) -> tqdm:
    """A progress bar on stderr, as wide in a notebook as in a terminal."""
    return tqdm(total=total, desc=desc, unit="step", file=sys.stderr, dynamic_ncols=False, ncols=90)


@contextmanager
def counting(module, names: list[str], desc: str, total: int | None = None):
    """A progress bar that advances each time one of ``module``'s functions
    ``names`` returns, while the block runs (the library's loops call them by
    module name, so the count is theirs, not a copy of their loops)."""
    bar = progress_bar(total, desc)
    originals = {name: getattr(module, name) for name in names}

    def counted(function):
        @wraps(function)
        def step(*args, **kwargs):
            result = function(*args, **kwargs)
            bar.update(1)
            return result
        return step

    for name, function in originals.items():
        setattr(module, name, counted(function))
    try:
        yield bar
    finally:
        for name, function in originals.items():
            setattr(module, name, function)
        bar.close()


def show(figure) -> None:
    """Displays ``figure`` once (inline backends would show a pyplot figure
    again at the end of the cell) and frees it."""
    display(figure)
    plt.close(figure)


def check_figure(figure, panels: int) -> None:
    """A figure worth showing: ``panels`` axes, each with something drawn."""
    axes = [ax for ax in figure.axes if ax.get_visible()]
    assert len(axes) >= panels, f"{len(axes)} panels, expected {panels}"
    assert all(ax.has_data() for ax in axes), "an empty panel"


def retimed(results: dict, paths: list[Path], repeats: int) -> dict:
    """``results`` of :func:`validation.convergence.measure` with each render's
    time the median of its timing there and ``repeats`` more (the same render:
    same scene, spp and seed, so the same image and error), and the slopes
    fitted again. On a machine shared with other jobs one timing may catch a
    burst of their load; the median of three does not follow it."""
    by_scene = {path.stem: path for path in paths}
    size = results["settings"]["image_size"]
    points = []
    for point in results["points"]:
        path = by_scene[point["scene"]]
        options = convergence.method_options(point["method"], path)
        timings = [point["seconds"]] + [convergence.render_timed(path, size, point["spp"], 1, options)[1]
                                        for _ in range(repeats)]
        points.append(dict(point, seconds=float(np.median(timings)), timings=timings))
    return convergence.refit(dict(results, points=points))
