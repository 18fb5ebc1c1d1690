"""python -m denoise.score: any denoiser's results against a ground truth, frame by frame.

    python -m denoise.score RESULTS --reference REF_DIR [--frames FRAME_DIR]
                            [--pattern 'result_{i}.exr'] [--compare METHOD ...]
                            [--plot FILE.png] [--json FILE]

RESULTS holds one EXR per frame (the GAMES202 framework's ``result_i.exr``,
or ``--pattern``); REF_DIR the ground truth ``beauty_i.exr`` of each frame
scored (``python -m export`` writes it as ``OUT_reference``). Per
frame: relMSE and mean FLIP against the truth. With ``--frames`` (the frame
folder the results were made from: its positions, ids and matrices) also
``temporal``, the relMSE between a result and the previous one
back-projected onto it, and the stability figure: its mean over the
ground truth's (1 = as steady as the truth). A reference that is no ground
truth (a frame folder, an export's truth of no more samples than the
frames, or the truth of another sequence than ``--frames``, by the export's
records) is refused (:mod:`export.ground_truth`). ``--compare METHOD ...`` runs
our methods (``python -m denoise``'s, named as in ``benchmarks.denoise``:
``svgf``, ``atrous+temporal``, ``oidn``, ...; ``raw`` is the noisy input) on
the same frames and scores them beside the results. Every number comes from
:mod:`imaging.metrics`, as in ``python -m benchmarks.denoise``.
"""
from __future__ import annotations

if __name__ == "__main__":  # first: ./.venv's Python, the libLLVM, then Dr.Jit (see core.launcher)
    from core.launcher import start
    start("python -m denoise.score", "denoise.score")

import argparse
import json
import os
import re
import string
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from core.entry import ArgumentParser, finish, run
from core.errors import FrameError, OutputError, UsageError
from core.inputs import check_outside
from export.frames import frame_indices, missing_between, read_frame, same_size
from export.ground_truth import check_ground_truth, check_outside_exports
from imaging.image_io import atomic_path, check_writable, read_exr_rgb
from imaging.metrics import flip_error, relmse
from renderer.variants import set_variant

from .methods import check_method_names, data_files, from_name
from .methods.user import add_method_file_option, load_method_files
from .pipeline import check_folder
from .temporal_metrics import stability, temporal_relmse

PROG = "python -m denoise.score"
DEFAULT_PATTERN = "result_{i}.exr"
#: the longest file name most file systems take
NAME_BYTES = 255
#: the noisy input, scored as a method
RAW = "raw"


@dataclass
class MethodScore:
    """One method's figures per frame; ``temporal`` (from the second frame on) and
    ``stability`` are None without the frame folder."""
    name: str
    relmse: list[float]
    flip: list[float]
    temporal: list[float] | None = None
    stability: float | None = None

    def as_json(self) -> dict:
        return {"name": self.name, "relmse": self.relmse, "flip": self.flip,
                "temporal": None if self.temporal is None else [None] + self.temporal,
                "mean_relmse": float(np.mean(self.relmse)), "mean_flip": float(np.mean(self.flip)),
                "stability": self.stability}


def check_pattern(pattern: str) -> str:
    """A file-name pattern with one ``{i}`` field (the frame index) and no other."""
    try:
        fields = [name for _, name, _, _ in string.Formatter().parse(pattern) if name is not None]
    except ValueError as error:
        raise UsageError(f"--pattern {pattern!r}: {error}") from None
    if fields != ["i"] or "/" in pattern:
        raise UsageError(f"--pattern {pattern!r}: a file name with exactly one {{i}} for the frame index, "
                         f"e.g. {DEFAULT_PATTERN!r}")
    specs = [spec for _, name, spec, _ in string.Formatter().parse(pattern) if name is not None]
    if any(re.search(r"\d{4,}", spec or "") for spec in specs):  # formatting it would fill the memory first
        raise UsageError(f"--pattern {pattern!r}: a width beyond what a file name holds ({NAME_BYTES} bytes)")
    try:
        pattern.format(i=0)
    except (ValueError, TypeError) as error:  # a format spec an integer does not take, e.g. {i:q}
        raise UsageError(f"--pattern {pattern!r}: {error}") from None
    return pattern


def read_rgb(path: Path) -> np.ndarray:
    """An EXR's R, G, B as float32 (H, W, 3); a damaged file, or one with NaN
    or infinite values (which no figure can score), is one line naming it."""
    if not path.exists():
        raise FrameError(f"{path}: missing")
    try:
        image = read_exr_rgb(path)
    except FrameError:  # a pipe or a device: said by the reader, before any read
        raise
    except KeyError as error:
        raise FrameError(f"{path}: no {error.args[0]} channel (expected R, G, B)") from None
    except Exception as error:  # OpenEXR reports damage as RuntimeError/OSError without the name
        raise FrameError(f"{path}: not a readable EXR ({' '.join(str(error).split()) or type(error).__name__})") \
            from None
    check_finite(path, image)
    return image


def check_finite(path: Path, image: np.ndarray, what: str = "") -> None:
    """One line naming ``path`` where ``image`` has NaN or infinite values, which no figure can score."""
    bad = ~np.isfinite(image)
    if bad.any():
        nan, inf = int(np.isnan(image).any(-1).sum()), int((bad & ~np.isnan(image)).any(-1).sum())
        raise FrameError(f"{path}: {nan} pixels NaN and {inf} infinite of {image.shape[0] * image.shape[1]}"
                         f"{what} (relMSE and FLIP need finite values)")


def reference_indices(reference: Path) -> list[int]:
    if not reference.is_dir():
        raise FrameError(f"--reference {reference}: not a folder")
    indices = frame_indices(reference)
    if not indices:
        raise FrameError(f"--reference {reference}: no beauty_<i>.exr frames")
    return indices


def check_consecutive(reference: Path, indices: list[int]) -> None:
    """The temporal figures compare each frame with the one before: no frame may be missing between."""
    gap = missing_between(indices)
    if gap:
        raise FrameError(f"--reference {reference}: frames {indices[0]}..{indices[-1]} without "
                         f"beauty_{gap[0]}.exr{f' (and {gap[1] - 1} more)' if gap[1] > 1 else ''}; "
                         "the temporal figures (--frames) need consecutive frames")


def result_paths(results: Path, pattern: str, indices: list[int]) -> list[Path]:
    """The result file of every frame, each checked to exist."""
    if not results.is_dir():
        raise FrameError(f"{results}: not a folder")
    names = [pattern.format(i=i) for i in indices]
    long = [name for name in names if len(os.fsencode(name)) > NAME_BYTES]
    if long:
        raise UsageError(f"--pattern {pattern!r}: names frame {indices[names.index(long[0])]} "
                         f"{long[0][:40]}... ({len(os.fsencode(long[0]))} bytes; a file name holds {NAME_BYTES})")
    first = {}
    for index, name in zip(indices, names):
        if name in first:
            raise UsageError(f"--pattern {pattern!r}: frames {first[name]} and {index} would both be read from "
                             f"{name}")
        first[name] = index
    paths = [results / name for name in names]
    missing = [p for p in paths if not p.exists()]
    if missing:
        more = f" (and {len(missing) - 1} more of the reference's {len(paths)} frames)" if len(missing) > 1 else ""
        raise FrameError(f"{missing[0]}: missing{more}")
    return paths


def read_sized(paths: list[Path], truth: dict[Path, np.ndarray]) -> list[np.ndarray]:
    """The images of ``paths``, each sized like its ``truth`` (reference file -> image)."""
    images = []
    for path, (truth_path, expected) in zip(paths, truth.items()):
        image = read_rgb(path)
        same_size(path, image.shape, truth_path, expected.shape)
        images.append(image)
    return images


def read_truth(reference: Path, indices: list[int]) -> dict[Path, np.ndarray]:
    """The reference's frames (file -> image), all of one size."""
    truth = {}
    for i in indices:
        path = reference / f"beauty_{i}.exr"
        truth[path] = read_rgb(path)
        first = next(iter(truth))
        same_size(path, truth[path].shape, first, truth[first].shape)
    return truth


def read_frames(folder: Path, indices: list[int], truth: dict[Path, np.ndarray]):
    """The frame folder's frames at ``indices`` (each checked, and sized like the truth)."""
    have = set(check_folder(folder))
    lacking = [i for i in indices if i not in have]
    if lacking:
        raise FrameError(f"--frames {folder}: no frame {lacking[0]}, which the reference has")
    frames = [read_frame(folder, i) for i in indices]
    for index, frame, (truth_path, expected) in zip(indices, frames, truth.items()):
        same_size(folder / f"beauty_{index}.exr", frame.beauty.shape, truth_path, expected.shape)
    return frames


def run_method(name: str, frames) -> list[np.ndarray]:
    """Our method ``name`` over ``frames`` in order (history kept), as ``benchmarks.denoise`` runs it."""
    if name == RAW:
        return [frame.beauty for frame in frames]
    denoiser = from_name(name)
    return [denoiser.step(frame) for frame in frames]


def score_images(name: str, images: list[np.ndarray], truth: list[np.ndarray], frames=None,
                 reference_temporal: list[float] | None = None) -> MethodScore:
    score = MethodScore(name, [relmse(image, reference) for image, reference in zip(images, truth)],
                        [flip_error(image, reference) for image, reference in zip(images, truth)])
    if frames is not None:
        score.temporal = temporal_relmse(frames, images)
        score.stability = stability(score.temporal, reference_temporal) if score.temporal else None
    return score


def score_sequence(results: Path, reference: Path, frames_folder: Path | None = None,
                   pattern: str = DEFAULT_PATTERN, compare: tuple[str, ...] = ()) -> dict:
    """Everything the command reports: ``indices``, ``reference_temporal`` (None
    without frames) and ``scores`` (the results', then each compared method's)."""
    pattern = check_pattern(pattern)
    if compare and frames_folder is None:
        raise UsageError("--compare runs our methods on the frames: give --frames FRAME_DIR")
    check_method_names("--compare", list(compare), {RAW: "the noisy input"})
    indices = reference_indices(reference)
    check_ground_truth("--reference", reference, frames_folder)
    if frames_folder is not None:
        check_consecutive(reference, indices)
    paths = result_paths(results, pattern, indices)
    named_truth = read_truth(reference, indices)
    images = read_sized(paths, named_truth)
    truth = list(named_truth.values())
    frames = reference_temporal = None
    if frames_folder is not None:
        frames = read_frames(frames_folder, indices, named_truth)
        if RAW in compare:  # the noisy input scored as it is, so as the results are: finite or refused
            for index, frame in zip(indices, frames):
                check_finite(frames_folder / f"beauty_{index}.exr", frame.beauty, f", which --compare {RAW} scores")
        reference_temporal = temporal_relmse(frames, truth)
    label = results.name or str(results)
    label = f"{label} (results)" if label in compare else label
    scores = [score_images(label, images, truth, frames, reference_temporal)]
    for name in compare:
        scores.append(score_images(name, run_method(name, frames), truth, frames, reference_temporal))
    return {"indices": indices, "reference_temporal": reference_temporal, "scores": scores}


def tables(report: dict) -> list[str]:
    """Per frame, then per method (means and stability), as Markdown tables."""
    indices, scores = report["indices"], report["scores"]
    lines = ["| method | frame | relMSE | FLIP | temporal |", "|---|---|---|---|---|"]
    for s in scores:
        temporal = [None] + s.temporal if s.temporal is not None else [None] * len(indices)
        for k, index in enumerate(indices):
            lines.append(f"| {s.name} | {index} | {s.relmse[k]:.5f} | {s.flip[k]:.4f} | "
                         + ("" if temporal[k] is None else f"{temporal[k]:.5f}") + " |")
    lines += ["", "| method | mean relMSE | mean FLIP | temporal stability |", "|---|---|---|---|"]
    for s in scores:
        missing = "n/a (no --frames)" if s.temporal is None else "n/a (one frame: no pair to compare)"
        lines.append(f"| {s.name} | {np.mean(s.relmse):.5f} | {np.mean(s.flip):.4f} | "
                     + (missing if s.stability is None else f"{s.stability:.2f}") + " |")
    return lines


def write_plot(path: Path, report: dict) -> None:
    """relMSE, FLIP and (with frames) temporal relMSE per frame, a line per method."""
    from matplotlib.figure import Figure  # noqa: PLC0415  without pyplot: no display, no global state
    from matplotlib.ticker import MaxNLocator  # noqa: PLC0415  matplotlib loads on use: --help and the paths without it stay quick

    indices, scores = report["indices"], report["scores"]
    panels = [("relMSE", "relmse"), ("mean FLIP", "flip")]
    if report["reference_temporal"] is not None:
        panels.append(("temporal relMSE", "temporal"))
    figure = Figure(figsize=(4.2 * len(panels), 3.4), layout="constrained")
    for axes, (title, key) in zip(figure.subplots(1, len(panels), squeeze=False)[0], panels):
        for k, s in enumerate(scores):
            values = getattr(s, key)
            axes.plot(indices[len(indices) - len(values):], values, marker="o", label=s.name,
                      linewidth=2.5 if k == 0 else 1.2)  # the results scored stand out from ours
        if key == "temporal":
            axes.plot(indices[1:], report["reference_temporal"], "k--", label="ground truth")
        axes.set(title=title, xlabel="frame", yscale="log" if key != "flip" else "linear")
        axes.xaxis.set_major_locator(MaxNLocator(integer=True))
        axes.grid(alpha=0.3)
    figure.legend(*axes.get_legend_handles_labels(), loc="outside right upper", fontsize="small")
    with atomic_path(path, ".png") as tmp:
        figure.savefig(tmp, format="png", dpi=110)


def write_json(path: Path, report: dict, arguments: dict) -> None:
    data = {**arguments, "indices": report["indices"], "reference_temporal": report["reference_temporal"],
            "methods": [s.as_json() for s in report["scores"]]}
    with atomic_path(path, ".json") as tmp:
        tmp.write_text(json.dumps(data, indent=2) + "\n")


def _parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(prog=PROG, description=__doc__.split("\n", 1)[0].split(": ", 1)[1],
                            formatter_class=argparse.RawDescriptionHelpFormatter,
                            epilog="example: python -m denoise.score out/mine --reference out/seq_reference "
                                   "--frames out/seq --compare svgf oidn --plot out/mine.png")
    parser.add_argument("results", type=Path, metavar="RESULTS", help="the folder of per-frame results (EXR)")
    parser.add_argument("--reference", type=Path, metavar="REF_DIR", required=True,
                        help="the ground truth: beauty_i.exr per frame")
    parser.add_argument("--frames", type=Path, metavar="FRAME_DIR",
                        help="the frames the results were made from (temporal stability, --compare)")
    parser.add_argument("--pattern", default=DEFAULT_PATTERN, help=f"result file names (default {DEFAULT_PATTERN})")
    parser.add_argument("--compare", nargs="+", metavar="METHOD", default=[],
                        help="our methods, run on --frames and scored beside the results (e.g. svgf oidn raw)")
    add_method_file_option(parser)
    parser.add_argument("--plot", type=Path, metavar="FILE.png", help="write the per-frame figures as a plot")
    parser.add_argument("--json", type=Path, metavar="FILE", help="write every number as JSON")
    parser.add_argument("--variant", help="Mitsuba variant (default: llvm_ad_rgb where usable)")
    return parser


def _main(argv: list[str] | None) -> int:
    load_method_files(argv)  # a method of one's own, for --compare
    args = _parser().parse_args(argv)
    if args.plot is not None and args.plot.suffix.lower() != ".png":
        raise UsageError(f"--plot writes PNG: name it .png, got {args.plot}")
    if args.json is not None and args.json.suffix.lower() != ".json":  # never onto a frame or a result
        raise UsageError(f"--json writes JSON: name it .json, got {args.json}")
    for flag, path in (("--plot", args.plot), ("--json", args.json)):
        if path is not None:
            if path.is_dir():
                raise OutputError(f"{flag} {path}: a folder, not a file")
            check_writable(flag, path)
    check_outside_exports({"--plot": args.plot, "--json": args.json})  # the reference's frames, a dataset's record
    check_outside({"--plot": args.plot, "--json": args.json},
                  {"RESULTS": args.results, "--reference": args.reference, "--frames": args.frames, **data_files()})
    check_pattern(args.pattern)  # the cheap checks before Dr.Jit starts
    if args.compare and args.frames is None:
        raise UsageError("--compare runs our methods on the frames: give --frames FRAME_DIR")
    check_method_names("--compare", args.compare, {RAW: "the noisy input"})
    if args.frames is not None:  # back projection and our methods run in Dr.Jit

        set_variant(args.variant, jit=True)
    report = score_sequence(args.results, args.reference, args.frames, args.pattern, tuple(args.compare))
    print("\n".join(tables(report)))
    if args.plot is not None:
        write_plot(args.plot, report)
    if args.json is not None:
        write_json(args.json, report, {"results": str(args.results), "reference": str(args.reference),
                                       "frames": None if args.frames is None else str(args.frames),
                                       "pattern": args.pattern})
    return 0


def main(argv: list[str] | None = None) -> int:
    return run(PROG, lambda: _main(argv))


if __name__ == "__main__":
    finish(main())
