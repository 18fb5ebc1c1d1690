"""The course's data: where it is, its scenes by name, and its grading command lines.

The course folder (``data/`` with the scenes, ``sample_out/`` with the reference
images, ``README.md`` with the grading command lines) is ``$COURSE_ROOT``, else
``../shared/course`` beside this checkout. ``render.py``, ``export``, the
benchmarks and the tests all find it through :func:`root`.

Imports only the standard library and :mod:`core.errors` (``render.py --help``
must not wait for NumPy or Mitsuba).
"""
from __future__ import annotations

import os
import re
import shlex
from dataclasses import dataclass
from pathlib import Path

from core.errors import NEED_COURSE, UsageError

REPO = Path(__file__).resolve().parent.parent
#: our own scenes, looked up by name before the course's
OUR_SCENES = REPO / "scenes"
#: the one environment variable that moves the course folder
ENVIRONMENT = "COURSE_ROOT"
#: names that located the course before: refused with a pointer to ENVIRONMENT,
#: never read (a user who set one would otherwise get the default silently)
RETIRED_ENVIRONMENT = ("COURSE_DATA",)
#: where CI and the development machines keep the course
DEFAULT_ROOT = REPO.parent / "shared" / "course"


def root() -> Path:
    """The course folder: ``$COURSE_ROOT``, else ``../shared/course`` (which may not exist)."""
    value = os.environ.get(ENVIRONMENT)
    retired = [name for name in RETIRED_ENVIRONMENT if os.environ.get(name)]
    if retired and not value:
        raise UsageError(f"${retired[0]} is no longer read; set ${ENVIRONMENT} to the course folder "
                         f"(the one holding data/ and sample_out/), or pass --data DIR")
    return Path(value) if value else DEFAULT_ROOT


def data_dir(explicit: str | Path | None = None) -> Path | None:
    """The folder of the course's scenes: ``explicit`` (``--data``), else ``root()/data``
    (``None`` where the default course is absent; a ``$COURSE_ROOT`` is taken as given)."""
    if explicit:
        return Path(explicit)
    data = root() / "data"
    return data if os.environ.get(ENVIRONMENT) or data.is_dir() else None


def check_data_flag(data: str | Path | None) -> None:
    """``--data`` where given is an existing folder, whether or not a scene is
    looked up in it (a mistyped folder was otherwise ignored in silence)."""
    if data is None:
        return
    path = Path(data)
    if not path.is_dir():
        raise UsageError(f"--data {data}: {'a file, not a folder' if path.exists() else 'does not exist'} "
                         f"(the course's data folder)")


def resolve_scene(name: str, data: Path | None) -> Path:
    """A scene by path, or by name in ``scenes/`` then the course data folder ``data``.

    A name matches ``<name>.txt`` or, if unique, ``<name>_*.txt`` (so
    ``scene06`` finds ``scene06_bunny_1k.txt``). A name that looks like a
    path (a folder part, or ``.txt``) must be an existing file.
    """
    path = Path(name)
    if path.is_dir():
        raise UsageError(f"scene {name} is a folder, not a scene file")
    if path.suffix == ".txt" or path.parent != Path(".") or path.is_absolute():
        if path.is_file():
            return path
        why = "is a folder" if path.is_dir() else "does not exist"
        raise UsageError(f"scene file {name} {why}")
    folders = [OUR_SCENES] + ([data] if data else [])
    for folder in folders:
        exact = folder / f"{name}.txt"
        if exact.exists():
            return exact
        matches = sorted(folder.glob(f"{name}_*.txt"))
        if len(matches) == 1:
            return matches[0]
        if len(matches) > 1:
            raise UsageError(f"scene name {name!r} is ambiguous in {folder}: "
                             + ", ".join(m.name for m in matches))
    where = ", ".join(str(f) for f in folders)
    if not data:  # the remedy names --data, which not every command has (ToolkitError.need)
        raise UsageError(f"no scene {name!r} in {where}",
                         f"set --data to the course's data folder, or {ENVIRONMENT} to the course folder", NEED_COURSE)
    chosen = f"${ENVIRONMENT}={os.environ[ENVIRONMENT]}" if os.environ.get(ENVIRONMENT) else "--data"
    if not data.is_dir():
        hint = f" ({data} {'is a file, not a folder' if data.exists() else 'does not exist'}; {chosen} chose it)"
    elif not any(data.glob("*.txt")):
        hint = f" ({data} holds no scene files (*.txt); {chosen} chose it, and should be the course's data folder)"
    else:
        hint = ""
    raise UsageError(f"no scene {name!r} in {where}{hint}")


# -- grading command lines ------------------------------------------------------------
#: the course binary's flags and how many values each takes
FLAG_VALUE_COUNTS = {"-input": 1, "-size": 2, "-output": 1, "-normals": 1, "-depth": 3, "-bounces": 1,
                "-shadows": 0, "-jitter": 0, "-filter": 0}


@dataclass(frozen=True)
class CourseRun:
    """One grading command line: ``a2 -size W H -input FILE ...``."""
    scene: str             # e.g. scene06_bunny_1k
    arguments: list[str]   # the command line without the program name, verbatim

    def flags(self) -> dict[str, list[str]]:
        """Each flag's values (``[]`` for a switch); a flag the course binary lacks is an error."""
        flags, words = {}, list(self.arguments)
        while words:
            flag = words.pop(0)
            if flag not in FLAG_VALUE_COUNTS or len(words) < FLAG_VALUE_COUNTS[flag]:
                raise ValueError(f"grading line {shlex.join(self.arguments)}: unexpected {flag!r}")
            flags[flag] = [words.pop(0) for _ in range(FLAG_VALUE_COUNTS[flag])]
        return flags


def grading_lines(course: Path | None = None) -> list[str]:
    """The course README's ``a2 -size ...`` command lines, verbatim."""
    readme = (root() if course is None else course) / "README.md"
    lines = [line.strip() for line in readme.read_text().splitlines() if re.match(r"\s*a2 -size", line)]
    if not lines:
        raise ValueError(f"{readme}: no grading command lines")
    return lines


def course_runs(course: Path | None = None) -> list[CourseRun]:
    """The grading command lines, parsed."""
    runs = []
    for line in grading_lines(course):
        words = shlex.split(line)[1:]
        runs.append(CourseRun(Path(words[words.index("-input") + 1]).stem, words))
    return runs


def outputs_into(words: list[str], folder: Path) -> list[str]:
    """The command line with its output files moved into ``folder``."""
    out = list(words)
    for flag, offset in (("-output", 1), ("-normals", 1), ("-depth", 3)):
        if flag in out:
            k = out.index(flag) + offset
            out[k] = str(folder / Path(out[k]).name)
    return out
