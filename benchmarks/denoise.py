"""Denoising quality, temporal stability and speed on our animated sequences, beside Intel Open Image Denoise.

    python -m benchmarks.denoise [--json PATH] [--quick] [--docs] [--work DIR]
                                 [--no-timing] [--timing-frames N]

Quality: each sequence of ``scenes/sequences/*.json`` is rendered once into
``--work`` at 320x180 (1-spp path-traced input; a ground truth of 1536 to 2048 spp, see
``REFERENCE_SPP``, made of two independently seeded halves; a rerun finds the
frames in ``WORK/NAME_320x180_<spp>spp`` and renders nothing). Every method runs over all 8 frames: ``raw`` (the input)
and each name the methods of :mod:`denoise.methods` are benchmarked under
(:func:`denoise.methods.benchmark_names`, e.g. ``atrous+temporal``; Intel
Open Image Denoise alone once per quality mode, ``oidn-fast``,
``oidn-balanced``, ``oidn-high``; docs/denoising_methods.md lists them).
Per frame: relMSE and FLIP against the ground truth, milliseconds, and
``temporal``: the relMSE between the output and the previous output
back-projected onto it.

The reference's own noise, relMSE(half_a, half_b) / 4 averaged over the
frames, is printed per sequence and must be at most 10 % of the best method's
mean relMSE, or the run fails (exit 1): a noisier ground truth cannot rank
the methods. Temporal stability per method is the mean of ``temporal`` over
the frames divided by the same figure for the ground truth (1 = as stable as
the truth).

Speed: one sequence rendered at 1280x720 (input only) and every method timed
per frame in the same run (llvm_ad_rgb, median after a warm-up frame), OIDN
by its execute call only (each quality mode's filter committed once for the
size); the ratios to ``oidn-high`` are the speed bars. The same
ratios of this process's CPU time (``cpu_ms``, ``cpu_ratio_to_oidn``) are
reported beside them: on a shared machine they move less with other jobs.

JSON: ``{"sequences": [{..., "reference_noise", "reference_temporal",
"stability": {method: figure}}], "results": [{"sequence", "method", "frame",
"relmse", "flip", "ms", "temporal"}], "timing": {...}}``.
"""
from __future__ import annotations

import argparse
import datetime
import os
import sys
import time
from pathlib import Path

# started as `python benchmarks/x.py`, this folder would shadow the course and denoise packages
if __name__ == "__main__" and not __package__:
    sys.path[0] = str(Path(__file__).resolve().parents[1])

if __name__ == "__main__":  # first: ./.venv's Python, the libLLVM, then Dr.Jit (see core.launcher)
    from core.launcher import start
    start("python -m benchmarks.denoise", "benchmarks.denoise" if __package__ else None)

import drjit as dr
import numpy as np

from benchmarks.denoise_front import front_points, write_front
from benchmarks.denoise_report import (
    BASELINE,
    HARD,
    OIDN_ALONE,
    STILL_METHODS,
    bar_lines,
    reference_checks,
    speed_lines,
    summary,
    write_results_page,
)
from benchmarks.records import check_json, machine, write_json
from core import entry
from core.entry import ArgumentParser
from core.errors import OutputError, UsageError
from core.inputs import check_outside
from denoise.methods import benchmark_names, check_method_names, from_name
from denoise.methods.oidn import oidn_version
from denoise.methods.user import add_method_file_option, load_method_files
from denoise.temporal_metrics import stability, temporal_relmse
from denoise.validate import render
from export import Spec, reference_folder
from export.frames import frame_indices, read_frame
from export.ground_truth import check_work_folder
from imaging.colour import side_by_side
from imaging.image_io import read_exr_rgb as read_rgb, write_image, write_video
from imaging.metrics import flip_error, relmse
from renderer.variants import set_variant

ROOT = Path(__file__).resolve().parent.parent
SEQUENCES = sorted((ROOT / "scenes" / "sequences").glob("*.json"))
METHODS = ("raw",) + benchmark_names()
#: each sequence at this size, over its own frames
QUALITY = dict(size=(320, 180))
#: ground-truth samples per pixel per sequence (two halves of half as many; the reference
#: noise falls as 1/spp, and docs/denoising_methods.md has the run these were chosen from);
#: --reference-spp overrides
REFERENCE_SPP = {"dolly_lamps": 2048, "orbit_transforms": 1536, "glossy_shadow": 2048, "moving_lamp": 2048,
                 "light_switch": 2048, "long_orbit": 2048}
QUICK = dict(size=(96, 54), reference_spp=16)
#: the quick run's frames per sequence (more where a light changes later: see quick_frames)
QUICK_FRAMES = 4
#: a method has responded to a sudden change once its relMSE stays within this factor of its value before
RESPONSE_FACTOR = 1.5
TIMING = dict(size=(1280, 720), frames=9, reference_spp=2)
QUICK_TIMING = dict(size=(160, 90), frames=3, reference_spp=2)
#: per-frame time at most this fraction of another's (OIDN by its execute time): the speed bars
#: of the filters and of the learned methods against OIDN 2 fast, and the assignment's against high
SPEED_BARS = (("atrous+temporal", "oidn-fast", 0.15), ("svgf", "oidn-fast", 0.15), ("asvgf", "oidn-fast", 0.3),
              ("learned-asvgf", "oidn-fast", 1.0), ("learned-mixture", "oidn-fast", 1.0), ("bilateral", BASELINE, 2.0))
#: every method is timed (the error-against-time front), OIDN's modes first
TIMED = OIDN_ALONE + tuple(m for m in METHODS if m not in OIDN_ALONE and m != "raw")


def timing_folder(work: Path, sequence: str, settings: dict, quick: bool = False) -> Path:
    """Where the speed run's frames of ``sequence`` are rendered and cached."""
    width, height = settings["size"]
    return work / f"timing_{sequence}_{width}x{height}_{settings['frames']}f{'_quick' if quick else ''}"


class RawMethod:
    last_execute_s = None

    def step(self, frame) -> np.ndarray:
        return frame.beauty


def make_method(name: str):
    return RawMethod() if name == "raw" else from_name(name)


def reference_noise(reference: Path, indices) -> list[float]:
    """Per frame: relMSE(half_a, half_b) / 4, the full reference's own relMSE."""
    return [relmse(read_rgb(reference / f"half_a_{i}.exr"), read_rgb(reference / f"half_b_{i}.exr")) / 4
            for i in indices]


def warm_up(method: str, frames) -> None:
    """Runs ``method`` on two frames, so that the kernels of a first frame and
    of one with history are compiled and cached before anything is timed."""
    runner = make_method(method)
    for frame in frames[:2]:
        runner.step(frame)


def run_sequence(folder: Path, name: str, methods=METHODS, outputs: dict | None = None) -> tuple[list[dict], dict]:
    """(per-frame rows, the sequence's reference figures and stability per method)."""
    indices = frame_indices(folder)
    frames = [read_frame(folder, i) for i in indices]
    truth = [read_rgb(reference_folder(folder) / f"beauty_{i}.exr") for i in indices]
    reference_temporal = temporal_relmse(frames, truth)
    figures = {"reference_noise": float(np.mean(reference_noise(reference_folder(folder), indices))),
               "reference_temporal": float(np.mean(reference_temporal)), "stability": {}}
    rows = []
    for method in methods:
        warm_up(method, frames)
        runner = make_method(method)
        results = []
        for index, (frame, reference) in enumerate(zip(frames, truth)):
            start = time.perf_counter()
            result = runner.step(frame)
            dr.sync_thread()
            ms = 1000 * (time.perf_counter() - start)
            results.append(result)
            rows.append({"sequence": name, "method": method, "frame": index, "relmse": relmse(result, reference),
                         "flip": flip_error(result, reference), "ms": ms, "temporal": None})
        flicker = temporal_relmse(frames, results)
        for row, value in zip(rows[-len(frames) + 1:], flicker):
            row["temporal"] = value
        figures["stability"][method] = stability(flicker, reference_temporal)
        if outputs is not None:
            outputs[method] = results
    if outputs is not None:
        outputs["reference"] = truth
    return rows, figures


def run_timing(folder: Path, methods=TIMED) -> dict:
    """Per-frame milliseconds (median after a warm-up frame) of every method
    on ``folder``'s frames, OIDN by its execute call alone. The methods take
    turns frame by frame (round robin), so that a slow spell of a shared
    machine falls on all of them alike instead of on whichever ran then."""
    frames = [read_frame(folder, i) for i in frame_indices(folder)]
    timing = {"size": [frames[0].beauty.shape[1], frames[0].beauty.shape[0]], "frames": len(frames), "ms": {},
              "order": "round robin: frame by frame, each method in turn"}
    methods = [m for m in methods if m != "raw"]
    runners = {}
    for method in methods:
        warm_up(method, frames)
        runners[method] = make_method(method)
        runners[method].step(frames[0])  # its filter committed (OIDN); its history started
    times = {m: [] for m in methods}
    cpu_times = {m: [] for m in methods}
    for frame in frames[1:]:
        for method, runner in runners.items():
            start, cpu = time.perf_counter(), time.process_time()
            runner.step(frame)
            dr.sync_thread()
            elapsed, cpu_elapsed = time.perf_counter() - start, time.process_time() - cpu
            execute = runner.last_execute_s is not None  # OIDN: its execute calls alone
            times[method].append(runner.last_execute_s if execute else elapsed)
            cpu_times[method].append(runner.last_execute_cpu_s if execute else cpu_elapsed)
    for method in methods:
        timing["ms"][method] = 1000 * float(np.median(times[method]))
        timing.setdefault("cpu_ms", {})[method] = 1000 * float(np.median(cpu_times[method]))
    if BASELINE in timing["ms"]:  # --methods may leave it out: then the bars' own bases alone
        timing["baseline"] = BASELINE
        timing["ratio_to_oidn"] = {m: ms / timing["ms"][BASELINE] for m, ms in timing["ms"].items()}
        # this process's CPU time (all its threads): what other jobs on the machine inflate least
        timing["cpu_ratio_to_oidn"] = {m: ms / timing["cpu_ms"][BASELINE] for m, ms in timing["cpu_ms"].items()}
    timing["bars"] = {f"{m} / {base}": {"ratio": timing["ms"][m] / timing["ms"][base], "bar": bar,
                                        "met": timing["ms"][m] / timing["ms"][base] <= bar}
                      for m, base, bar in SPEED_BARS if m in timing["ms"] and base in timing["ms"]}
    # a bar whose method ran without its base (--methods): said, not passed over
    timing["bars_not_checked"] = [f"{m} / {base} (no {base} in this run)" for m, base, _ in SPEED_BARS
                                  if m in timing["ms"] and base not in timing["ms"]]
    return timing


def sudden_change(spec) -> tuple[int, int] | None:
    """``(a, b)`` of the spec's light change over one frame (``"frames": [a, b]`` with
    ``b = a + 1``): frame ``a`` is the last before it, ``b`` the first after; None without one."""
    windows = [tuple(change["frames"]) for change in spec.lights.values() if "frames" in change]
    windows = [(a, b) for a, b in windows if b == a + 1]
    return min(windows) if windows else None


def quick_frames(spec) -> int:
    """The quick run's frames of ``spec``: :data:`QUICK_FRAMES`, or two past a sudden change."""
    switch = sudden_change(spec)
    return min(spec.frames, max(QUICK_FRAMES, switch[1] + 2 if switch else 0))


def response(rows: list[dict], method: str, switch: tuple[int, int]) -> int | None:
    """Frames after a sudden change until ``method``'s relMSE is back, to stay, within
    :data:`RESPONSE_FACTOR` times its value on the last frame before (0: at once);
    None if it is not back by the last frame."""
    before, after = switch
    values = {r["frame"]: r["relmse"] for r in rows if r["method"] == method}
    bound = RESPONSE_FACTOR * values[before]
    late = [frame for frame in sorted(values) if frame >= after and values[frame] > bound]
    if not late:
        return 0
    if late[-1] == max(values):
        return None
    return late[-1] + 1 - after


PROG = "python -m benchmarks.denoise"


def check_work_and_json(work: Path, json_path: Path | None, folders: list[Path] = ()) -> None:
    """The cache folder and the JSON file, checked before hours of rendering:
    the JSON is named .json and lies outside the sequences' ``folders`` it reads."""
    if work.exists() and not work.is_dir():
        raise OutputError(f"--work {work}: a file, not a folder")
    check_work_folder(work)
    if json_path is not None and not json_path.is_dir() and json_path.suffix.lower() != ".json":
        raise UsageError(f"--json writes JSON: name it .json, got {json_path}")
    for folder in folders:
        name = folder.name.removeprefix("timing_")
        check_outside({"--json": json_path}, {f"frame folder (--work) of {name}": folder,
                                              f"ground truth (--work) of {name}": reference_folder(folder)})
    work.mkdir(parents=True, exist_ok=True)  # an OSError names the path (one line under core.entry.run)
    check_json(json_path)


def checked_methods(names: list[str], docs: bool) -> tuple[str, ...]:
    """``--methods``: known names, each once, and not for the results page (which has every method)."""
    if docs:
        raise UsageError("--methods: --docs writes the page of every method; leave one of them out")
    check_method_names("--methods", names, {"raw": "the noisy input"})
    return tuple(names)


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0],
                            formatter_class=argparse.RawDescriptionHelpFormatter,
                            epilog="example: python -m benchmarks.denoise --json out/denoise.json")
    parser.add_argument("--json", type=Path, metavar="PATH", help="write every number as JSON")
    parser.add_argument("--quick", action="store_true", help="small frames and a noisy reference (CI; the "
                        "reference check is reported, not enforced)")
    parser.add_argument("--work", type=Path, default=Path("out/denoise"),
                        help="where the sequences are rendered and cached (default out/denoise)")
    parser.add_argument("--docs", "--readme", action="store_true",
                        help="write docs/denoise/ (JSON, still, video) and the results in docs/results/denoise.md "
                             "(--readme: its former name)")
    parser.add_argument("--no-timing", action="store_true", help="skip the 1280x720 speed run")
    parser.add_argument("--sequences", nargs="+", metavar="NAME", help="only these sequences")
    parser.add_argument("--methods", nargs="+", metavar="NAME",
                        help="only these methods (raw and the names of python -m denoise --method), e.g. a method "
                             "of one's own from --method-file; not with --docs")
    add_method_file_option(parser)
    parser.add_argument("--reference-spp", type=int, metavar="N",
                        help="ground-truth spp for every sequence, even (default: " +
                             ", ".join(f"{k} {v}" for k, v in REFERENCE_SPP.items()) + ")")
    load_method_files(argv)  # before parsing: --methods may name a method of one's own
    args = parser.parse_args(argv)
    methods = METHODS if args.methods is None else checked_methods(args.methods, args.docs)
    known = [p.stem for p in SEQUENCES]
    unknown = [name for name in args.sequences or [] if name not in known]
    if unknown:
        raise UsageError(f"--sequences: no sequence {unknown[0]!r}; choose from {', '.join(known)}")
    if args.reference_spp is not None and (args.reference_spp < 2 or args.reference_spp % 2):
        raise UsageError(f"--reference-spp must be an even number >= 2 (two independently seeded halves), "
                         f"got {args.reference_spp}")
    docs = ROOT / "docs" / "denoise"
    if args.docs:
        args.json = args.json or docs / "denoise.json"
    quality, timing_size = (QUICK, QUICK_TIMING) if args.quick else (QUALITY, TIMING)
    suffix = "_quick" if args.quick else ""
    planned = []  # (spec file, spec, folder): every spec read and every folder named before any work
    for spec_path in SEQUENCES:
        if args.sequences and spec_path.stem not in args.sequences:
            continue
        settings = dict(quality)
        if args.quick:
            settings["frames"] = quick_frames(Spec.load(spec_path))
        if args.reference_spp is not None:
            settings["reference_spp"] = args.reference_spp
        elif not args.quick:
            settings["reference_spp"] = REFERENCE_SPP.get(spec_path.stem, 1024)
        spec = Spec.load(spec_path, **settings)
        # the folder names its settings: other settings render beside it, never into it
        folder = args.work / f"{spec_path.stem}_{spec.size[0]}x{spec.size[1]}_{spec.reference_spp}spp{suffix}"
        planned.append((spec_path, spec, folder))
    timed = None if args.no_timing else timing_folder(args.work, SEQUENCES[0].stem, timing_size, args.quick)
    check_work_and_json(args.work, args.json, [f for _, _, f in planned] + ([timed] if timed else []))
    set_variant(None, jit=True)
    start = time.perf_counter()
    results = {"date": datetime.date.today().isoformat(), "machine": machine(),
               "load_average_at_start": round(os.getloadavg()[0], 2),
               "oidn": f"OIDN {oidn_version()} through pyoidn: hdr on, albedo and normal with cleanAux, "
                       "one filter per quality mode committed once per size", "sequences": [], "results": []}
    # every sequence and the speed frames in one export: on one Dask worker per core (each render
    # is single-threaded so that bytes do not depend on thread counts); the quick CI size in-process
    timing_spec = [] if timed is None else [(Spec.load(SEQUENCES[0], **timing_size), timed)]
    render([(spec, folder) for _, spec, folder in planned] + timing_spec,
           **({} if args.quick else {"workers": os.cpu_count() or 1}))
    outputs_hard = None
    for spec_path, spec, folder in planned:
        outputs = {} if spec_path.stem == HARD else None
        rows, figures = run_sequence(folder, spec_path.stem, methods, outputs=outputs)
        if outputs is not None:
            outputs_hard = outputs
        switch = sudden_change(spec)
        if switch is not None:
            figures["switch"] = list(switch)
            figures["response"] = {m: response(rows, m, switch) for m in dict.fromkeys(r["method"] for r in rows)}
        results["sequences"].append({"name": spec_path.stem, "spec": str(spec_path.relative_to(ROOT)),
                                     "size": list(spec.size), "frames": spec.frames, "spp": spec.spp,
                                     "reference_spp": spec.reference_spp, **figures})
        results["results"] += rows
        print(f"{spec_path.stem}: reference noise {figures['reference_noise']:.2e}", file=sys.stderr)
    if not args.no_timing:
        spec_path, folder = SEQUENCES[0], timed
        results["timing"] = {"sequence": spec_path.stem,
                             **run_timing(folder, TIMED if args.methods is None else methods)}
    results.update(load_average_at_end=round(os.getloadavg()[0], 2), wall_s=round(time.perf_counter() - start, 1))
    print(summary(results))
    checks = reference_checks(results)
    # the quality bars compare every method; the speed bars those of theirs that ran
    for line in checks + (bar_lines(results) if args.methods is None else speed_lines(results)):
        print(line)
    if args.json:
        write_json(args.json, results)
    if args.docs:
        still = video = None
        if outputs_hard is not None:
            panels = [outputs_hard[m] for m in STILL_METHODS] + [outputs_hard["reference"]]
            still, video = docs / f"{HARD}_last.png", docs / f"{HARD}.mp4"
            write_image(still, side_by_side([p[-1] for p in panels]))
            write_video(video, [side_by_side(list(images)) for images in zip(*panels)])
        front = write_front(results, docs / "front.png") if front_points(results).get("all") else None
        write_results_page(results, still, video, front, "python -m benchmarks.denoise --docs")
    failed = [line for line in checks if line.startswith("FAIL")]
    if failed and not args.quick:
        print("benchmarks.denoise: error: the ground truth is too noisy to rank the methods (see FAIL above)",
              file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    entry.finish(entry.run(PROG, main))
