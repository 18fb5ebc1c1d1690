"""What the kernel benchmarks share: every Dr.Jit kernel of a method's frame,
timed from Dr.Jit's kernel history, and what its LLVM IR reads and writes per
pixel (``benchmarks.denoise_profile`` and ``benchmarks.roofline``)."""
from __future__ import annotations

import re
import time

import drjit as dr
import numpy as np

from benchmarks.denoise import make_method

#: the taps an À-Trous level reads around its centre (5x5 less the centre): a kernel with at
#: least this many 4-float and 8-float packet gathers, or 9 times as many shifted loads
#: (3 colour and 6 guide planes per tap), is an À-Trous level
LEVEL_TAPS = 24
#: the record sizes (floats) of Dr.Jit's packet gather helpers
PACKET_SIZES = (2, 4, 8, 16)


def ir_traffic(ir: str) -> dict:
    """What a kernel's LLVM IR reads and writes per lane (= per pixel): its
    main function's loads, stores, single-float gathers and scatters, and
    calls of Dr.Jit's packet gather/scatter helpers (their bodies not counted).

    ``distinct_bytes_per_pixel`` is what the kernel must bring from memory at
    the least: each array it gathers from counted once, one record per pixel
    (a filter's taps read neighbours that the pixels around read too), plus
    its plain loads and its stores (:func:`shifted_level` corrects the loads
    of a level reading shifted planes)."""
    start = ir.find("define void @drjit_")
    if start >= 0:
        ir = ir[start:ir.find("\n}", start)]
    packets = {}  # (record length, element bytes) -> calls
    for n, kind in re.findall(r"call fastcc \[(\d+) x <\d+ x (float|half)>\] @gather_\d+xf(?:32|16)", ir):
        key = (int(n), 4 if kind == "float" else 2)
        packets[key] = packets.get(key, 0) + 1
    single_gathers = len(re.findall(r"call <\d+ x (?:float|i32)> @llvm\.masked\.gather", ir))
    loads = len(re.findall(r"= load <\d+ x (?:float|i32)>", ir))
    stores = len(re.findall(r"store <\d+ x (?:float|i32)>", ir))
    scatters = len(re.findall(r"call void @llvm\.masked\.scatter", ir)) + sum(
        n * len(re.findall(rf"call fastcc void @scatter_{n}xf32\(", ir)) for n in PACKET_SIZES)
    # the arrays gathered from: a vector of addresses into one array, as [n x type] records or single values
    sources = {}
    for record, base in re.findall(r"getelementptr (\[\d+ x (?:float|half)\]|float|i32|half), ptr (%\w+), <", ir):
        n = int(record[1:].split()[0]) if record.startswith("[") else 1
        sources[base] = max(sources.get(base, 0), n * (2 if "half" in record else 4))
    read = sum(n * size * c for (n, size), c in packets.items()) + 4 * (single_gathers + loads)
    written = 4 * (stores + scatters)
    return {"packet_gathers": {record_name(n, size): c for (n, size), c in sorted(packets.items())},
            "single_gathers": single_gathers, "loads": loads, "shifted_loads": 0,
            "bytes_read_per_pixel": read, "bytes_written_per_pixel": written,
            "distinct_bytes_per_pixel": sum(sources.values()) + 4 * loads + written}


def shifted_level(traffic: dict) -> dict:
    """``traffic`` of a kernel with no packet gathers and at least
    ``9 * LEVEL_TAPS`` plain loads: an À-Trous level that reads shifted planes
    (:mod:`denoise.neighbours`), its loads then ``shifted_loads``. A mapped
    array is a plain load in the IR, which cannot tell which ones share a
    plane: its distinct bytes count the loads once per ``LEVEL_TAPS`` (each
    plane read at every tap's offset; the few loads of the centre's own values
    are then under-counted). Other kernels: ``traffic`` as it is."""
    if traffic["packet_gathers"] or traffic["loads"] < 9 * LEVEL_TAPS:
        return traffic
    loads = traffic["loads"]
    return {**traffic, "shifted_loads": loads, "distinct_bytes_per_pixel":
            traffic["distinct_bytes_per_pixel"] - 4 * loads + 4 * -(-loads // LEVEL_TAPS)}


def record_name(n: int, element_bytes: int = 4) -> str:
    """A packet gather's record as the tables name it: ``4 floats``, ``8 halves``."""
    return f"{n} {'floats' if element_bytes == 4 else 'halves'}"


def ir_text(kernel: dict) -> str:
    """A history entry's IR as text (only JIT kernels have IR, not e.g. Dr.Jit's compress or memset)."""
    ir = kernel.get("ir", "")
    return ir.getvalue() if hasattr(ir, "getvalue") else str(ir)


def profile(frames, method: str) -> dict:
    """Median per-kernel execution times of ``method`` over ``frames[2:]``
    (the first two compile a first frame's kernels and a frame's with history)."""
    runner = make_method(method)
    for frame in frames[:2]:
        runner.step(frame)
    dr.sync_thread()
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    runs, walls = [], []
    try:
        for frame in frames[2:]:
            dr.kernel_history()  # drop what came before
            start = time.perf_counter()
            runner.step(frame)
            dr.sync_thread()
            walls.append(1000 * (time.perf_counter() - start))
            runs.append([k for k in dr.kernel_history() if "execution_time" in k and k.get("size", 0) > 1])
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    counts = {len(r) for r in runs}
    if len(counts) != 1:
        raise RuntimeError(f"{method}: the frames launched different numbers of kernels ({sorted(counts)})")
    kernels = []
    for position, first in enumerate(runs[0]):
        traffic = shifted_level(ir_traffic(ir_text(first)))
        packets = traffic["packet_gathers"]
        kernels.append({"kernel": position, "type": str(first["type"]).split(".")[-1], "size": int(first["size"]),
                        "operations": int(first.get("operation_count", 0)),
                        "level": (packets.get("8 floats", 0) >= LEVEL_TAPS and packets.get("4 floats", 0)
                                  >= LEVEL_TAPS) or traffic["shifted_loads"] > 0,
                        **traffic,
                        "ms": float(np.median([r[position]["execution_time"] for r in runs])),
                        "ms_min": float(min(r[position]["execution_time"] for r in runs)),
                        "ms_max": float(max(r[position]["execution_time"] for r in runs))})
    total = sum(k["ms"] for k in kernels)
    levels = sum(k["ms"] for k in kernels if k["level"])
    return {"method": method, "frames": len(runs), "wall_ms": float(np.median(walls)), "kernels_ms": total,
            "levels_ms": levels, "other_kernels_ms": total - levels, "kernels": kernels}
