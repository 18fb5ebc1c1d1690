"""What exporting a dataset through Dask costs, against the plain local export.

    python -m benchmarks.scaleout [--json PATH] [--frames 4] [--size 320 180]
                                  [--reference-spp 1024] [--batch-spp 64] [--workers 2]

The same small dataset (the sequences in ``scenes/sequences/``, shortened) is
exported twice: in this process without Dask, and through a ``LocalCluster``
of ``--workers`` processes with one task each. Every render runs on one Dr.Jit
thread (:data:`export.sequence.RENDER_THREADS`: Dr.Jit's sums follow the
thread count, and the bytes must not), so the in-process export uses one core
and the cluster's ideal is ``workers`` times faster. Prints and writes (``--json``)::

    {"local_s", "cluster_s", "efficiency": local_s / cluster_s,
     "parallel_efficiency": local_s / (workers * cluster_s), "identical",
     "tasks", "task_median_s", "overhead_s", "writing_s_per_task",
     "cluster_start_s", "workers_busy_1000_frames", ...}

``cluster_s`` runs from a started cluster (its processes up, the project
imported and the variant set on each) to the last file written;
``cluster_start_s`` is that start. ``overhead_s`` is the median round trip
of a near-empty task (submit, run, result back). ``identical``: every image
and matrix file of the two exports is byte for byte the same (exit 1 if
not). ``workers_busy_1000_frames``: how many workers the task granularity
keeps busy on a 1000-frame dataset of the same frames: each worker needs a
task every ``task_median_s``, and the one client dispatches and writes one
every ``max(overhead_s, writing_s_per_task)``; at least ten tasks per worker
keep the tail short.
"""
from __future__ import annotations

import json
import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

# started as `python benchmarks/x.py`, this folder would shadow the course and denoise packages
if __name__ == "__main__" and not __package__:
    sys.path[0] = str(Path(__file__).resolve().parents[1])

if __name__ == "__main__":  # first: ./.venv's Python, the libLLVM, then Dr.Jit (see core.launcher)
    from core.launcher import start
    start("python -m benchmarks.scaleout", "benchmarks.scaleout" if __package__ else None)

from benchmarks.records import check_json, write_json
from core import entry
from core.entry import ArgumentParser
from export.cluster import dask_client
from export.runners import export_sequences, sequences_for
from export.sequence import RENDER_THREADS
from export.spec import Spec
from export.tasks import prepare_process
from renderer.variants import set_variant

ROOT = Path(__file__).resolve().parent.parent
#: the dataset: two of our sequences (fixed, so that adding a sequence does not change the benchmark)
SEQUENCES = [ROOT / "scenes" / "sequences" / f"{name}.json" for name in ("dolly_lamps", "orbit_transforms")]


def _noop(x: int) -> int:
    return x


def _warm(variant: str, threads: int) -> str:
    """Imports the project and sets the variant on a worker (its start-up, not a task's cost)."""
    prepare_process(variant, threads)
    return variant


def files_of(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and p.suffix in (".exr", ".mat")}


def round_trip(client, count: int = 40) -> float:
    """The median wall time of submitting a near-empty task and getting its result."""
    times = []
    for k in range(count):
        start = time.perf_counter()
        client.submit(_noop, k, pure=False).result()
        times.append(time.perf_counter() - start)
    return statistics.median(times[count // 4:])  # the first ones include connection set-up


def measure(frames: int, size: tuple[int, int], reference_spp: int, batch_spp: int, workers: int,
            work: Path, spp: int = 1) -> dict:
    variant = set_variant(None, quiet=True)
    overrides = dict(frames=frames, size=size, reference_spp=reference_spp, spp=spp)
    specs = [(path.stem, Spec.load(path, **overrides)) for path in SEQUENCES]

    local_out, cluster_out = work / "local", work / "cluster"
    for folder in (local_out, cluster_out):
        shutil.rmtree(folder, ignore_errors=True)
    local = sequences_for(specs, local_out, batch_spp=batch_spp, variant=variant)
    start = time.perf_counter()
    export_sequences(local, local=True, manifest=local_out / "dataset.json")
    local_s = time.perf_counter() - start
    print(f"scaleout: local export {local_s:.1f} s", file=sys.stderr)

    cluster = sequences_for(specs, cluster_out, batch_spp=batch_spp, variant=variant)
    start = time.perf_counter()
    with dask_client(None, workers) as (client, threads):
        client.run(_warm, variant, threads)
        cluster_start_s = time.perf_counter() - start
        start = time.perf_counter()
        export_sequences(cluster, manifest=cluster_out / "dataset.json", client=client, threads=threads)
        cluster_s = time.perf_counter() - start
        overhead_s = round_trip(client)
    manifest = json.loads((cluster_out / "dataset.json").read_text())
    print(f"scaleout: cluster export {cluster_s:.1f} s ({manifest['tasks']} tasks)", file=sys.stderr)

    seconds = [t["seconds"] for entry in manifest["sequences"] for f in entry["frames"] for t in f["tasks"]]
    tasks = len(seconds)
    task_median_s = statistics.median(seconds)
    writing_s = manifest["writing_s_per_task"]
    identical = files_of(local_out) == files_of(cluster_out)
    tasks_per_frame = tasks / sum(s.spec.frames for s in cluster)
    tasks_1000 = 1000 * tasks_per_frame
    busy = min(tasks_1000 / 10, task_median_s / max(overhead_s, writing_s))
    return {"local_s": round(local_s, 3), "cluster_s": round(cluster_s, 3),
            "efficiency": round(local_s / cluster_s, 4),
            "parallel_efficiency": round(local_s / (workers * cluster_s), 4), "identical": identical,
            "tasks": tasks, "task_median_s": round(task_median_s, 4), "overhead_s": round(overhead_s, 5),
            "overhead_fraction": round(overhead_s / task_median_s, 5),
            "writing_s_per_task": round(writing_s, 4), "cluster_start_s": round(cluster_start_s, 3),
            "tasks_per_frame": tasks_per_frame, "workers_busy_1000_frames": int(busy),
            "workers": workers, "render_threads": RENDER_THREADS, "cores": os.cpu_count(),
            "sequences": [s.name for s in cluster], "frames": frames, "size": list(size), "spp": spp,
            "reference_spp": reference_spp, "batch_spp": batch_spp, "variant": variant,
            "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog="python -m benchmarks.scaleout", description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", type=Path, metavar="PATH")
    parser.add_argument("--frames", type=int, default=4)
    parser.add_argument("--size", type=int, nargs=2, default=(320, 180), metavar=("W", "H"))
    parser.add_argument("--reference-spp", type=int, default=1024)
    parser.add_argument("--batch-spp", type=int, default=64)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--work", type=Path, help="where the two exports go (default: a temporary folder)")
    args = parser.parse_args(argv)
    check_json(args.json)
    with tempfile.TemporaryDirectory(prefix="scaleout.") as scratch:
        result = measure(args.frames, tuple(args.size), args.reference_spp, args.batch_spp, args.workers,
                         args.work or Path(scratch))
    print(json.dumps(result, indent=2))
    print(f"efficiency {result['efficiency']:.3f}, per worker {result['parallel_efficiency']:.3f} (bar >= 0.9), "
          f"overhead {100 * result['overhead_fraction']:.2f} % "
          f"of the median task (bar <= 5 %), identical: {result['identical']}", file=sys.stderr)
    if args.json:
        write_json(args.json, result)
    return 0 if result["identical"] else 1


if __name__ == "__main__":
    entry.finish(entry.run("python -m benchmarks.scaleout", main))
