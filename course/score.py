"""python -m course.score: how far a folder of your ray tracer's images is from the course's.

    python -m course.score DIR [--reference DIR] [--report FILE.md]

Every PNG of the reference folder (the course's ``sample_out``: ``a01.png``,
``a01n.png``, ``a01d.png``, ...) is compared with the image of the same name
in DIR: the share of pixels that differ by more than 2/255 in some channel,
and the mean FLIP error. An image meets the course's bar when at most 0.5 %
of its pixels are that far off; a missing image fails. The command prints a
table, writes a Markdown report with thumbnails (and a FLIP heat map for
each failing image) and exits with 1 when some image fails, else 0. A
missing folder, an unreadable PNG, another format under a .png name, a PNG
with transparent pixels or an image of another size is one line and exit
code 2 (every PNG mode and bit depth is read as its pixels).
"""
from __future__ import annotations

if __name__ == "__main__":  # first: ./.venv's Python, the libLLVM, then Dr.Jit (see core.launcher)
    from core.launcher import start
    start("python -m course.score", "course.score")

import argparse
import os
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import quote

import numpy as np
from tqdm import tqdm

from core.entry import ArgumentParser, finish, printable, run
from core.errors import FrameError, UsageError
from core.inputs import check_outside
from course import ENVIRONMENT, root
from imaging.image_io import IMAGE_DECODE_ERRORS, atomic_path, check_writable, read_png, write_image
from imaging.metrics import MAX_BAD_FRACTION, TOLERANCE, bad_pixels, flip_error, flip_heat_map

PROG = "python -m course.score"
#: thumbnails in the report are at most this wide
THUMBNAIL_WIDTH = 200


@dataclass
class ImageScore:
    """One image's comparison; ``bad`` is None where DIR lacks the image."""
    name: str
    pixels: int
    bad: int | None = None
    flip: float | None = None
    heat_map: np.ndarray | None = None

    @property
    def missing(self) -> bool:
        return self.bad is None

    @property
    def passes(self) -> bool:
        """The course's bar: at most :data:`MAX_BAD_FRACTION` of the pixels off by more than 2/255."""
        return not self.missing and self.bad <= MAX_BAD_FRACTION * self.pixels


def read_image(path: Path) -> np.ndarray:
    """A PNG as uint8 RGB; a damaged file is one line naming it."""
    try:
        return read_png(path)
    except FileNotFoundError:
        raise
    except IMAGE_DECODE_ERRORS as error:
        raise FrameError(f"{path}: not a readable PNG ({' '.join(str(error).split()) or type(error).__name__})") \
            from None


def reference_images(reference: Path) -> list[Path]:
    if not reference.is_dir():
        raise FrameError(f"--reference {reference}: not a folder")
    found = sorted(reference.glob("*.png"))
    if not found:
        raise FrameError(f"--reference {reference}: no PNG images to compare with")
    return found


def score_image(yours: Path, reference: Path) -> ImageScore:
    """The comparison of ``yours`` with ``reference`` (FLIP only where they differ:
    identical images have FLIP 0; the heat map only where the bar is not met)."""
    expected = read_image(reference)
    score = ImageScore(reference.name, int(expected.shape[0] * expected.shape[1]))
    if not yours.exists():
        return score
    image = read_image(yours)
    if image.shape != expected.shape:
        raise FrameError(f"{yours}: {image.shape[1]}x{image.shape[0]} pixels, but {reference} has "
                         f"{expected.shape[1]}x{expected.shape[0]}")
    score.bad = bad_pixels(image, expected)
    if np.array_equal(image, expected):
        score.flip = 0.0
    elif score.passes:
        score.flip = flip_error(image / 255.0, expected / 255.0)
    else:
        score.flip, score.heat_map = flip_heat_map(image / 255.0, expected / 255.0)
    return score


def score_folder(folder: Path, reference: Path, on_image=None) -> list[ImageScore]:
    """Every reference image's score against ``folder``'s image of that name."""
    if not folder.is_dir():
        raise FrameError(f"{folder}: not a folder")
    scores = []
    for path in reference_images(reference):
        scores.append(score_image(folder / path.name, path))
        if on_image is not None:
            on_image(scores[-1])
    return scores


def table(scores: list[ImageScore]) -> list[str]:
    """The scores as Markdown table rows (without thumbnails)."""
    lines = [f"| image | pixels > {TOLERANCE}/255 off | share | mean FLIP | course's bar |", "|---|---|---|---|---|"]
    for s in scores:
        if s.missing:
            lines.append(f"| {s.name} | missing | | | fails |")
        else:
            lines.append(f"| {s.name} | {s.bad} | {100 * s.bad / s.pixels:.3f} % | {s.flip:.5f} | "
                         f"{'meets' if s.passes else 'fails'} |")
    return lines


def verdict(scores: list[ImageScore]) -> str:
    failing = [s.name for s in scores if not s.passes and not s.missing]
    missing = [s.name for s in scores if s.missing]
    line = (f"{sum(s.passes for s in scores)} of {len(scores)} images meet the course's bar (at most "
            f"{100 * MAX_BAD_FRACTION:g} % of pixels more than {TOLERANCE}/255 off)")
    if failing:
        line += "; failing: " + ", ".join(failing)
    if missing:
        line += "; missing: " + ", ".join(missing)
    return line


def thumbnail(image: np.ndarray) -> np.ndarray:
    """``image`` box-filtered down to at most :data:`THUMBNAIL_WIDTH` pixels wide."""
    shrink = -(-image.shape[1] // THUMBNAIL_WIDTH)
    if shrink == 1:
        return image
    h, w = image.shape[0] // shrink, image.shape[1] // shrink
    small = image[: h * shrink, : w * shrink].astype(np.float64).reshape(h, shrink, w, shrink, -1).mean(axis=(1, 3))
    return np.round(small).astype(np.uint8)


def write_report(report: Path, scores: list[ImageScore], folder: Path, reference: Path) -> None:
    """The Markdown report; its images go into the folder ``<report stem>/`` beside it:
    thumbnails of the reference and yours, and for each failing image its FLIP heat map
    (full size, linked from its thumbnail)."""
    assets = report.parent / report.stem
    assets.mkdir(parents=True, exist_ok=True)

    def link(name: str) -> str:  # percent-encoded: a space, a bracket or a byte that is not UTF-8 stays a link
        return quote(os.fsencode(f"{assets.name}/{name}"))

    lines = [f"# Scores of {printable(folder)}", "",
             f"Against `{printable(reference)}` ({len(scores)} images). {printable(verdict(scores))}.", "",
             f"| image | pixels > {TOLERANCE}/255 off | mean FLIP | course's bar | reference | yours | FLIP heat map |",
             "|---|---|---|---|---|---|---|"]
    for s in scores:
        stem = Path(s.name).stem
        write_image(assets / f"{stem}_reference.png", thumbnail(read_image(reference / s.name)))
        cells = [f"![reference]({link(f'{stem}_reference.png')})"]
        name = printable(s.name)
        if s.missing:
            lines.append(f"| {name} | missing | | fails | {cells[0]} | | |")
            continue
        write_image(assets / f"{stem}_yours.png", thumbnail(read_image(folder / s.name)))
        cells.append(f"![yours]({link(f'{stem}_yours.png')})")
        if s.heat_map is not None:
            write_image(assets / f"{stem}_flip.png", s.heat_map)
            write_image(assets / f"{stem}_flip_small.png", thumbnail(s.heat_map))
            cells.append(f"[![FLIP]({link(f'{stem}_flip_small.png')})]({link(f'{stem}_flip.png')})")
        else:
            cells.append("")
        lines.append(f"| {name} | {s.bad} ({100 * s.bad / s.pixels:.3f} %) | {s.flip:.5f} | "
                     f"{'meets' if s.passes else '**fails**'} | " + " | ".join(cells) + " |")
    with atomic_path(report, ".md") as tmp:
        tmp.write_text("\n".join(lines) + "\n")


def _parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(prog=PROG, description=__doc__.split("\n", 1)[0].split(": ", 1)[1],
                            formatter_class=argparse.RawDescriptionHelpFormatter,
                            epilog="exit status: 0 when every image meets the course's bar, 1 when one fails or is "
                                   "missing, 2 on an error\nexample: python -m course.score out/mine")
    parser.add_argument("folder", type=Path, metavar="DIR", help="your images (a01.png, a01n.png, a01d.png, ...)")
    parser.add_argument("--reference", type=Path, metavar="DIR",
                        help="the images to compare with (default: the course's sample_out)")
    parser.add_argument("--report", type=Path, metavar="FILE.md",
                        help="the Markdown report (default: DIR/score.md; its images go into DIR/score/)")
    return parser


def _main(argv: list[str] | None) -> int:
    args = _parser().parse_args(argv)
    if not args.folder.is_dir():
        raise FrameError(f"{args.folder}: not a folder")
    reference = args.reference or root() / "sample_out"
    if args.reference is None and not reference.is_dir():
        raise FrameError(f"the course's sample_out is not at {reference}: set ${ENVIRONMENT} to the course folder "
                         "or pass --reference DIR")
    count = len(reference_images(reference))  # checked before the first image
    report = args.report or args.folder / "score.md"
    if report.suffix.lower() != ".md":  # never onto an image being scored
        raise UsageError(f"--report writes Markdown: name it .md, got {report}")
    # the report and its images (beside it, in a folder of its stem) never go into the reference, at any depth
    check_outside({"--report": report, "--report's images": report.parent / report.stem},
                  {"--reference": reference})
    check_writable("--report", report)

    with tqdm(total=count, desc="scoring", unit="image", delay=1.0, leave=False,
              disable=None) as bar:
        scores = score_folder(args.folder, reference, on_image=lambda _: bar.update())
    print("\n".join(printable(line) for line in table(scores)))
    print(printable(verdict(scores)))
    write_report(report, scores, args.folder, reference)
    print(f"report: {printable(report)}")
    return 0 if all(s.passes for s in scores) else 1


def main(argv: list[str] | None = None) -> int:
    return run(PROG, lambda: _main(argv))


if __name__ == "__main__":
    finish(main())
