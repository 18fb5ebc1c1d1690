"""Render speed per course scene at the course's sizes, as whole processes.

    python -m benchmarks.render_speed [--json PATH] [--repeat N] [--variant V] [--peer PATH]

For each of the course's seven grading command lines it measures, in one run
on this machine (medians of N):

- ``process_s``: the whole ``python render.py <the course's flags>`` process,
  wall, from start to exit (interpreter start, import, scene load, render,
  files written), run in the course folder as the course runs its binary;
- ``peer_process_s`` (only with ``--peer PATH``): the course binary given,
  run the same way with the same arguments, interleaved with ours; without
  ``--peer`` there is no such column (no timings are copied from elsewhere);
- ``render_s``: inside one process, ``mi.render`` on the loaded scene with
  the AOVs the command line's outputs need, warm (kernels compiled);
  ``first_render_s`` is the first render in the process (tracing included,
  kernels from the cache). These are not comparable with a process time;
- ``native_direct_s`` / ``whitted_direct_s``: Mitsuba's native ``direct``
  integrator against our ``whitted`` with 0 bounces and shadows, same
  converted scene, same spp, interleaved. ``direct`` is configured with
  ``emitter_samples`` = the number of lights and ``bsdf_samples`` = 0: as
  many shadow rays as whitted traces, but each of them goes to a light
  picked **at random** (Mitsuba's ``direct`` cannot take one sample per
  light), so it renders a noisy estimate of whitted's image at the same
  ray count;

and ``suite_wall_s``: all seven command lines in one ``render.py --batch``
process (and ``peer_suite_s``: the peer binary's seven processes, summed).
The JSON records the machine and the date.
"""
from __future__ import annotations

import datetime as dt
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

# started as `python benchmarks/x.py`, this folder would shadow the course and denoise packages
if __name__ == "__main__" and not __package__:
    sys.path[0] = str(Path(__file__).resolve().parents[1])

if __name__ == "__main__":  # first: ./.venv's Python, the libLLVM, then Dr.Jit (see core.launcher)
    from core.launcher import start
    start("python -m benchmarks.render_speed", "benchmarks.render_speed" if __package__ else None)

import drjit as dr
import mitsuba as mi

from benchmarks.records import check_json, machine, write_json
from converters.course_scene import load_scene
from converters.description import scene_dict
from converters.to_mitsuba import load_scene_dict
from core.entry import ArgumentParser
from course import course_runs, outputs_into, root as course_root
from renderer.job import course_job
from renderer.variants import set_variant

ROOT = Path(__file__).resolve().parent.parent


def _timed(fn) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def measure(course: Path, repeat: int, variant: str | None, peer: Path | None = None,
            only: list[str] | None = None) -> dict:
    variant = set_variant(variant, quiet=True)


    def render(scene):
        image = mi.render(scene)
        dr.eval(image)
        dr.sync_thread()
        return image

    rows = []
    runs = [r for r in course_runs(course) if not only or r.scene in only]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for run in runs:
            args = outputs_into(run.arguments, tmp)
            job = course_job(run, course, outputs=tmp)
            parsed = load_scene(job.scene)
            description = scene_dict(parsed, job.options())
            scene = load_scene_dict(description)
            first = _timed(lambda scene=scene: render(scene))
            warm = [_timed(lambda scene=scene: render(scene)) for _ in range(repeat)]

            # native direct vs whitted, same scene and spp, interleaved
            lights = max(1, len(parsed.lights))
            native = dict(description, integrator={"type": "direct", "emitter_samples": lights, "bsdf_samples": 0})
            ours = dict(description, integrator=dict(description["integrator"], bounces=0, shadows=True, aovs=""))
            native_scene, ours_scene = load_scene_dict(native), load_scene_dict(ours)
            render(native_scene), render(ours_scene)
            native_t, ours_t = [], []
            for _ in range(repeat):
                native_t.append(_timed(lambda scene=native_scene: render(scene)))
                ours_t.append(_timed(lambda scene=ours_scene: render(scene)))

            command = [sys.executable, str(ROOT / "render.py"), *args, "--quiet", "--variant", variant]
            peer_command = [str(peer), *args] if peer else None
            for c in filter(None, (command, peer_command)):
                subprocess.run(c, cwd=course, check=True, stdout=subprocess.DEVNULL)  # warm the caches
            process, peer_process = [], []
            for _ in range(repeat):  # interleaved: both see the same machine load
                process.append(_timed(lambda command=command: subprocess.run(command, cwd=course, check=True)))
                if peer_command:
                    peer_process.append(_timed(lambda command=peer_command: subprocess.run(
                        command, cwd=course, check=True, stdout=subprocess.DEVNULL)))
            row = {"scene": run.scene, "variant": variant, "process_s": statistics.median(process),
                   "render_s": statistics.median(warm), "first_render_s": first,
                   "native_direct_s": statistics.median(native_t), "whitted_direct_s": statistics.median(ours_t)}
            if peer_command:
                row["peer_process_s"] = statistics.median(peer_process)
            rows.append(row)
            print(f"{run.scene}: process {row['process_s']:.2f} s"
                  + (f", peer {row['peer_process_s']:.2f} s" if peer else ""), file=sys.stderr)

        batch = tmp / "grading.sh"
        batch.write_text("\n".join(" ".join(["a2", *outputs_into(r.arguments, tmp)]) for r in runs) + "\n")
        command = [sys.executable, str(ROOT / "render.py"), "--batch", str(batch), "--quiet", "--variant", variant]
        subprocess.run(command, cwd=course, check=True)
        suite = [_timed(lambda command=command: subprocess.run(command, cwd=course, check=True)) for _ in range(repeat)]
    results = {"scenes": rows, "suite_wall_s": statistics.median(suite), "repeat": repeat,
               "command": "python -m benchmarks.render_speed" + (" --peer PATH" if peer else ""),
               "machine": machine(), "date": dt.date.today().isoformat()}
    if peer:
        results["peer"] = str(peer)
        results["peer_suite_s"] = sum(r["peer_process_s"] for r in rows)
    return results


def report(results: dict) -> str:
    """Markdown: whole processes side by side (the peer's only if it was measured), then
    the in-process render times and direct vs whitted."""
    peer = "peer_suite_s" in results
    head = "| scene | render.py process s |" + (" peer process s | peer / ours |" if peer else "")
    head += " in-process render s (warm) | first render s | native `direct` s | `whitted` 0 bounces s | ratio |"
    lines = [head, "|---|---|" + ("---|---|" if peer else "") + "---|---|---|---|---|"]
    for r in results["scenes"]:
        cells = [r["scene"], f"{r['process_s']:.2f}"]
        if peer:
            cells += [f"{r['peer_process_s']:.2f}", f"{r['peer_process_s'] / r['process_s']:.2f}"]
        cells += [f"{r['render_s']:.3f}", f"{r['first_render_s']:.3f}", f"{r['native_direct_s']:.3f}",
                  f"{r['whitted_direct_s']:.3f}", f"{r['whitted_direct_s'] / r['native_direct_s']:.2f}"]
        lines.append("| " + " | ".join(cells) + " |")
    n = len(results["scenes"])
    lines.append(f"\nAll {n} command lines in one `render.py --batch` process: {results['suite_wall_s']:.2f} s wall"
                 + (f"; the peer binary's {n} processes: {results['peer_suite_s']:.2f} s" if peer else "") + ".")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog="python -m benchmarks.render_speed", description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", type=Path, metavar="PATH", help="also write the numbers as JSON")
    parser.add_argument("--repeat", type=int, default=5, help="timed runs per measurement (default 5)")
    parser.add_argument("--variant", help="variant (default: llvm_ad_rgb where usable)")
    parser.add_argument("--course", type=Path, default=course_root(),
                        help="course folder (default: $COURSE_ROOT, else ../shared/course)")
    parser.add_argument("--peer", type=Path, metavar="PATH",
                        help="the course's binary: timed as a whole process beside ours, same arguments")
    parser.add_argument("--only", metavar="SCENE", action="append", help="only these scenes (a quick check)")
    args = parser.parse_args(argv)
    check_json(args.json)
    results = measure(args.course, args.repeat, args.variant, args.peer, args.only)
    print(report(results))
    if args.json:
        write_json(args.json, results)
    return 0


if __name__ == "__main__":
    from core import entry

    entry.finish(entry.run("python -m benchmarks.render_speed", main))
