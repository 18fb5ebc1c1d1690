"""The course's grading command lines, and how far our images are from its references.

    python -m benchmarks.course [--record] [--variant V]

Renders the course's seven grading command lines (from its README) through
``render.py --batch`` and counts, per image of ``sample_out``, the pixels more
than 2/255 off in any channel. ``--record`` writes the counts, with machine,
date and variant, to ``docs/validation/course_images.json``, which
``tests/test_course_images.py`` holds the renderer to (no image may get more
than :data:`REGRESSION_FACTOR` times worse). Rerun it after a change that
moves pixels on purpose.
"""
from __future__ import annotations

import argparse
import datetime as dt
import os
import platform
import re
import shlex
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_COURSE = ROOT.parent / "shared" / "course"
RECORD = ROOT / "docs" / "validation" / "course_images.json"
#: a pixel is bad when some 8-bit channel differs by more than this
TOLERANCE = 2
#: the course's bar: at most this fraction of bad pixels per image
MAX_BAD_FRACTION = 0.005
#: and no image may have more than this many times its recorded bad pixels
#: (plus :data:`REGRESSION_SLACK` pixels, so that 0 or 3 recorded pixels do not make
#: a one-pixel change a failure)
REGRESSION_FACTOR = 2.0
REGRESSION_SLACK = 10


@dataclass(frozen=True)
class CourseRun:
    scene: str             # e.g. scene06_bunny_1k
    arguments: list[str]   # the a2 command line without the program name


def grading_lines(course: Path = DEFAULT_COURSE) -> list[str]:
    """The course README's ``a2 -size ...`` command lines, verbatim."""
    text = (course / "README.md").read_text()
    lines = [line.strip() for line in text.splitlines() if re.match(r"\s*a2 -size", line)]
    if not lines:
        raise ValueError(f"{course / 'README.md'}: no grading command lines")
    return lines


def course_runs(course: Path = DEFAULT_COURSE) -> list[CourseRun]:
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


def bad_pixels(a: np.ndarray, b: np.ndarray, tolerance: int = TOLERANCE) -> int:
    """Pixels whose 8-bit values differ by more than ``tolerance`` in any channel."""
    a, b = np.asarray(a).astype(int), np.asarray(b).astype(int)
    if a.shape != b.shape:
        raise ValueError(f"image shapes differ: {a.shape} vs {b.shape}")
    diff = np.abs(a - b)
    return int((diff.max(axis=-1) if diff.ndim == 3 else diff).__gt__(tolerance).sum())


def render_grading_images(course: Path, folder: Path, variant: str | None = None) -> None:
    """All grading command lines in one ``render.py --batch`` run, outputs into ``folder``."""
    from renderer.cli import main

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
    from imaging.image_io import read_png

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


def machine() -> str:
    """CPU model, cores, OS and Python, for the record of a measurement."""
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{model}, {os.cpu_count()} cores, {platform.system()} {platform.release()}, Python {platform.python_version()}"


def record(course: Path, variant: str | None, path: Path = RECORD) -> dict:
    """Renders the grading lines and writes their counts to ``path``."""
    import mitsuba as mi

    from benchmarks import write_json
    from renderer.variants import set_variant

    variant = set_variant(variant, quiet=True)
    with tempfile.TemporaryDirectory() as tmp:
        render_grading_images(course, Path(tmp), mi.variant())
        counts = image_counts(course, Path(tmp))
    data = {"command": "python -m benchmarks.course --record", "machine": machine(),
            "date": dt.date.today().isoformat(), "variant": variant, "tolerance": TOLERANCE, "images": counts}
    write_json(path, data)
    return data


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.course", description=__doc__.split("\n\n")[0])
    parser.add_argument("--record", action="store_true", help=f"write the counts to {RECORD.relative_to(ROOT)}")
    parser.add_argument("--variant", help="variant (default: llvm_ad_rgb where usable)")
    parser.add_argument("--course", type=Path, default=DEFAULT_COURSE, help="course folder (default ../shared/course)")
    args = parser.parse_args(argv)
    if args.record:
        counts = record(args.course, args.variant)["images"]
    else:
        from renderer.variants import set_variant

        variant = set_variant(args.variant, quiet=True)
        with tempfile.TemporaryDirectory() as tmp:
            render_grading_images(args.course, Path(tmp), variant)
            counts = image_counts(args.course, Path(tmp))
    for name, c in counts.items():
        print(f"{name}: {c['bad']} bad pixels ({100 * c['bad'] / c['pixels']:.3f} %)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
