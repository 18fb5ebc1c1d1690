"""Writes the notebooks and runs them, so that they are stored with their outputs.

    python -m notebooks.build            # quick size: what is committed (about 2 minutes)
    python -m notebooks.build --full     # full size, same files (see FULL_RUNTIME: long)
    python -m notebooks.build --check    # run them without writing; fail on a missing figure

The notebooks call library functions only (the checks in ``validation.crossval``
and ``validation.convergence``, the plots and tables in ``benchmarks.crossval``
and ``benchmarks.error_vs_time``); ``NOTEBOOK_QUICK=1`` selects their small
settings. Cells tagged ``figure`` must show a plot: after a run each of them
must hold an ``image/png`` output (a figure shown as the text
``<Figure size ...>`` means the inline backend was lost), and every cell
checks the numbers and figures it shows with ``assert``.
"""
from __future__ import annotations

import argparse
import os
import re
import sys
import time
from pathlib import Path

if __name__ == "__main__":  # started by a Python without the project's packages: use ./.venv's
    from core.launcher import use_project_python
    use_project_python("python -m notebooks.build", "notebooks.build")

import tempfile

import nbformat
from nbformat.v4 import new_code_cell, new_markdown_cell, new_notebook

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
#: Full-size run time, measured with ``--full --check`` (README "Layout")
FULL_RUNTIME = {"crossval": "45 minutes of wall time on a 2-core machine shared with other jobs "
                            "(load average about 17; 13 minutes of CPU in the kernel)",
                "error_vs_time": "longer than crossval (see the README)"}
QUICK_SETTINGS = {"crossval": "4 materials × 3 angles; the last course scene and two of ours at 48² pixels",
                  "error_vs_time": "the last course scene and two of ours at 32² pixels"}


def _stored_note(name: str) -> str:
    return (f"*Stored with the outputs of `python -m notebooks.build` at the quick size "
            f"({QUICK_SETTINGS[name]}); CI re-runs it the same way. Run all cells in JupyterLab "
            f"(`./dev notebooks`) for the full size, with a progress bar: {FULL_RUNTIME[name]}.*")


SETUP = """%matplotlib inline
import os
QUICK = os.environ.get("NOTEBOOK_QUICK", "0") == "1"   # python -m notebooks.build and CI set it
from renderer.variants import set_variant
print("variant:", set_variant(None, quiet=True), "| size:", "quick" if QUICK else "full")
from IPython.display import Markdown, display
from notebooks.support import check_figure, counting, show"""


def _figure_cell(source: str):
    return new_code_cell(source, metadata={"tags": ["figure"]})


CROSSVAL = [
    new_markdown_cell("""# Cross-validation against Mitsuba's path tracer

Two checks that the renderer computes what it claims:

1. **The `phong` BSDF** samples directions with exactly the density its `pdf`
   reports (Mitsuba's own chi-square test, `mitsuba.chi2`), for shininess
   from 1 to 2000 and incident angles up to 85°, and its albedo, estimated
   with its own sampling, never exceeds 1 when `kd + ks ≤ 1`.
2. **The `whitted` integrator** agrees with Mitsuba's `path` integrator
   restricted to the same light paths (direct light from the point and
   directional lights with shadows, plus the ideal mirror weighted by `ks`:
   `phong` with `sampling="mirror"`), ambient 0 and a background that emits
   nothing. Both render with the same jittered pixel samples; the relative
   MSE between them must stay below twice the relative MSE between two path
   renders with different seeds.

""" + _stored_note("crossval")),
    new_code_cell(SETUP),
    new_code_cell("""from benchmarks.crossval import plot_agreement, plot_light_paths, summary_table
from course import root as course_root
from validation import crossval
materials, angles = (crossval.QUICK_MATERIALS, crossval.QUICK_ANGLES) if QUICK else (crossval.MATERIALS, crossval.ANGLES)
scenes = crossval.scene_paths(course_root(), quick=QUICK)
steps = 2 * len(materials) * len(angles) + len(scenes) * (3 * 2 if QUICK else 5 * 2)   # bounce counts x spps
with counting(crossval, ["chi2_case", "furnace_albedo", "agreement"], desc="cross-validation", total=steps):
    results = crossval.run(course_root(), quick=QUICK)
display(Markdown(summary_table(results)))
failed = crossval.failures(results)
# the criteria stated above, on the numbers in the table
assert not failed, failed
assert all(c["p_value"] >= 0.01 for c in results["chi2"])
assert all(f["albedo"] <= 1 + 4 * f["stderr"] for f in results["furnace"])
assert all(a["relmse_whitted_path"] <= 2 * a["relmse_path_path"] for a in results["agreement"])
print(f"all criteria hold: {len(results['chi2'])} chi-square cases, {len(results['furnace'])} furnace cases, "
      f"{len(results['agreement'])} whitted/path comparisons")"""),  # noqa: E501  the cell as stored in crossval.ipynb
    new_markdown_cell("""Where the scene has one light, whitted and the restricted path tracer compute
the same thing sample for sample (ratio ≈ 0). With several lights the path
tracer picks one light per sample, so it is noisier; the ratio is then about
0.5, since the two path renders carry that noise twice."""),
    _figure_cell("""figure = plot_agreement(results)
check_figure(figure, panels=len(results["settings"]["spp"]))
ratios = [a["relmse_whitted_path"] / a["relmse_path_path"] for a in results["agreement"]]
assert max(ratios) < 2, max(ratios)   # every point below the red line
show(figure)"""),
    new_markdown_cell("""## What Whitted leaves out

Whitted follows only mirror reflections and light arriving straight from
the lights. The full path tracer also samples the Phong lobes (glossy
inter-reflection, colour bleeding) and lets the background light the scene."""),
    _figure_cell("""for path in crossval.scene_paths(course_root(), quick=True):
    figure = plot_light_paths(path, size=64 if QUICK else 200, spp=16 if QUICK else 256)
    check_figure(figure, panels=3)
    show(figure)"""),
]

ERROR_VS_TIME = [
    new_markdown_cell("""# Error against run time

For each scene: relMSE and FLIP against a converged render of the same light
transport, as a function of wall time, for whitted with jittered
supersampling and for the full path tracer. On a log-log plot Monte Carlo
error falls with slope −1 once the fixed cost per render is small next to
the sampling; the dotted lines mark when each method reaches relMSE 1e-3.

""" + _stored_note("error_vs_time")),
    new_code_cell(SETUP),
    new_code_cell("""from benchmarks.error_vs_time import plot_scene, slope_table
from course import root as course_root
from validation import convergence
from validation.crossval import scene_paths
size, spps, reference = convergence.settings(QUICK)
paths = scene_paths(course_root(), quick=QUICK)
renders = len(paths) * sum(len(counts) + 1 for counts in spps.values())   # + 1: the reference
with counting(convergence, ["render_timed"], desc="renders", total=renders):
    results = convergence.measure(paths, size, spps, reference, progress=lambda line: None)
errors = [p["relmse"] for p in results["points"]]
assert all(0 < e < float("inf") for e in errors)
# more samples, less error: each curve's last point beats its first by the sample ratio, within 4x
for scene in dict.fromkeys(p["scene"] for p in results["points"]):
    for method, counts in spps.items():
        curve = [p for p in results["points"] if p["scene"] == scene and p["method"] == method]
        gain = curve[0]["relmse"] / curve[-1]["relmse"]
        assert gain > counts[-1] / counts[0] / 4, (scene, method, gain)
print(f"{len(results['points'])} renders of {len(paths)} scenes at {size}² pixels")"""),
    _figure_cell("""for scene in dict.fromkeys(p["scene"] for p in results["points"]):
    figure = plot_scene(results, scene)
    check_figure(figure, panels=2)
    show(figure)"""),
    new_markdown_cell("""Slopes over time are meaningful only where the sampling, not the fixed
cost of a render, dominates the time: at the full size. Over the sample
count they hold at any size: relMSE ∝ 1/spp is slope −1 on a log-log plot."""),
    new_code_cell("""import numpy as np
display(Markdown(slope_table(results)))
rows = ["| scene | method | slope of log relMSE over log spp |", "|---|---|---|"]
for s in results["slopes"]:
    curve = [p for p in results["points"] if p["scene"] == s["scene"] and p["method"] == s["method"]]
    over_spp = np.polyfit(np.log([p["spp"] for p in curve]), np.log([p["relmse"] for p in curve]), 1)[0]
    rows.append(f"| {s['scene']} | {s['method']} | {over_spp:.2f} |")
    assert -1.4 < over_spp < -0.6, (s["scene"], s["method"], over_spp)   # Monte Carlo: 1/spp
    if not QUICK:   # over time, once sampling dominates (NaN: too few renders above the fixed cost)
        assert s["slope"] != s["slope"] or -1.6 < s["slope"] < -0.6, s
display(Markdown("\\n".join(rows)))"""),
]

NOTEBOOKS = {"crossval": CROSSVAL, "error_vs_time": ERROR_VS_TIME}


def make(name: str) -> nbformat.NotebookNode:
    return new_notebook(cells=[nbformat.from_dict(c) for c in NOTEBOOKS[name]],
                        metadata={"kernelspec": {"name": "python3", "display_name": "Python 3",
                                                 "language": "python"},
                                  "language_info": {"name": "python"}})


def execute(notebook: nbformat.NotebookNode, quick: bool = True, timeout: int = 3600) -> nbformat.NotebookNode:
    """Runs ``notebook`` in a fresh kernel of this Python, in the project folder."""
    from jupyter_client import KernelManager  # noqa: PLC0415  jupyter_client loads on use: --help and the paths without it stay quick
    from nbclient import NotebookClient  # noqa: PLC0415  nbclient loads on use: --help and the paths without it stay quick

    os.environ["NOTEBOOK_QUICK"] = "1" if quick else "0"
    os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))
    with tempfile.TemporaryDirectory(prefix="notebook-kernel-") as sockets:
        # the kernel on local sockets, not TCP (no open port, no warning about one)
        kernel = KernelManager(kernel_name="python3", transport="ipc", ip=os.path.join(sockets, "kernel"))
        try:
            NotebookClient(notebook, km=kernel, timeout=timeout, allow_errors=True,
                           resources={"metadata": {"path": str(ROOT)}}).execute()
        finally:
            if kernel.has_kernel:
                kernel.shutdown_kernel()
    return notebook


def _as_a_terminal_shows(text: str) -> str:
    """Stream text with carriage-return redraws (progress bars) collapsed."""
    return "\n".join(re.split(r"\r+", line.rstrip("\r"))[-1] for line in text.split("\n"))


def tidy(notebook: nbformat.NotebookNode) -> nbformat.NotebookNode:
    """Outputs as a reader should see them: consecutive stream outputs merged,
    progress bars at their final state, no timings in the metadata."""
    for cell in notebook.cells:
        cell.metadata.pop("execution", None)
        merged = []
        for output in cell.get("outputs", []):
            if (output.output_type == "stream" and merged and merged[-1].output_type == "stream"
                    and merged[-1].name == output.name):
                merged[-1].text += output.text
            else:
                merged.append(output)
        for output in merged:
            if output.output_type == "stream":
                output.text = _as_a_terminal_shows(output.text)
        if cell.cell_type == "code":
            cell.outputs = [o for o in merged if o.output_type != "stream" or o.text.strip()]
    return notebook


def problems(notebook: nbformat.NotebookNode) -> list[str]:
    """Errors, and figure cells without an ``image/png`` output."""
    found = []
    for index, cell in enumerate(notebook.cells):
        if cell.cell_type != "code":
            continue
        for output in cell.outputs:
            if output.output_type == "error":
                found.append(f"cell {index}: {output.ename}: {output.evalue}")
        if "figure" in cell.metadata.get("tags", []):
            if not any("image/png" in output.get("data", {}) for output in cell.outputs):
                shown = [output.get("data", {}).get("text/plain", output.get("text", ""))[:60]
                         for output in cell.outputs]
                found.append(f"cell {index}: a figure cell without an image/png output (shows {shown})")
    return found


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m notebooks.build", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="example:\n  python -m notebooks.build --only crossval")
    parser.add_argument("--full", action="store_true", help="run at full size (default: the quick size)")
    parser.add_argument("--check", action="store_true", help="run, but write nothing (default: write)")
    parser.add_argument("--only", choices=sorted(NOTEBOOKS), action="append",
                        help="this notebook only (default: all)")
    args = parser.parse_args(argv)
    failed = False
    for name in args.only or NOTEBOOKS:
        start = time.perf_counter()
        notebook = tidy(execute(make(name), quick=not args.full))
        seconds = time.perf_counter() - start
        found = problems(notebook)
        for line in found:
            print(f"notebooks/{name}.ipynb: {line}", file=sys.stderr)
        failed |= bool(found)
        if not args.check and not found:
            nbformat.write(notebook, HERE / f"{name}.ipynb")
        print(f"notebooks/{name}.ipynb: {'full' if args.full else 'quick'} size, ran in {seconds:.0f} s"
              + ("" if args.check or found else ", written"), flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
