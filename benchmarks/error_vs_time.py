"""Error against run time for two ways of rendering the same image.

    python -m benchmarks.error_vs_time [--quick] [--json PATH] [--out DIR]

Per scene (the course's and ours), the light transport of the course's ray
tracer (``whitted``'s light paths: direct light from every point light with
shadows, plus mirror recursion; ambient 0 and a background that emits
nothing, as in :mod:`validation.crossval`), computed two ways:

- ``whitted``: our integrator, every light evaluated at every hit, with
  jittered supersampling, 1..256 spp;
- ``path``: Mitsuba's path tracer on the same light paths (``phong`` with
  ``sampling="mirror"``): one light picked at random per hit, 1..4096 spp.

Both are compared with **one common reference**: ``whitted`` converged
(4096 jittered spp, another seed), so "seconds to relMSE 1e-3" compares the
two on the same image. Errors are relMSE and mean FLIP (``flip-evaluator``,
LDR: the course displays linear values clamped to [0, 1]).

The fitting rule (fixed before any data was taken) and the measurement are
:mod:`validation.convergence`'s; this command runs them at full size.

Writes per scene a log-log plot ``<out>/<scene>.png``,
``<out>/error_vs_time.csv`` and, with ``--json``,
``{"points": [{scene, method, spp, seconds, relmse, flip}],
"slopes": [{scene, method, slope, spp_slope, seconds_to_relmse_1e-3}]}``.
"""
from __future__ import annotations

import csv
import sys
from pathlib import Path

# started as `python benchmarks/x.py`, this folder would shadow the course and denoise packages
if __name__ == "__main__" and not __package__:
    sys.path[0] = str(Path(__file__).resolve().parents[1])

if __name__ == "__main__":  # first: ./.venv's Python, the libLLVM, then Dr.Jit (see core.launcher)
    from core.launcher import start
    start("python -m benchmarks.error_vs_time", "benchmarks.error_vs_time" if __package__ else None)

import mitsuba as mi

from benchmarks.records import check_json, stamp, write_json
from core.entry import ArgumentParser, printable
from course import root as course_root
from imaging.image_io import atomic_path
from renderer.variants import set_variant
from validation.convergence import TARGET_RELMSE, measure, settings
from validation.crossval import scene_paths


def plot_scene(results: dict, scene: str):
    """Log-log relMSE and FLIP against seconds for one scene; returns the figure."""
    import matplotlib.pyplot as plt  # noqa: PLC0415  matplotlib loads on use: --help and the paths without it stay quick

    fig, (ax_mse, ax_flip) = plt.subplots(1, 2, figsize=(10, 4))
    for method in sorted({p["method"] for p in results["points"]}):
        pts = [p for p in results["points"] if p["scene"] == scene and p["method"] == method]
        if not pts:
            continue
        seconds = [p["seconds"] for p in pts]
        fit = next(s for s in results["slopes"] if s["scene"] == scene and s["method"] == method)
        label = f"{method} (slope {fit['slope']:.2f})"
        ax_mse.loglog(seconds, [p["relmse"] for p in pts], "o-", label=label)
        ax_flip.loglog(seconds, [p["flip"] for p in pts], "o-", label=method)
        if fit["seconds_to_relmse_1e-3"]:
            ax_mse.axvline(fit["seconds_to_relmse_1e-3"], ls=":", color=ax_mse.lines[-1].get_color())
    ax_mse.axhline(TARGET_RELMSE, color="grey", lw=0.8)
    ax_mse.set(xlabel="render time (s)", ylabel="relMSE vs converged whitted",
               title=f"{scene}: relMSE (dotted: time to 1e-3)")
    ax_flip.set(xlabel="render time (s)", ylabel="mean FLIP", title=f"{scene}: FLIP")
    for ax in (ax_mse, ax_flip):
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    fig.tight_layout()
    return fig


def write_outputs(results: dict, out: Path) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for scene in sorted({p["scene"] for p in results["points"]}):
        fig = plot_scene(results, scene)
        with atomic_path(out / f"{scene}.png", ".png") as tmp:
            fig.savefig(tmp, dpi=90, format="png")
        written.append(out / f"{scene}.png")
        import matplotlib.pyplot as plt  # noqa: PLC0415  matplotlib loads on use: --help and the paths without it stay quick

        plt.close(fig)
    with atomic_path(out / "error_vs_time.csv", ".csv") as tmp:
        with open(tmp, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=["scene", "method", "spp", "seconds", "relmse", "flip"])
            writer.writeheader()
            writer.writerows(results["points"])
    written.append(out / "error_vs_time.csv")
    return written


def slope_table(results: dict) -> str:
    """Markdown table: slope of log relMSE over log time, and time to relMSE 1e-3."""
    lines = ["| scene | method | slope per second | slope per spp | seconds to relMSE 1e-3 |", "|---|---|---|---|---|"]
    for s in results["slopes"]:
        to_target = "not reached" if s["seconds_to_relmse_1e-3"] is None else f"{s['seconds_to_relmse_1e-3']:.3g}"
        lines.append(f"| {s['scene']} | {s['method']} | {s['slope']:.2f} | {s.get('spp_slope', float('nan')):.2f} "
                     f"| {to_target} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog="python -m benchmarks.error_vs_time", description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="a small version (CI)")
    parser.add_argument("--json", type=Path, metavar="PATH", help="write the points and slopes as JSON")
    parser.add_argument("--out", type=Path, default=Path("out/error_vs_time"), help="folder for plots and CSV")
    parser.add_argument("--course", type=Path, default=course_root(),
                        help="course folder (default: $COURSE_ROOT, else ../shared/course)")
    args = parser.parse_args(argv)
    check_json(args.json)

    set_variant(None)
    size, spps, reference = settings(args.quick)
    results = measure(scene_paths(args.course, args.quick), size, spps, reference,
                      progress=lambda line: print(line, file=sys.stderr))
    for path in write_outputs(results, args.out):
        print(printable(path))

    results.update(variant=mi.variant(), **stamp(["python -m benchmarks.error_vs_time", *(argv or sys.argv[1:])]))
    if args.json:
        write_json(args.json, results)
    return 0


if __name__ == "__main__":
    from core import entry

    entry.finish(entry.run("python -m benchmarks.error_vs_time", main))

