"""Render speed per course scene at 800x800, beside the course binary's times.

    python -m benchmarks.render_speed [--json PATH] [--repeat N] [--variant V]

For each of the course's seven grading command lines it measures, in one run
on this machine:

- ``render_s``: our render (mi.render on the loaded scene, with the AOVs the
  command line's outputs need), median of N warm runs; ``first_render_s`` is
  the first render in the process (tracing included, kernels from the cache);
- ``process_s``: the whole ``python render.py <course flags>`` process, wall,
  median of N (caches warm);
- ``native_direct_s`` / ``whitted_direct_s``: Mitsuba's native ``direct``
  integrator (emitter sampling only, one sample per light) against our
  ``whitted`` with 0 bounces and shadows, same converted scene, 1 spp,
  interleaved, medians;

and ``suite_wall_s``: all seven command lines in one ``render.py --batch``
process. The course binary's times come from the course README.
"""
from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks import write_json
from benchmarks.course import DEFAULT_COURSE, ROOT, course_runs


def _timed(fn) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def _rewrite_outputs(words: list[str], folder: Path) -> list[str]:
    """The command line with its output files moved into ``folder``."""
    out = list(words)
    for flag, offset in (("-output", 1), ("-normals", 1), ("-depth", 3)):
        if flag in out:
            k = out.index(flag) + offset
            out[k] = str(folder / Path(out[k]).name)
    return out


def measure(course: Path, repeat: int, variant: str | None) -> dict:
    from renderer.variants import set_variant

    variant = set_variant(variant, quiet=True)
    import drjit as dr
    import mitsuba as mi

    from converters.course_scene import load_scene
    from converters.to_mitsuba import load_scene_dict, scene_dict
    from renderer.cli import build_parser, jobs_from_args

    def render(scene):
        image = mi.render(scene)
        dr.eval(image)
        dr.sync_thread()
        return image

    rows = []
    runs = course_runs(course)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for run in runs:
            args = _rewrite_outputs(run.arguments, tmp)
            (job,) = jobs_from_args(build_parser().parse_args(["-input", str(course / args[args.index("-input") + 1]),
                                                               *[a for k, a in enumerate(args) if k not in
                                                                 (args.index("-input"), args.index("-input") + 1)]]))
            parsed = load_scene(job.scene)
            description = scene_dict(parsed, job.options())
            scene = load_scene_dict(description)
            first = _timed(lambda: render(scene))
            warm = [_timed(lambda: render(scene)) for _ in range(repeat)]

            # native direct vs whitted, same scene and spp, interleaved
            lights = max(1, len(parsed.lights))
            native = dict(description, integrator={"type": "direct", "emitter_samples": lights, "bsdf_samples": 0})
            ours = dict(description, integrator=dict(description["integrator"], max_depth=0, shadows=True, aovs=""))
            native_scene, ours_scene = load_scene_dict(native), load_scene_dict(ours)
            render(native_scene), render(ours_scene)
            native_t, ours_t = [], []
            for _ in range(repeat):
                native_t.append(_timed(lambda: render(native_scene)))
                ours_t.append(_timed(lambda: render(ours_scene)))

            command = [sys.executable, str(ROOT / "render.py"), *args, "--quiet", "--variant", variant]
            subprocess.run(command, cwd=course, check=True)  # warm the caches
            process = [_timed(lambda: subprocess.run(command, cwd=course, check=True)) for _ in range(repeat)]
            rows.append({"scene": run.scene, "variant": variant,
                         "render_s": statistics.median(warm), "first_render_s": first,
                         "process_s": statistics.median(process),
                         "native_direct_s": statistics.median(native_t),
                         "whitted_direct_s": statistics.median(ours_t),
                         "course_s": run.course_seconds})
            print(f"{run.scene}: render {rows[-1]['render_s']:.3f} s, process {rows[-1]['process_s']:.2f} s",
                  file=sys.stderr)

        batch = tmp / "grading.sh"
        batch.write_text("\n".join(" ".join(["a2", *_rewrite_outputs(r.arguments, tmp)]) for r in runs) + "\n")
        command = [sys.executable, str(ROOT / "render.py"), "--batch", str(batch), "--quiet", "--variant", variant]
        subprocess.run(command, cwd=course, check=True)
        suite = [_timed(lambda: subprocess.run(command, cwd=course, check=True)) for _ in range(repeat)]
    return {"scenes": rows, "suite_wall_s": statistics.median(suite),
            "course_suite_s": sum(r.course_seconds for r in runs)}


def report(results: dict) -> str:
    lines = ["| scene | course binary s | our render s | % of course | first render s | process s | "
             "process speed-up | native direct s | whitted direct s | whitted/native |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in results["scenes"]:
        lines.append(f"| {r['scene']} | {r['course_s']:.2f} | {r['render_s']:.3f} | "
                     f"{100 * r['render_s'] / r['course_s']:.1f}% | {r['first_render_s']:.3f} | "
                     f"{r['process_s']:.2f} | {r['course_s'] / r['process_s']:.1f}x | "
                     f"{r['native_direct_s']:.3f} | {r['whitted_direct_s']:.3f} | "
                     f"{r['whitted_direct_s'] / r['native_direct_s']:.2f} |")
    lines.append(f"\nAll seven in one process: {results['suite_wall_s']:.2f} s wall "
                 f"(course binary: {results['course_suite_s']:.1f} s in seven processes)")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.render_speed", description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", type=Path, metavar="PATH", help="also write the numbers as JSON")
    parser.add_argument("--repeat", type=int, default=5, help="timed runs per measurement (default 5)")
    parser.add_argument("--variant", help="variant (default: llvm_ad_rgb where usable)")
    parser.add_argument("--course", type=Path, default=DEFAULT_COURSE, help="course folder (default ../shared/course)")
    args = parser.parse_args(argv)
    results = measure(args.course, args.repeat, args.variant)
    print(report(results))
    if args.json:
        write_json(args.json, results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
