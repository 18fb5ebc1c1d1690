"""The denoisers' error against their time: the front a user chooses from.

    python -m benchmarks.denoise_front [--json PATH] [--out PNG]

From the results of ``python -m benchmarks.denoise`` (``--json``; default
docs/denoise/denoise.json, which ``--docs`` writes), one log-log panel per
sequence and a last one for all of them: each method's mean relMSE over
frames >= :data:`QUALITY_FROM` against its time per frame at the speed run's
size (1280x720), one marker per method. The last panel takes the geometric
mean of each method's relMSE over the sequences and joins its Pareto front
(the methods that no other beats in both error and time). ``python -m
benchmarks.denoise --docs`` draws it beside its results page.
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

# started as `python benchmarks/x.py`, this folder would shadow the course and denoise packages
if __name__ == "__main__" and not __package__:
    sys.path[0] = str(Path(__file__).resolve().parents[1])

if __name__ == "__main__":  # first: ./.venv's Python, the libLLVM, then Dr.Jit (see core.launcher)
    from core.launcher import start
    start("python -m benchmarks.denoise_front", "benchmarks.denoise_front" if __package__ else None)

from core import entry
from core.entry import ArgumentParser, printable
from core.errors import UsageError
from core.json_input import JSONInputError, read_json
from denoise.temporal_metrics import QUALITY_FROM
from imaging.image_io import atomic_path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_JSON = ROOT / "docs" / "denoise" / "denoise.json"
DEFAULT_FIGURE = ROOT / "docs" / "denoise" / "front.png"
#: the largest results file read (a full run's is about 1 MB)
JSON_LIMIT = 64 << 20
#: the methods drawn with a filled marker of their own colour family
FAMILIES = (("oidn", "tab:blue"), ("learned", "tab:red"), ("asvgf", "tab:orange"), ("svgf", "tab:green"))


def tail_mean(rows: list[dict], sequence: str, method: str) -> float | None:
    """``method``'s mean relMSE on ``sequence`` over frames >= :data:`QUALITY_FROM`; None without such frames."""
    values = [r["relmse"] for r in rows
              if r["sequence"] == sequence and r["method"] == method and r["frame"] >= QUALITY_FROM]
    return sum(values) / len(values) if values else None


def front_points(results: dict) -> dict[str, dict[str, tuple[float, float]]]:
    """Per panel (each sequence, then ``all``): method -> (ms per frame, mean relMSE), for
    the methods the speed run timed; ``all`` holds the geometric mean over the sequences."""
    timing = results.get("timing") or {}
    ms = timing.get("ms", {})
    sequences = [s["name"] for s in results.get("sequences", [])]
    panels: dict[str, dict[str, tuple[float, float]]] = {}
    for sequence in sequences:
        points = {m: (t, e) for m, t in ms.items()
                  if (e := tail_mean(results["results"], sequence, m)) is not None and e > 0 and t > 0}
        if points:
            panels[sequence] = points
    common = [m for m in ms if panels and all(m in points for points in panels.values())]
    panels["all"] = {m: (ms[m], math.exp(sum(math.log(p[m][1]) for p in panels.values()) / len(panels)))
                     for m in common}
    return panels


def pareto(points: dict[str, tuple[float, float]]) -> list[str]:
    """The methods no other is both faster than and more accurate than, fastest first."""
    ordered = sorted(points, key=lambda m: (points[m][0], points[m][1]))
    front, best = [], math.inf
    for method in ordered:
        if points[method][1] < best:
            front.append(method)
            best = points[method][1]
    return front


def colour(method: str) -> str:
    return next((c for prefix, c in FAMILIES if method.startswith(prefix)), "tab:gray")


def write_front(results: dict, path: Path) -> Path:
    """Draws :func:`front_points` into ``path`` (PNG); raises UsageError without a speed run."""
    import matplotlib  # noqa: PLC0415  matplotlib loads on use: --help and the paths without it stay quick

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415  as above
    from matplotlib.ticker import LogFormatterSciNotation, NullFormatter  # noqa: PLC0415  as above

    if not (results.get("timing") or {}).get("ms"):
        raise UsageError("the results have no speed run (timing) to plot the front against; "
                         "run python -m benchmarks.denoise without --no-timing")
    panels = front_points(results)
    if not panels.get("all"):
        raise UsageError(f"no timed method has frames >= {QUALITY_FROM} on every sequence (a --quick run has "
                         "4 frames a sequence): there is no front to draw")
    size = "x".join(map(str, results["timing"].get("size", ("?", "?"))))
    columns = min(len(panels), 4)
    rows = math.ceil(len(panels) / columns)
    figure, axes = plt.subplots(rows, columns, figsize=(4.2 * columns, 3.6 * rows), squeeze=False)
    markers = "osD^v<>pPhX*d8H1234"
    methods = list(dict.fromkeys(m for points in panels.values() for m in points))
    for axis, (name, points) in zip(axes.flat, panels.items()):
        for k, method in enumerate(methods):
            if method in points:
                axis.loglog(*points[method], markers[k % len(markers)], color=colour(method), label=method,
                            markersize=7, markeredgecolor="black", markeredgewidth=0.5)
        if name == "all":
            front = pareto(points)
            axis.loglog([points[m][0] for m in front], [points[m][1] for m in front], "-", color="black",
                        linewidth=0.8, zorder=0, label="Pareto front")
        axis.set_title(name if name != "all" else "all sequences (geometric mean)", fontsize=10)
        axis.set_xlabel(f"ms per frame at {size}")
        axis.set_ylabel(f"mean relMSE, frames >= {QUALITY_FROM}")
        axis.grid(True, which="both", linewidth=0.3)
        for ticks in (axis.xaxis, axis.yaxis):  # decades labelled, the minor ticks not (they overlapped)
            ticks.set_major_formatter(LogFormatterSciNotation())
            ticks.set_minor_formatter(NullFormatter())
    for axis in list(axes.flat)[len(panels):]:
        axis.axis("off")
    handles, labels = axes.flat[len(panels) - 1].get_legend_handles_labels()
    figure.legend(handles, labels, loc="lower center", ncol=min(len(labels), 6), fontsize=9, frameon=False)
    figure.suptitle(f"error against time per frame ({results.get('machine', 'this machine')}, "
                    f"{results.get('date', '')})", fontsize=10)
    figure.tight_layout(rect=(0, 0.06 * (1 + len(labels) // 7) / rows, 1, 0.96))
    try:
        with atomic_path(path, ".png") as tmp:
            figure.savefig(tmp, format="png", dpi=110)
    finally:
        plt.close(figure)
    return Path(path)


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog="python -m benchmarks.denoise_front", description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", type=Path, default=DEFAULT_JSON, metavar="PATH",
                        help="results of python -m benchmarks.denoise --json (default docs/denoise/denoise.json)")
    parser.add_argument("--out", type=Path, default=DEFAULT_FIGURE, metavar="PNG",
                        help="the figure (default docs/denoise/front.png)")
    args = parser.parse_args(argv)
    if args.out.suffix.lower() != ".png":
        raise UsageError(f"--out: expected a .png file, got {args.out}")
    try:
        results = read_json(args.json, JSON_LIMIT)
    except JSONInputError as error:
        raise UsageError(str(error)) from None
    if not isinstance(results, dict) or not isinstance(results.get("results"), list):
        raise UsageError(f"{args.json}: not the JSON of python -m benchmarks.denoise (no 'results' list)")
    path = write_front(results, args.out)
    front = ", ".join(pareto(front_points(results)["all"]))
    print(f"{printable(path)}: Pareto front over all sequences, fastest first: {front}")
    return 0


if __name__ == "__main__":
    entry.finish(entry.run("python -m benchmarks.denoise_front", main))
