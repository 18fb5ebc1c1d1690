"""Cross-validation of the renderer against Mitsuba's own machinery: the command and its report.

    python -m benchmarks.crossval [--json PATH] [--quick] [--bias FRACTION] [--agreement-only]

Runs the checks of :mod:`validation.crossval` (the phong BSDF's chi-square test
and white furnace; whitted against Mitsuba's path tracer restricted to
Whitted's light paths, per tile) at 128x128 pixels, 64 and 1024 spp
(``--quick``: 48x48, 16 and 64 spp, three scenes). ``--bias 0.01`` scales
whitted's shading by 1.01 (fault injection): the run must then fail.

Exits non-zero if any criterion fails. The notebook ``notebooks/crossval.ipynb``
calls the same functions and the presentation below.
"""
from __future__ import annotations

import sys
from pathlib import Path

# started as `python benchmarks/x.py`, this folder would shadow the course and denoise packages
if __name__ == "__main__" and not __package__:
    sys.path[0] = str(Path(__file__).resolve().parents[1])

if __name__ == "__main__":  # first: ./.venv's Python, the libLLVM, then Dr.Jit (see core.launcher)
    from core.launcher import start
    start("python -m benchmarks.crossval", "benchmarks.crossval" if __package__ else None)

import numpy as np

from benchmarks.records import check_json, stamp, write_json
from converters.scene_variants import with_mirror_sampling, with_path_tracer, without_ambient, without_background
from core.entry import ArgumentParser
from course import root as course_root
from renderer.variants import set_variant
from validation.crossval import biased_whitted, failures, render, run


# -- presentation (used by the notebook and the README report) -----------------
def summary_table(results: dict) -> str:
    """Markdown tables of the chi-square tests, the furnace and the agreement."""
    lines = ["| kd | ks | shininess | θi | χ² p-value | albedo (MC) | albedo (integrated) | passed |",
             "|---|---|---|---|---|---|---|---|"]
    for c, f in zip(results["chi2"], results["furnace"]):
        lines.append(f"| {c['kd']} | {c['ks']} | {c['shininess']:g} | {c['theta_deg']:g}° | {c['p_value']:.3f} | "
                     f"{f['albedo']:.4f} ± {f['stderr']:.4f} | {f['expected']:.4f} | "
                     f"{'yes' if c['passed'] and f['passed'] else 'NO'} |")
    lines += ["", "| scene | bounces | spp | max abs z (bound) | whitted/path - 1 | relMSE(whitted, path) | "
              "relMSE(path, path') | ratio | passed |", "|---|---|---|---|---|---|---|---|---|"]
    for a in results["agreement"]:
        ratio = a["relmse_whitted_path"] / a["relmse_path_path"] if a["relmse_path_path"] else float("nan")
        lines.append(f"| {a['scene']} | {a['bounces']} | {a['spp']} | {a['max_abs_z']:.2f} ({a['z_critical']:.2f}) | "
                     f"{round(100 * a['relative_bias'], 3) + 0.0:+.3f} ± {100 * a['relative_bias_stderr']:.3f} % | "
                     f"{a['relmse_whitted_path']:.2e} | {a['relmse_path_path']:.2e} | {ratio:.2f} | "
                     f"{'yes' if a['passed'] else 'NO'} |")
    return "\n".join(lines)


def plot_agreement(results: dict):
    """Per scene and bounce count: the largest tile |z| over its bound (pass: below 1),
    and relMSE(whitted, path) / relMSE(path, path') (pass: below 2)."""
    import matplotlib.pyplot as plt  # noqa: PLC0415  matplotlib loads on use: --help and the paths without it stay quick

    rows = results["agreement"]
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    spps = sorted({r["spp"] for r in rows})
    fig, axes = plt.subplots(2, len(spps), figsize=(6 * len(spps), 8), squeeze=False)
    for column, spp in enumerate(spps):
        for bounces in sorted({r["bounces"] for r in rows}):
            picked = [next((r for r in rows if r["scene"] == s and r["spp"] == spp and r["bounces"] == bounces),
                           None) for s in scenes]
            z = [r["max_abs_z"] / r["z_critical"] if r else np.nan for r in picked]
            ratios = [r["relmse_whitted_path"] / r["relmse_path_path"] if r else np.nan for r in picked]
            axes[0, column].plot(range(len(scenes)), z, "o", label=f"{bounces} bounces")
            axes[1, column].plot(range(len(scenes)), ratios, "o", label=f"{bounces} bounces")
        for row, (bound, label) in enumerate(((1.0, "max |z| / Bonferroni bound"),
                                              (2.0, "relMSE(whitted, path) / relMSE(path, path')"))):
            ax = axes[row, column]
            ax.axhline(bound, color="red", lw=1, label="criterion")
            ax.set_xticks(range(len(scenes)), scenes, rotation=45, ha="right")
            ax.set(ylabel=label, title=f"{spp} spp", ylim=(0, 1.25 * bound))
            ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def plot_light_paths(path: Path, size: int = 160, spp: int = 64, bounces: int = 3):
    """Whitted, the path tracer on Whitted's light paths, and the full path tracer."""
    import matplotlib.pyplot as plt  # noqa: PLC0415  matplotlib loads on use: --help and the paths without it stay quick

    common = dict(bounces=bounces, shadows=True, spp=spp, jitter=True)
    whitted_paths = (without_ambient, without_background)
    images = {
        "whitted (ambient 0, no background)": render(path, size, variants=whitted_paths, **common),
        "path, Whitted's light paths": render(path, size, variants=(*whitted_paths, with_path_tracer,
                                                                    with_mirror_sampling), **common),
        "path, full Phong model + background light": render(path, size, variants=(with_path_tracer,),
                                                            **dict(common, bounces=max(bounces, 6))),
    }
    fig, axes = plt.subplots(1, 3, figsize=(12, 4.4))
    for ax, (title, image) in zip(axes, images.items()):
        ax.imshow(np.clip(image, 0, 1))
        ax.set_title(title, fontsize=9)
        ax.axis("off")
    fig.suptitle(path.stem)
    fig.tight_layout()
    return fig


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog="python -m benchmarks.crossval", description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", type=Path, metavar="PATH", help="write the numbers as JSON")
    parser.add_argument("--quick", action="store_true", help="a small version (CI)")
    parser.add_argument("--course", type=Path, default=course_root(),
                        help="course folder (default: $COURSE_ROOT, else ../shared/course)")
    parser.add_argument("--bias", type=float, default=0.0, metavar="FRACTION",
                        help="fault injection: scale whitted's shading by 1 + FRACTION (the run must then fail)")
    parser.add_argument("--agreement-only", action="store_true", help="skip the chi-square and furnace checks")
    args = parser.parse_args(argv)
    check_json(args.json)

    set_variant(None)
    if args.bias:
        with biased_whitted(args.bias):
            results = run(args.course, args.quick, bsdf=not args.agreement_only)
        results["settings"]["injected_bias"] = args.bias
    else:
        results = run(args.course, args.quick, bsdf=not args.agreement_only)
    scenes = list(dict.fromkeys(a["scene"] for a in results["agreement"]))
    failed_scenes = [s for s in scenes if any(not a["passed"] for a in results["agreement"] if a["scene"] == s)]
    results.update(failed_scenes=failed_scenes, **stamp(["python -m benchmarks.crossval", *(argv or sys.argv[1:])]))
    if args.json:
        write_json(args.json, results)
    failed = failures(results)
    print(f"chi2: {sum(c['passed'] for c in results['chi2'])}/{len(results['chi2'])} passed; "
          f"furnace: {sum(c['passed'] for c in results['furnace'])}/{len(results['furnace'])}; "
          f"agreement: {sum(a['passed'] for a in results['agreement'])}/{len(results['agreement'])} "
          f"({len(scenes) - len(failed_scenes)}/{len(scenes)} scenes pass)")
    for line in failed:
        print("FAILED " + line, file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    from core import entry

    entry.finish(entry.run("python -m benchmarks.crossval", main))
