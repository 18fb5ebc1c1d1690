"""A roofline for this machine from Dr.Jit, and every denoising kernel against it.

    python -m benchmarks.roofline [--work DIR] [--json PATH] [--docs] [--quick]

Microbenchmarks (llvm_ad_rgb, each kernel timed from Dr.Jit's kernel history,
the least of ``REPEATS`` launches):

- **packet gathers**: ``dr.gather`` of records of 1, 2, 4 and 8 floats (and 4
  and 8 halves, ``Float16``) from a table in cache (``IN_CACHE`` bytes) and
  out of cache (``OUT_OF_CACHE`` bytes, above the last-level cache), with
  stride-1 indices (lane ``i`` reads record ``i + offset``) and random ones
  (a hash of the lane); ``GATHERS_PER_LANE`` gathers per lane, summed, one
  float written. Nanoseconds per gathered record per lane, all threads.
- **streaming copy**: ``dst = src + 1`` over ``OUT_OF_CACHE`` bytes: bytes read
  and written per second (memory bandwidth).
- **operations**: ``OP_CHAINS`` independent chains of fma and add per lane,
  ``OP_STEPS`` long: nanoseconds per IR operation per lane (Dr.Jit's
  ``operation_count``). Not a hard roof: a kernel's integer, compare and
  select operations may issue beside its floating-point ones, and a division,
  a square root or ``dr.maximum`` (``llvm.maximum``) costs several.

Then every kernel of a frame of ``atrous+temporal``, ``svgf`` and ``asvgf``
at 1280x720 (``benchmarks.denoise``'s speed frames, rendered if missing;
``benchmarks.kernel_profile``): its gathers, bytes and operations per pixel
from its IR, its measured time, and three lower bounds: the gathers at the
in-cache stride-1 rate of their record size, its distinct bytes (each array
read once, see :func:`benchmarks.kernel_profile.ir_traffic`) at the copy's
bandwidth, and its operations at the measured rate. The bound is the largest;
the table gives the resource that sets it and measured / bound.

``--docs`` writes docs/denoise/roofline.json and section ``roofline`` of
docs/results/roofline.md (``core.markdown.replace_section``).
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
    start("python -m benchmarks.roofline", "benchmarks.roofline" if __package__ else None)

import drjit as dr
import mitsuba as mi

from benchmarks.denoise import QUICK_TIMING, SEQUENCES, TIMING, check_work_and_json, timing_folder
from benchmarks.kernel_profile import ir_text, profile, record_name
from benchmarks.records import machine, write_json
from core import entry
from core.entry import ArgumentParser
from core.markdown import replace_section
from denoise import neighbours
from denoise.validate import render
from export import Spec
from export.frames import frame_indices, read_frame
from renderer.variants import set_variant

ROOT = Path(__file__).resolve().parent.parent
PROG = "python -m benchmarks.roofline"
PAGE = ROOT / "docs" / "results" / "roofline.md"
METHODS = ("atrous+temporal", "svgf", "asvgf")
#: table sizes: well inside the 2nd-level cache, and far above the last-level cache
IN_CACHE, OUT_OF_CACHE = 256 << 10, 256 << 20
#: record lengths timed, (elements, bytes per element)
RECORDS = ((1, 4), (2, 4), (4, 4), (8, 4), (4, 2), (8, 2))
PATTERNS = ("stride-1", "random")
GATHERS_PER_LANE = 8
#: lanes of an in-cache gather kernel (indices wrap around the table)
IN_CACHE_LANES = 1 << 22
OP_CHAINS, OP_STEPS = 8, 64
REPEATS = 7
#: --quick: smaller kernels, fewer launches (for the test of the page's shape)
QUICK = {"out_of_cache": 16 << 20, "in_cache_lanes": 1 << 16, "repeats": 2}


def timed(make, repeats: int) -> tuple[float, dict]:
    """(least ms, the history entry of the last launch) of the one kernel that
    evaluating ``make()`` launches; ``make`` builds the computation afresh each
    time. The least of ``repeats`` launches after a first one (compilation,
    the output's first touch): a roof is what the machine reaches, and other
    jobs on a shared machine only ever slow a launch down."""
    times, last, value = [], None, None
    for _ in range(repeats + 1):
        value = None  # the last output freed first: its memory is the next one's, already touched
        value = make()
        dr.sync_thread()
        dr.kernel_history()
        dr.eval(value)
        dr.sync_thread()
        kernels = [k for k in dr.kernel_history() if k.get("execution_time") is not None and k.get("ir")]
        if len(kernels) != 1:
            raise RuntimeError(f"a microbenchmark launched {len(kernels)} kernels, not 1")
        last = kernels[0]
        times.append(last["execution_time"])
    return float(min(times[1:])), last


def table_of(records: int, floats: int, element_bytes: int):
    """An evaluated flat table of ``records`` records of ``floats`` elements."""
    values = dr.arange(mi.Float, records * floats) * (1.0 / (records * floats))
    table = mi.Float16(values) if element_bytes == 2 else values
    dr.eval(table)
    return table


def lane_indices(lane: mi.UInt32, g: int, records: int, lanes: int, pattern: str) -> mi.UInt32:
    """Record ``g`` of lane ``lane``: stride-1 (each gather its own stretch of
    the table, never the same record: Dr.Jit would merge equal gathers) or a
    hash of the lane (murmur3's finaliser)."""
    if pattern == "stride-1":
        return (lane + g * (records // GATHERS_PER_LANE)) & (records - 1)
    h = lane ^ mi.UInt32((0x9E3779B9 * (g + 1)) & 0xFFFFFFFF)
    h = (h ^ (h >> 16)) * 0x85EBCA6B
    h = (h ^ (h >> 13)) * 0xC2B2AE35
    return (h ^ (h >> 16)) & (records - 1)


def gather_rate(floats: int, element_bytes: int, table_bytes: int, pattern: str, lanes: int | None,
                repeats: int) -> dict:
    """ns per gathered record per lane; ``lanes`` None: as many as read the table once."""
    records = table_bytes // (floats * element_bytes)
    lanes = lanes or records // GATHERS_PER_LANE
    table = table_of(records, floats, element_bytes)
    kind = mi.ArrayXf16 if element_bytes == 2 else mi.ArrayXf

    def make():
        lane = dr.arange(mi.UInt32, lanes)
        total = mi.Float(0.0)
        for g in range(GATHERS_PER_LANE):
            index = lane_indices(lane, g, records, lanes, pattern)
            if floats == 1:
                total += mi.Float(dr.gather(type(table), table, index))
            else:
                record = dr.gather(kind, table, index, shape=(floats, lanes))
                total += sum(mi.Float(record[k]) for k in range(floats))
        return total

    ms, kernel = timed(make, repeats)
    per = 1e6 * ms / (lanes * GATHERS_PER_LANE)
    return {"record": record_name(floats, element_bytes), "bytes": floats * element_bytes,
            "table_bytes": table_bytes, "pattern": pattern, "lanes": lanes, "ns_per_gather": per,
            "gb_per_s": floats * element_bytes / per, "packet": "@gather_" in ir_text(kernel)}


def copy_bandwidth(table_bytes: int, repeats: int) -> dict:
    """Bytes read and written per second by ``dst = src + 1`` over ``table_bytes``."""
    source = table_of(table_bytes // 4, 1, 4)
    ms, _ = timed(lambda: source + 1.0, repeats)
    return {"table_bytes": table_bytes, "ms": ms, "gb_per_s": 2 * table_bytes / (1e6 * ms)}


def op_rate(lanes: int, repeats: int) -> dict:
    """ns per IR operation per lane: ``OP_CHAINS`` independent chains of
    ``a = fma(a, s, t)`` and ``b = b + s`` (the multiply-add and add pipes both busy)."""
    def make():
        lane = mi.Float(dr.arange(mi.UInt32, lanes))
        s, t = 0.5 + lane * 1e-9, 0.25 + lane * 1e-9  # lane values: nothing to fold
        chains = [(s + k, t + k) for k in range(OP_CHAINS)]
        for _ in range(OP_STEPS):
            chains = [(dr.fma(a, s, t), b + s) for a, b in chains]
        return sum(a + b for a, b in chains)

    ms, kernel = timed(make, repeats)
    ops = int(kernel.get("operation_count", 0))
    return {"lanes": lanes, "operations": ops, "ms": ms, "ns_per_op": 1e6 * ms / (lanes * ops)}


def microbenchmarks(quick: bool) -> dict:
    out_of_cache = QUICK["out_of_cache"] if quick else OUT_OF_CACHE
    lanes = QUICK["in_cache_lanes"] if quick else IN_CACHE_LANES
    repeats = QUICK["repeats"] if quick else REPEATS
    gathers = [gather_rate(n, size, table, pattern, lanes if table == IN_CACHE else None, repeats)
               for n, size in RECORDS for table in (IN_CACHE, out_of_cache) for pattern in PATTERNS]
    return {"gathers": gathers, "copy": copy_bandwidth(out_of_cache, repeats), "ops": op_rate(lanes, repeats)}


def gather_ns(micro: dict, record: str) -> float:
    """The roof of one gather of ``record``: its in-cache stride-1 rate."""
    return next(g["ns_per_gather"] for g in micro["gathers"]
                if g["record"] == record and g["table_bytes"] == IN_CACHE and g["pattern"] == "stride-1")


def bound(kernel: dict, micro: dict) -> dict:
    """A kernel's three lower bounds (ms), the largest and measured / largest."""
    pixels = kernel["size"]
    gathers = sum(c * gather_ns(micro, record) for record, c in kernel["packet_gathers"].items())
    gathers += kernel["single_gathers"] * gather_ns(micro, record_name(1))
    times = {"gathers": 1e-6 * pixels * gathers,
             "bandwidth": pixels * kernel["distinct_bytes_per_pixel"] / (1e6 * micro["copy"]["gb_per_s"]),
             "operations": 1e-6 * pixels * kernel["operations"] * micro["ops"]["ns_per_op"]}
    binds = max(times, key=times.get)
    return {"bound_ms": times, "binds": binds,
            "ratio": kernel["ms"] / times[binds] if times[binds] > 0 else None}


def micro_table(micro: dict, quick: bool) -> list[str]:
    out_of_cache = QUICK["out_of_cache"] if quick else OUT_OF_CACHE
    lines = ["| record | bytes | in cache, stride-1 | in cache, random | out of cache, stride-1 | "
             "out of cache, random |", "|---|---|---|---|---|---|"]
    for n, size in RECORDS:
        name = record_name(n, size)
        cells = []
        for table in (IN_CACHE, out_of_cache):
            for pattern in PATTERNS:
                g = next(g for g in micro["gathers"]
                         if g["record"] == name and g["table_bytes"] == table and g["pattern"] == pattern)
                cells.append(f"{g['ns_per_gather']:.3f} ns ({g['gb_per_s']:.1f} GB/s)")
        lines.append(f"| {name} | {n * size} | " + " | ".join(cells) + " |")
    c, o = micro["copy"], micro["ops"]
    return lines + ["", f"Streaming copy over {c['table_bytes'] >> 20} MiB: {c['gb_per_s']:.1f} GB/s read + "
                    f"written. Operations: {o['ns_per_op'] * 1000:.1f} ps per IR operation per pixel "
                    f"({OP_CHAINS} independent chains of fma and add, {o['operations']} operations per lane)."]


def kernel_table(p: dict, levels_only: bool = False) -> list[str]:
    lines = [f"`{p['method']}`{', neighbour reads gathered' if levels_only else ''}, one frame: kernels "
             f"{p['kernels_ms']:.0f} ms, À-Trous levels {p['levels_ms']:.0f} ms; median of {p['frames']} frames"
             f"{' (its À-Trous levels)' if levels_only else ''}:", "",
             "| kernel | packet gathers per pixel | bytes gathered+loaded / distinct per pixel | operations "
             "| ms | bound ms: gathers / bandwidth / operations | binds | measured / bound |",
             "|---|---|---|---|---|---|---|---|"]
    for k in p["kernels"]:
        if k["type"] != "JIT" or (levels_only and not k["level"]):
            continue
        gathers = ", ".join(f"{c}x{n}" for n, c in k["packet_gathers"].items()) or "-"
        if k["single_gathers"]:
            gathers += f"; {k['single_gathers']} single"
        if k["shifted_loads"]:
            gathers += f"; {k['shifted_loads']} shifted loads"
        b = k["bound_ms"]
        ratio = f"{k['ratio']:.1f}" if k["ratio"] is not None else "-"
        lines.append(f"| {k['kernel']}{' (À-Trous level)' if k['level'] else ''} | {gathers} | "
                     f"{k['bytes_read_per_pixel']} / {k['distinct_bytes_per_pixel']} | {k['operations']} | "
                     f"{k['ms']:.1f} | {b['gathers']:.1f} / {b['bandwidth']:.1f} / {b['operations']:.1f} | "
                     f"{k['binds']} | {ratio} |")
    return lines + [""]


def levels_summary(p: dict, how: str) -> str:
    levels = [k for k in p["kernels"] if k["level"]]
    if not levels:
        return f"- `{p['method']}`, {how}: no À-Trous level found."
    binds = sorted({k["binds"] for k in levels})
    ratios = [k["ratio"] for k in levels]
    second = [sorted(k["bound_ms"].values())[-2] / k["bound_ms"][k["binds"]] for k in levels]
    return (f"- `{p['method']}`, {how}: its {len(levels)} À-Trous levels take {p['levels_ms']:.0f} ms, bound by "
            f"{' and '.join(binds)}; each takes {min(ratios):.1f}-{max(ratios):.1f}x that bound (the next "
            f"resource's bound is {min(second):.2f}-{max(second):.2f} of it).")


def page(results: dict, command: str) -> str:
    m = results["machine"]
    lines = [f"Written by `{command}` on {results['date']} ({m}; load average {results['load_average_at_start']} "
             f"at the start, {results['load_average_at_end']} at the end; {results['size'][0]}x"
             f"{results['size'][1]}; {dr.thread_count()} Dr.Jit threads).", "",
             f"Packet gathers, time per gathered record per pixel, all threads (tables of {IN_CACHE >> 10} KiB "
             f"in cache, {results['out_of_cache_bytes'] >> 20} MiB out of cache; {GATHERS_PER_LANE} gathers per "
             "lane; GB/s of records delivered):", ""]
    lines += micro_table(results["micro"], results["quick"]) + [""]
    for shifted, gathered in zip(results["methods"], results["gather_methods"]):
        lines += [levels_summary(gathered, "neighbour reads gathered"),
                  levels_summary(shifted, "shifted planes (denoise.neighbours)")]
    lines.append("")
    for p in results["methods"]:
        lines += kernel_table(p)
    for p in results["gather_methods"]:
        lines += kernel_table(p, levels_only=True)
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    parser.add_argument("--work", type=Path, default=Path("out/denoise"),
                        help="where the speed run's frames are (rendered there if missing; default out/denoise)")
    parser.add_argument("--json", type=Path, metavar="PATH", help="write the measurements as JSON")
    parser.add_argument("--docs", action="store_true",
                        help="write docs/denoise/roofline.json and the section of docs/results/roofline.md")
    parser.add_argument("--quick", action="store_true",
                        help="small microbenchmarks and the small speed frames of benchmarks.denoise --quick")
    args = parser.parse_args(argv)
    if args.docs:
        args.json = args.json or ROOT / "docs" / "denoise" / "roofline.json"
    check_work_and_json(args.work, args.json)
    set_variant(None, jit=True)  # it reads Dr.Jit's kernel history
    size = QUICK_TIMING if args.quick else TIMING
    folder = timing_folder(args.work, SEQUENCES[0].stem, size, args.quick)
    render([(Spec.load(SEQUENCES[0], **size), folder)])
    frames = [read_frame(folder, i) for i in frame_indices(folder)]
    results = {"date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
               "machine": machine(), "load_average_at_start": round(os.getloadavg()[0], 2), "quick": args.quick,
               "out_of_cache_bytes": QUICK["out_of_cache"] if args.quick else OUT_OF_CACHE,
               "size": [frames[0].beauty.shape[1], frames[0].beauty.shape[0]]}
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        results["micro"] = microbenchmarks(args.quick)
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    results["methods"] = [profile(frames, method) for method in METHODS]
    neighbours.ENABLED = False  # the same kernels with every neighbour read a gather
    try:
        results["gather_methods"] = [profile(frames, method) for method in METHODS]
    finally:
        neighbours.ENABLED = True
    for p in results["methods"] + results["gather_methods"]:
        for k in p["kernels"]:
            k.update(bound(k, results["micro"]))
    results["load_average_at_end"] = round(os.getloadavg()[0], 2)
    text = page(results, "python -m benchmarks.roofline" + (" --quick" if args.quick else ""))
    print(text)
    if args.json:
        write_json(args.json, results)
    if args.docs:
        replace_section(PAGE, "roofline", text)
    return 0


if __name__ == "__main__":
    entry.finish(entry.run(PROG, main))
