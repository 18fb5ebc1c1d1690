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
``--docs`` writes the table into docs/asvgf.md (section ``asvgf-bounds``).
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
from denoise.methods.asvgf import GRADIENT_FLOOR, ASVGFParams, asvgf, box_statistics, fitted, to_ycocg
from denoise.temporal_metrics import QUALITY_FROM
from export import reference_folder
from export.frames import frame_indices, read_frame
from imaging.metrics import relmse
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
    return {name: float(np.mean(values[QUALITY_FROM:])) for name, values in per_frame.items()}


def table(results: dict) -> str:
    rows = ["| sequence | " + BASELINE + " | " + " | ".join(VARIANTS) + " |", "|---" * (2 + len(VARIANTS)) + "|"]
    for name, means in results["sequences"].items():
        base = means[BASELINE]
        rows.append(f"| {name} | {base:.4f} | " + " | ".join(
            f"{means[v]:.4f} ({means[v] / base:.2f}x)" for v in VARIANTS) + " |")
    return "\n".join(rows)


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
    if args.json:
        write_json(args.json, results)
    if args.docs:
        replace_section(PAGE, "asvgf-bounds", section(results))
    return 0


if __name__ == "__main__":
    entry.finish(entry.run(PROG, main))
