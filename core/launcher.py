"""Runs a command with the project's own Python when another one started it.

``python render.py ...`` or ``python -m converters ...`` typed in a shell
where ``python`` is the system's (no virtual environment active) would fail
on ``import numpy``. Each entry point calls :func:`use_project_python` first:
when the project's packages are not importable here but ``./.venv`` (made by
``./dev setup``) exists, the process replaces itself with the same command
run by ``./.venv/bin/python``; when there is no ``./.venv`` either, it prints
one line saying to run ``./dev setup`` and exits 2. It first installs
:func:`core.start_up.exit_on_signals`: a Ctrl-C during the imports that
follow (Dr.Jit's native start-up among them) then stops the command with one
line, until ``core.entry.run`` takes over.

:func:`start` is the first call of every entry point: the above, then the
libLLVM choice (:mod:`core.libllvm`) and the first import of Mitsuba and
Dr.Jit, after which any module may import them at its top, as Mitsuba's own
Python does.

Standard library only until the project's Python runs: it runs before
anything else is importable.
"""
from __future__ import annotations

import importlib.util
import os
import signal
import sys
from pathlib import Path

from core.start_up import INTERRUPTED, STOP_SIGNALS, exit_on_signals

ROOT = Path(__file__).resolve().parent.parent
VENV = ROOT / ".venv"
VENV_PYTHON = VENV / "bin" / "python"
#: What every entry point imports first (found, not imported, by the check)
REQUIRED = ("numpy", "drjit", "mitsuba")


def missing_packages() -> list[str]:
    return [name for name in REQUIRED if importlib.util.find_spec(name) is None]


def in_project_venv() -> bool:
    return Path(sys.prefix).resolve() == VENV.resolve()


def use_project_python(prog: str, module: str | None = None, stopped: str = INTERRUPTED) -> None:
    """Re-executes this command under ``./.venv/bin/python`` where needed.

    ``module`` is the ``-m`` name (``"converters"``); ``None`` re-runs the
    script ``sys.argv[0]``. Arguments, working folder and environment stay.
    ``stopped``: what a stop signal during the start-up prints after ``PROG: ``.
    """
    exit_on_signals(prog, stopped)
    missing = missing_packages()
    if not missing:
        return
    if VENV_PYTHON.exists() and not in_project_venv():
        command = [str(VENV_PYTHON)] + (["-m", module] if module else [sys.argv[0]]) + sys.argv[1:]
        sys.stdout.flush()
        sys.stderr.flush()
        # the mask survives exec: a Ctrl-C during the new Python's start-up waits for its
        # exit_on_signals (one line) instead of a KeyboardInterrupt traceback from some import
        signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
        os.execv(command[0], command)  # does not return
    where = f"{VENV_PYTHON} lacks them" if VENV_PYTHON.exists() else f"there is no {VENV}"
    print(f"{prog}: error: {sys.executable} cannot import {', '.join(missing)} and {where}; "
          f"run ./dev setup in {ROOT}", file=sys.stderr)
    raise SystemExit(2)


def start(prog: str, module: str | None = None, quiet: bool = True, stopped: str = INTERRUPTED) -> None:
    """The first call of every entry point: :func:`use_project_python`, then the
    libLLVM choice, then Dr.Jit's and Mitsuba's start-up (their own notices kept
    off stderr when ``quiet``, inside ``hold_signals``: see there)."""
    use_project_python(prog, module, stopped)  # the stop signals' handlers first, then the rest imports
    from core.entry import hold_signals, native_start_up  # noqa: PLC0415  after exit_on_signals (see above)
    from core.libllvm import prepare_libllvm  # noqa: PLC0415  after exit_on_signals (see above)

    prepare_libllvm(prog)
    with hold_signals(), native_start_up(quiet=quiet):
        import mitsuba  # noqa: F401, PLC0415  the first import of Dr.Jit: after the libLLVM is chosen


def start_before_package(package: str) -> None:
    """:func:`start` for ``python -m PACKAGE``, called first by a package whose
    ``__init__`` imports Dr.Jit: Python imports the package before it runs the
    package's ``__main__``. Python sets ``sys.argv[0]`` to ``"-m"`` while it
    looks for that module, so anything else (an ordinary import) returns at once."""
    if sys.argv[:1] != ["-m"]:
        return
    words = sys.orig_argv
    module = next((words[k + 1] if word == "-m" else word[2:] for k, word in enumerate(words[:-1])
                   if k and word.startswith("-m")), None)
    if module == package or (module or "").startswith(f"{package}."):
        start(f"python -m {module}", module)
