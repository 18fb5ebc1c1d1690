"""How far asvgf is from OIDN 2 because of its temporal gradient, measured with a perfect one.

    python -m benchmarks.asvgf_bounds [--work DIR] [--sequences NAME ...] [--json PATH] [--docs]

A-SVGF's temporal gradient λ says where the history is out of date. asvgf
estimates it from the history (:func:`denoise.methods.asvgf.temporal_gradient`); the
paper re-renders gradient samples. Either way the best a gradient can do is
to be exact, and the ground truth gives the exact one: the relative change of
the 3x3 box mean of the demodulated truth's luminance between a frame and its
back-projected predecessor, ``λ = clip(ORACLE_GAIN (δ - ORACLE_THRESHOLD), 0, 1)``.

On each benchmark sequence already rendered into ``--work`` by
``python -m benchmarks.denoise`` (nothing is rendered here), side by side:
``oidn-high``, ``asvgf`` as shipped, ``asvgf`` with the exact λ, and the
same without its history clips and with a history of up to ``LONG_HISTORY``
frames (the exact λ alone decides what to forget, so nothing needs to be
short).
Prints the mean relMSE over frames >= ``QUALITY_FROM`` of each and its
ratio to ``oidn-high``'s (the bar of ``python -m benchmarks.denoise`` is
1.5). If even the exact λ leaves a sequence above the bar, what is missing
there is spatial: the filtering of pixels whose history is short.

Then the spatial side's bound for a method that steers asvgf (as
``learned-asvgf`` does): the images asvgf can make of a frame from the
history it has (its slow history and the output of every À-Trous level, the
wide one too, with σ_luminance times each of ``SELECTION_SCALES``, and its
own output), and the error of an oracle that picks, with the truth in hand,
the best of them per pixel, or per square tile of ``SELECTION_TILES``
pixels a side (a choice a network could make from a neighbourhood; one
pixel's choice also picks its noise). As ratios to asvgf's.
``--docs`` writes the tables into docs/asvgf.md (sections ``asvgf-bounds``
and ``asvgf-selection``).
"""
from __future__ import annotations

import argparse
import datetime
import sys
from dataclasses import replace
from pathlib import Path

# started as `python benchmarks/x.py`, this folder would shadow the course and denoise packages
if __name__ == "__main__" and not __package__:
    sys.path[0] = str(Path(__file__).resolve().parents[1])

if __name__ == "__main__":  # first: ./.venv's Python, the libLLVM, then Dr.Jit (see core.launcher)
    from core.launcher import start
    start("python -m benchmarks.asvgf_bounds", "benchmarks.asvgf_bounds" if __package__ else None)

import drjit as dr
import mitsuba as mi
import numpy as np

from benchmarks.denoise import QUALITY, REFERENCE_SPP, SEQUENCES
from benchmarks.denoise_report import ASVGF_RELMSE_BAR, BASELINE
from benchmarks.records import check_json, machine, write_json
from core import entry
from core.entry import ArgumentParser
from core.errors import UsageError
from core.markdown import replace_section
from denoise.filters import demodulate, remodulate
from denoise.fit import prepare
from denoise.methods import from_name
from denoise.methods.asvgf import (
    GRADIENT_FLOOR,
    ASVGFHistory,
    ASVGFParams,
    FilterValues,
    asvgf,
    box_statistics,
    fitted,
    to_ycocg,
)
from denoise.temporal_metrics import QUALITY_FROM
from export import reference_folder
from export.frames import frame_indices, read_frame
from imaging.metrics import least_error_per_tile, relmse, relmse_per_pixel
from renderer.variants import set_variant

ROOT = Path(__file__).resolve().parent.parent
PAGE = ROOT / "docs" / "asvgf.md"
PROG = "python -m benchmarks.asvgf_bounds"
#: the exact λ: a relative change of the truth's 3x3 mean above the threshold forgets the history
ORACLE_GAIN = 10.0
ORACLE_THRESHOLD = 0.02
#: a clip this wide never acts (the widest asvgf declares)
NO_CLIP = 100.0
#: with the exact λ deciding what to forget, the history may be long: the cap is then this
LONG_HISTORY = 32.0
VARIANTS = ("asvgf", "asvgf, exact λ", "asvgf, exact λ, no clip, long history")
#: the σ_luminance factors of the À-Trous outputs the oracle picks from
SELECTION_SCALES = (0.25, 0.5, 1.0, 2.0, 4.0)
#: the sides, in pixels, of the square tiles the tiled oracles pick per
SELECTION_TILES = (8, 32)
SELECTIONS = ("best of σ×1, per pixel", "best of all, per pixel", *(f"best of all, per {t}×{t} tile"
                                                                    for t in SELECTION_TILES))


def exact_gradient(frame, previous) -> mi.Float:
    """λ of ``frame`` (a :class:`denoise.fit.PreparedFrame`) from its ground truth and ``previous``'s."""
    def demodulated_truth(f):
        truth = demodulate(f.reference, f.albedo) if f.albedo is not None else f.reference
        return dr.unravel(mi.Vector3f, truth.array)

    current = demodulated_truth(frame)
    before = dr.gather(mi.Vector3f, demodulated_truth(previous), frame.index, frame.valid)
    mean_now, _ = box_statistics(frame.buffers, to_ycocg(current), 1)
    mean_before, _ = box_statistics(frame.buffers, to_ycocg(before), 1)
    delta = dr.abs(mean_now.x - mean_before.x) / (dr.maximum(mean_now.x, mean_before.x) + GRADIENT_FLOOR)
    return dr.clip(ORACLE_GAIN * (delta - ORACLE_THRESHOLD), 0.0, 1.0)


def run_asvgf(frames, params: ASVGFParams, exact: bool) -> list[float]:
    """relMSE per frame of asvgf over ``frames``, λ estimated or exact."""
    history, errors = None, []
    for k, f in enumerate(frames):
        gradient = exact_gradient(f, frames[k - 1]) if exact and f.index is not None else None
        result, history = asvgf(f.buffers, params, history if f.index is not None else None, f.index, f.valid,
                                gradient=gradient)
        if f.albedo is not None:
            result = remodulate(result, f.albedo)
        errors.append(relmse(result.numpy(), f.reference.numpy()))
    return errors


def candidates(f, params: ASVGFParams, history: ASVGFHistory | None) -> dict[float, list[np.ndarray]]:
    """What asvgf can make of frame ``f`` (a :class:`denoise.fit.PreparedFrame`)
    from ``history``, by σ_luminance factor: the slow history, then every
    À-Trous level's output (the wide one too), remodulated, (H, W, 3) each."""
    result = {}
    for factor in SELECTION_SCALES:
        values = replace(FilterValues.of(params), sigma_luminance=params.sigma_luminance * factor)
        images = []
        asvgf(f.buffers, params, history if f.index is not None else None, f.index, f.valid, values, images=images)
        result[factor] = [(remodulate(i, f.albedo) if f.albedo is not None else i).numpy() for i in images]
    return result


def run_selection(frames, params: ASVGFParams) -> dict[str, list[float]]:
    """relMSE per frame of asvgf and of the oracles of :data:`SELECTIONS`."""
    history, errors = None, {name: [] for name in ("asvgf", *SELECTIONS)}
    for f in frames:
        images = candidates(f, params, history)
        result, history = asvgf(f.buffers, params, history if f.index is not None else None, f.index, f.valid)
        if f.albedo is not None:
            result = remodulate(result, f.albedo)
        reference = f.reference.numpy()
        at_one = relmse_per_pixel([*images[1.0], result.numpy()], reference)
        every = np.concatenate([at_one, relmse_per_pixel([i for k in SELECTION_SCALES if k != 1.0 for i in images[k]],
                                                     reference)])
        values = (float(at_one[-1].mean()), float(at_one.min(axis=0).mean()), float(every.min(axis=0).mean()),
                  *(least_error_per_tile(every, tile) for tile in SELECTION_TILES))
        for name, value in zip(errors, values, strict=True):
            errors[name].append(value)
    return errors


def run_baseline(folder: Path, frames) -> list[float]:
    method = from_name(BASELINE)
    return [relmse(method.step(read_frame(folder, i)), f.reference.numpy())
            for i, f in zip(frame_indices(folder), frames)]


def measure(folder: Path) -> dict[str, float]:
    """Mean relMSE over frames >= QUALITY_FROM of the baseline and each variant."""
    frames = prepare(folder)
    shipped = fitted()
    unclipped = replace(shipped, clip_width=NO_CLIP, fast_clip=NO_CLIP, slow_frames=LONG_HISTORY)
    per_frame = {BASELINE: run_baseline(folder, frames), "asvgf": run_asvgf(frames, shipped, False),
                 "asvgf, exact λ": run_asvgf(frames, shipped, True),
                 "asvgf, exact λ, no clip, long history": run_asvgf(frames, unclipped, True)}
    selection = run_selection(frames, shipped)
    per_frame.update({name: selection[name] for name in SELECTIONS})
    return {name: float(np.mean(values[QUALITY_FROM:])) for name, values in per_frame.items()}


def table(results: dict, base_name: str = BASELINE, columns: tuple[str, ...] = VARIANTS) -> str:
    """Mean relMSE of ``columns`` per sequence, with the ratio to ``base_name``'s."""
    rows = [f"| sequence | {base_name} | " + " | ".join(columns) + " |", "|---" * (2 + len(columns)) + "|"]
    for name, means in results["sequences"].items():
        base = means[base_name]
        rows.append(f"| {name} | {base:.4f} | " + " | ".join(
            f"{means[v]:.4f} ({means[v] / base:.2f}x)" for v in columns) + " |")
    return "\n".join(rows)


def selection_table(results: dict) -> str:
    """The oracles' table, with OIDN 2 high's ratio to asvgf's beside them."""
    return table(results, "asvgf", (*SELECTIONS, BASELINE))


def selection_section(results: dict) -> str:
    scales = ", ".join(f"{k:g}" for k in SELECTION_SCALES)
    return (f"Written by `{PROG} --docs` on {results['date']} ({results['machine']}): mean relMSE over frames "
            f">= {QUALITY_FROM} at 320x180 on the benchmark's frames and ground truth, and its ratio to asvgf's; "
            f"the oracles pick among asvgf's slow history, its output and every À-Trous level's output at "
            f"σ_luminance × {scales} (σ×1: the levels asvgf runs).\n\n" + selection_table(results))


def section(results: dict) -> str:
    return (f"Written by `{PROG} --docs` on {results['date']} ({results['machine']}): mean relMSE over frames "
            f">= {QUALITY_FROM} at 320x180 on the benchmark's frames and ground truth, and its ratio to "
            f"{BASELINE}'s (the bar is {ASVGF_RELMSE_BAR}x); exact λ: gain {ORACLE_GAIN:g}, threshold "
            f"{ORACLE_THRESHOLD:g} on the truth's 3x3 luminance change.\n\n" + table(results))


def folder_of(work: Path, name: str) -> Path:
    width, height = QUALITY["size"]
    folder = work / f"{name}_{width}x{height}_{REFERENCE_SPP.get(name, 1024)}spp"
    indices = frame_indices(folder) if folder.is_dir() else []
    if not indices or not all((reference_folder(folder) / f"beauty_{i}.exr").is_file() for i in indices):
        raise UsageError(f"{folder}: not rendered yet; run python -m benchmarks.denoise --work {work} first")
    return folder


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0],
                            formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--work", type=Path, default=Path("out/denoise"),
                        help="where python -m benchmarks.denoise rendered the sequences (out/denoise)")
    parser.add_argument("--sequences", nargs="*", metavar="NAME", help="only these sequences")
    parser.add_argument("--json", type=Path, metavar="PATH", help="write the numbers as JSON")
    parser.add_argument("--docs", action="store_true", help="write the table into docs/asvgf.md")
    args = parser.parse_args(argv)
    known = [p.stem for p in SEQUENCES]
    unknown = [name for name in args.sequences or [] if name not in known]
    if unknown:
        raise UsageError(f"--sequences: no sequence {unknown[0]!r}; choose from {', '.join(known)}")
    check_json(args.json)
    folders = {name: folder_of(args.work, name) for name in args.sequences or known}
    set_variant("llvm_ad_rgb", jit=True)
    results = {"date": datetime.date.today().isoformat(), "machine": machine(), "sequences": {}}
    for name, folder in folders.items():
        results["sequences"][name] = measure(folder)
    print(table(results))
    print(selection_table(results))
    if args.json:
        write_json(args.json, results)
    if args.docs:
        replace_section(PAGE, "asvgf-bounds", section(results))
        replace_section(PAGE, "asvgf-selection", selection_section(results))
    return 0


if __name__ == "__main__":
    entry.finish(entry.run(PROG, main))
