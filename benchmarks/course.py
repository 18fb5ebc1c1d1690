"""The course's grading command lines, and how far our images are from its references.

    python -m benchmarks.course [--record] [--variant V] [--course DIR]

Renders the course's seven grading command lines (from its README) through
``render.py --batch`` and counts, per image of ``sample_out``, the pixels more
than 2/255 off in any channel (:mod:`validation.course_images`). ``--record``
writes the counts, with machine, date and variant, to
``docs/validation/course_images.json``, which ``tests/test_course_images.py``
holds the renderer to (no image may get more than twice worse). Rerun it
after a change that moves pixels on purpose.
"""
from __future__ import annotations

import datetime as dt
import sys
import tempfile
from pathlib import Path

# started as `python benchmarks/x.py`, this folder would shadow the course and denoise packages
if __name__ == "__main__" and not __package__:
    sys.path[0] = str(Path(__file__).resolve().parents[1])

if __name__ == "__main__":  # first: ./.venv's Python, the libLLVM, then Dr.Jit (see core.launcher)
    from core.launcher import start
    start("python -m benchmarks.course", "benchmarks.course" if __package__ else None)

import mitsuba as mi

from benchmarks.records import machine, write_json
from core.entry import ArgumentParser
from course import root as course_root
from imaging.metrics import TOLERANCE
from renderer.variants import set_variant
from validation.course_images import RECORD, ROOT, image_counts, render_grading_images


def record(course: Path, variant: str | None, path: Path = RECORD) -> dict:
    """Renders the grading lines and writes their counts to ``path``."""
    variant = set_variant(variant)
    with tempfile.TemporaryDirectory() as tmp:
        render_grading_images(course, Path(tmp), mi.variant())
        counts = image_counts(course, Path(tmp))
    data = {"command": "python -m benchmarks.course --record", "machine": machine(),
            "date": dt.date.today().isoformat(), "variant": variant, "tolerance": TOLERANCE, "images": counts}
    write_json(path, data)
    return data


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog="python -m benchmarks.course", description=__doc__.split("\n\n")[0])
    parser.add_argument("--record", action="store_true", help=f"write the counts to {RECORD.relative_to(ROOT)}")
    parser.add_argument("--variant", help="variant (default: llvm_ad_rgb where usable)")
    parser.add_argument("--course", type=Path, default=course_root(),
                        help="course folder (default: $COURSE_ROOT, else ../shared/course)")
    args = parser.parse_args(argv)
    if args.record:
        counts = record(args.course, args.variant)["images"]
    else:
        variant = set_variant(args.variant)
        with tempfile.TemporaryDirectory() as tmp:
            render_grading_images(args.course, Path(tmp), variant)
            counts = image_counts(args.course, Path(tmp))
    for name, c in counts.items():
        print(f"{name}: {c['bad']} bad pixels ({100 * c['bad'] / c['pixels']:.3f} %)")
    return 0


if __name__ == "__main__":
    from core import entry

    entry.finish(entry.run("python -m benchmarks.course", main))
