"""The course's grading command lines and reference timings, read from its README."""
from __future__ import annotations

import re
import shlex
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_COURSE = ROOT.parent / "shared" / "course"


@dataclass(frozen=True)
class CourseRun:
    scene: str             # e.g. scene06_bunny_1k
    arguments: list[str]   # the a2 command line without the program name
    course_seconds: float  # the reference solution's time from the README


def course_runs(course: Path = DEFAULT_COURSE) -> list[CourseRun]:
    text = (course / "README.md").read_text()
    lines = [shlex.split(line)[1:] for line in text.splitlines() if re.match(r"\s*a2 -size", line)]
    table = [line for line in text.splitlines() if line.startswith("| seconds")]
    if not lines or not table:
        raise ValueError(f"{course / 'README.md'}: no grading command lines or timing table")
    seconds = [float(v) for v in table[0].strip("|").split("|")[1:]]
    runs = []
    for words, secs in zip(lines, seconds):
        scene = Path(words[words.index("-input") + 1]).stem
        runs.append(CourseRun(scene, words, secs))
    return runs
