"""What the notebooks use besides the library: progress bars (one over the
steps of a long library call), and figures shown exactly once."""
from __future__ import annotations

import sys
from contextlib import contextmanager
from functools import wraps

from tqdm import tqdm


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
    from IPython.display import display
    import matplotlib.pyplot as plt

    display(figure)
    plt.close(figure)


def check_figure(figure, panels: int) -> None:
    """A figure worth showing: ``panels`` axes, each with something drawn."""
    axes = [ax for ax in figure.axes if ax.get_visible()]
    assert len(axes) >= panels, f"{len(axes)} panels, expected {panels}"
    assert all(ax.has_data() for ax in axes), "an empty panel"
