"""The course's reference images: how far ours are, and the regression bar.

:func:`render_grading_images` renders the course's seven grading command lines
(from its README) through ``render.py --batch``; :func:`image_counts` counts,
per image of ``sample_out``, the pixels more than 2/255 off in any channel.
``tests/test_course_images.py`` holds the renderer to the counts recorded in
:data:`RECORD` (``python -m benchmarks.course --record`` rewrites them): no
image may get more than :data:`REGRESSION_FACTOR` times worse.
"""
from __future__ import annotations

import os
import shlex
from pathlib import Path

from course import course_runs, outputs_into
from imaging.image_io import read_png
from imaging.metrics import MAX_BAD_FRACTION, bad_pixels
from renderer.cli import main

ROOT = Path(__file__).resolve().parent.parent
RECORD = ROOT / "docs" / "validation" / "course_images.json"
#: no image may have more than this many times its recorded bad pixels
#: (plus :data:`REGRESSION_SLACK` pixels, so that 0 or 3 recorded pixels do not make
#: a one-pixel change a failure)
REGRESSION_FACTOR = 2.0
REGRESSION_SLACK = 10


def render_grading_images(course: Path, folder: Path, variant: str | None = None) -> None:
    """All grading command lines in one ``render.py --batch`` run, outputs into ``folder``."""
    batch = folder / "grading.sh"
    batch.write_text("\n".join(shlex.join(["a2", *outputs_into(run.arguments, folder)])
                               for run in course_runs(course)) + "\n")
    cwd = os.getcwd()
    os.chdir(course)  # the command lines name their inputs relative to the course folder
    try:
        status = main(["--batch", str(batch), "--quiet", *(["--variant", variant] if variant else [])])
    finally:
        os.chdir(cwd)
    if status != 0:
        raise RuntimeError(f"render.py --batch exited with {status}")


def image_counts(course: Path, folder: Path) -> dict[str, dict[str, int]]:
    """Bad pixels per reference image of ``sample_out`` against ``folder``'s image of that name."""
    counts = {}
    for reference in sorted((course / "sample_out").glob("a0*.png")):
        expected = read_png(reference)
        counts[reference.name] = {"bad": bad_pixels(read_png(folder / reference.name), expected),
                                  "pixels": int(expected.shape[0] * expected.shape[1])}
    return counts


def allowed_bad_pixels(recorded: int, pixels: int) -> int:
    """The most bad pixels an image may have: the course's bar, and at most
    :data:`REGRESSION_FACTOR` x its recorded count (+ :data:`REGRESSION_SLACK`)."""
    return min(int(MAX_BAD_FRACTION * pixels), int(REGRESSION_FACTOR * recorded) + REGRESSION_SLACK)
