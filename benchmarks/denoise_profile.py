"""Where a denoised frame's time goes: every Dr.Jit kernel of a frame of the
timed methods at 1280x720, with its execution time and the bytes it moves.

    python -m benchmarks.denoise_profile [--work DIR] [--frames N] [--json PATH] [--docs]

Runs ``atrous+temporal`` and ``svgf`` (llvm_ad_rgb) over the speed run's
frames (``benchmarks.denoise``'s 1280x720 folder, rendered if missing), with
Dr.Jit's kernel history on. Per kernel, in launch order: its size, its
operation count, what its IR reads per pixel (packet gathers of 4- and
8-float records, single-float gathers, plain loads) and writes, and its
execution time, the median over the frames after two warm-up frames.
Kernels with at least 24 gathers of 4-float colour records and 24 of 8-float
guide records, or 216 shifted loads (3 colour and 6 guide planes per tap,
:mod:`denoise.neighbours`), are the À-Trous levels (5x5 taps, the centre read
without either); the table sums them apart from the rest (guide packing, SVGF's
spatial variance estimate, reprojection, accumulation and clamping).

Last, ``atrous+temporal``'s kernel time with one Dr.Jit thread against the
default count (how far the second core helps).

``--docs`` writes docs/denoise/profile.json and section ``denoise-profile``
of docs/results/denoise.md (``core.markdown.replace_section``).
"""
from __future__ import annotations

import datetime
import os
import sys
from pathlib import Path

# started as `python benchmarks/x.py`, this folder would shadow the course and denoise packages
if __name__ == "__main__" and not __package__:
    sys.path[0] = str(Path(__file__).resolve().parents[1])

if __name__ == "__main__":  # first: ./.venv's Python, the libLLVM, then Dr.Jit (see core.launcher)
    from core.launcher import start
    start("python -m benchmarks.denoise_profile", "benchmarks.denoise_profile" if __package__ else None)

import drjit as dr

from benchmarks.denoise import QUICK_TIMING, SEQUENCES, TIMING, check_work_and_json, timing_folder
from benchmarks.denoise_report import RESULTS_PAGE
from benchmarks.kernel_profile import profile
from benchmarks.records import machine, write_json
from core import entry
from core.entry import ArgumentParser
from core.markdown import replace_section
from denoise.validate import render
from export import Spec
from export.frames import frame_indices, read_frame
from renderer.variants import set_variant

ROOT = Path(__file__).resolve().parent.parent
PROG = "python -m benchmarks.denoise_profile"
METHODS = ("atrous+temporal", "svgf")
def thread_scaling(frames, method: str = "atrous+temporal") -> dict:
    """Kernel time per frame of ``method`` with one Dr.Jit thread and with the default count."""
    default = dr.thread_count()
    try:
        dr.set_thread_count(1)
        one = profile(frames, method)["kernels_ms"]
    finally:
        dr.set_thread_count(default)
    return {"method": method, "threads": default, "kernels_ms_one_thread": one,
            "kernels_ms": profile(frames, method)["kernels_ms"]}


def table(results: dict) -> str:
    lines = []
    for p in results["methods"]:
        lines += [f"`{p['method']}`, one frame: wall {p['wall_ms']:.0f} ms, kernels {p['kernels_ms']:.0f} ms, of "
                  f"which À-Trous levels {p['levels_ms']:.0f} ms ({100 * p['levels_ms'] / p['kernels_ms']:.0f} %); "
                  f"median of {p['frames']} frames:", "",
                  "| kernel | pixels | operations | packet gathers per pixel | bytes read / written per pixel "
                  "| ms (min–max) |",
                  "|---|---|---|---|---|---|"]
        for k in p["kernels"]:
            gathers = ", ".join(f"{c}x{n}" for n, c in k["packet_gathers"].items()) or "-"
            if k["single_gathers"]:
                gathers += f"; {k['single_gathers']} single"
            if k["shifted_loads"]:
                gathers += f"; {k['shifted_loads']} shifted loads"
            name = f"{k['kernel']}" + (" (À-Trous level)" if k["level"] else "" if k["type"] == "JIT"
                                       else f" ({k['type']})")
            lines.append(f"| {name} | {k['size']} | {k['operations']} | {gathers} | "
                         f"{k['bytes_read_per_pixel']} / {k['bytes_written_per_pixel']} | {k['ms']:.1f} "
                         f"({k['ms_min']:.1f}–{k['ms_max']:.1f}) |")
        lines.append("")
    t = results.get("threads")
    if t:
        lines += [f"`{t['method']}` kernels with one Dr.Jit thread {t['kernels_ms_one_thread']:.0f} ms, with "
                  f"{t['threads']} {t['kernels_ms']:.0f} ms ({t['kernels_ms_one_thread'] / t['kernels_ms']:.2f}x).", ""]
    return "\n".join(lines)


def write_results_page(results: dict, command: str) -> None:
    """Section ``denoise-profile`` of benchmarks.denoise's results page."""
    m = results["machine"]
    head = (f"Written by `{command}` on {results['date']} ({m}; load average "
            f"{results['load_average_at_start']} at the start):\n\n")
    replace_section(RESULTS_PAGE, "denoise-profile", head + table(results))


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    parser.add_argument("--work", type=Path, default=Path("out/denoise"),
                        help="where the speed run's frames are (rendered there if missing; default out/denoise)")
    parser.add_argument("--json", type=Path, metavar="PATH", help="write the profile as JSON")
    parser.add_argument("--docs", "--readme", action="store_true",
                        help="write docs/denoise/profile.json and its section of docs/results/denoise.md "
                             "(--readme: its former name)")
    parser.add_argument("--quick", action="store_true", help="the small speed frames of benchmarks.denoise --quick")
    args = parser.parse_args(argv)
    if args.docs:
        args.json = args.json or ROOT / "docs" / "denoise" / "profile.json"
    check_work_and_json(args.work, args.json)
    set_variant(None, jit=True)  # it reads Dr.Jit's kernel history
    size = QUICK_TIMING if args.quick else TIMING
    folder = timing_folder(args.work, SEQUENCES[0].stem, size, args.quick)
    render([(Spec.load(SEQUENCES[0], **size), folder)])
    frames = [read_frame(folder, i) for i in frame_indices(folder)]
    results = {"date": datetime.date.today().isoformat(), "machine": machine(),
               "load_average_at_start": round(os.getloadavg()[0], 2),
               "size": [frames[0].beauty.shape[1], frames[0].beauty.shape[0]],
               "methods": [profile(frames, method) for method in METHODS], "threads": thread_scaling(frames)}
    print(table(results))
    if args.json:
        write_json(args.json, results)
    if args.docs:
        write_results_page(results, "python -m benchmarks.denoise_profile --docs")
    return 0


if __name__ == "__main__":
    entry.finish(entry.run(PROG, main))
