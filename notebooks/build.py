"""Writes the notebooks and runs them, so that they are stored with their outputs.

    python -m notebooks.build            # full size: what is stored (long: docs/notebooks.md)
    python -m notebooks.build --quick    # quick size (what CI runs, in a scratch copy)
    python -m notebooks.build --check    # run them without writing; fail on a missing figure
    python -m notebooks.build --out DIR  # write into DIR instead of notebooks/

The notebooks call library functions only (the checks in ``validation.crossval``,
``validation.convergence`` and ``validation.inverse_rendering``, the plots and
tables in ``benchmarks.crossval``, ``benchmarks.error_vs_time`` and
``notebooks.figures``); ``NOTEBOOK_QUICK=1`` selects their small settings.
Cells tagged ``figure`` must show a plot: after a run each of them must hold
an ``image/png`` output (a figure shown as the text ``<Figure size ...>``
means the inline backend was lost), and every cell checks the numbers and
figures it shows with ``assert``. A written notebook records its size in its
metadata (``notebooks_build``), and is written atomically.
"""
from __future__ import annotations

if __name__ == "__main__":  # first: ./.venv's Python, the libLLVM, then Dr.Jit (see core.launcher)
    from core.launcher import start
    start("python -m notebooks.build", "notebooks.build")

import argparse
import os
import re
import sys
import tempfile
import time
from pathlib import Path

import nbformat
from nbformat.v4 import new_code_cell, new_markdown_cell, new_notebook

from core.entry import ArgumentParser
from core.errors import OutputError, write_failure
from imaging.image_io import atomic_path

PROG = "python -m notebooks.build"

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
#: the metadata key of a written notebook: {"size": "full" or "quick"}
METADATA = "notebooks_build"
FULL_SETTINGS = {
    "crossval": "the BSDF checks in full; the agreement and the images of three scenes at 200×200 pixels",
    "error_vs_time": "three scenes at 200×200 pixels, whitted 1–1024 spp, path 1–4096 spp, "
                     "a 16384-spp reference, each render timed three times",
    "inverse_rendering": "200×200 pixels, 300 steps"}


def _stored_note(name: str) -> str:
    return (f"*Stored with the outputs of `python -m notebooks.build`, at the full size "
            f"({FULL_SETTINGS[name]}; its run time is in `docs/notebooks.md`); CI re-runs it at a quick "
            f"size in a scratch copy. Run all cells in JupyterLab (`./dev notebooks`) for the full "
            f"size, with a progress bar.*")


SETUP = """%matplotlib inline
import os
QUICK = os.environ.get("NOTEBOOK_QUICK", "0") == "1"   # python -m notebooks.build --quick and CI set it
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
   with its own sampling, agrees with the model's formula integrated
   independently (a white furnace).
2. **The `whitted` integrator** agrees with Mitsuba's `path` integrator
   restricted to the same light paths (direct light from the point and
   directional lights with shadows, plus the ideal mirror weighted by `ks`:
   `phong` with `sampling="mirror"`), ambient 0 and a background that emits
   nothing. Both render with the same jittered pixel samples; no 16×16 tile
   may have a mean difference beyond its standard error's bound, and the
   relative MSE between them must stay below twice the relative MSE between
   two path renders with different seeds.

Here the agreement runs on three scenes (the last course scene: two lights,
mirrors, shadows; `lamps`: three lights; `mirrors`: one);
`python -m benchmarks.crossval` runs it on every scene.

""" + _stored_note("crossval")),
    new_code_cell(SETUP),
    new_code_cell("""from benchmarks.crossval import plot_agreement, summary_table
from course import root as course_root
from validation import crossval
materials, angles = (crossval.QUICK_MATERIALS, crossval.QUICK_ANGLES) if QUICK else (crossval.MATERIALS, crossval.ANGLES)
size, spps, bounce_list = (48, [16, 64], [0, 2, 4]) if QUICK else (200, [64, 1024], [0, 2, 4])
scenes = crossval.scene_paths(course_root(), quick=True)
steps = 2 * len(materials) * len(angles) + len(scenes) * len(bounce_list) * len(spps)
with counting(crossval, ["chi2_case", "furnace_case", "agreement"], desc="cross-validation", total=steps):
    results = crossval.run(course_root(), quick=QUICK, size=size, spps=spps, bounce_list=bounce_list, paths=scenes)
display(Markdown(summary_table(results)))
failed = crossval.failures(results)
# the criteria stated above, on the numbers in the table
assert not failed, failed
assert all(c["p_value"] >= 0.01 for c in results["chi2"])
assert all(abs(f["z"]) <= crossval.FURNACE_SIGMAS for f in results["furnace"])
assert all(a["max_abs_z"] <= a["z_critical"] for a in results["agreement"])
assert all(a["relmse_whitted_path"] <= 2 * a["relmse_path_path"] for a in results["agreement"])
print(f"all criteria hold: {len(results['chi2'])} chi-square cases, {len(results['furnace'])} furnace cases, "
      f"{len(results['agreement'])} whitted/path comparisons at {size}×{size} pixels, {' and '.join(map(str, spps))} spp")"""),
    new_markdown_cell("""Where the scene has one light, whitted and the restricted path tracer compute
the same thing sample for sample (ratio ≈ 0). With several lights the path
tracer picks one light per sample, so it is noisier; the ratio is then about
0.5, since the two path renders carry that noise twice."""),
    _figure_cell("""figure = plot_agreement(results)
check_figure(figure, panels=len(results["settings"]["spp"]))
ratios = [a["relmse_whitted_path"] / a["relmse_path_path"] for a in results["agreement"]]
assert max(ratios) < 2, max(ratios)   # every point below the red line
show(figure)"""),
    new_markdown_cell("""## The images, and what Whitted leaves out

Per scene: whitted, the path tracer on Whitted's light paths with the same
pixel samples, their difference, and the full path tracer. The difference
has no structure, only noise: where one light shines (`mirrors`) the two
are the same image; with several lights the path tracer's choice of one
light per sample is noise of both signs. Its mean over the image is
printed with its standard error; a bias (a missing factor, a wrong
falloff) would be a coloured region, and a mean many standard errors from 0.

The full path tracer also samples the Phong lobes (glossy inter-reflection,
colour bleeding) and lets the background light the scene: that is what
Whitted's light paths leave out."""),
    _figure_cell("""from notebooks.figures import plot_whitted_path_difference, whitted_path_difference
size, spp = (64, 16) if QUICK else (200, 256)
for path in scenes:
    renders = whitted_path_difference(path, size, spp)
    mean, error = renders["relative_mean"], renders["relative_stderr"]
    print(f"{path.stem}: {size}×{size} pixels, {spp} spp: mean of whitted − path {100 * mean:+.3f} ± {100 * error:.3f} % "
          f"of path's mean")
    assert abs(mean) <= 4 * error + 1e-6, (path.stem, mean, error)   # no bias: within 4 standard errors
    figure = plot_whitted_path_difference(renders)
    check_figure(figure, panels=4)
    show(figure)"""),
]

ERROR_VS_TIME = [
    new_markdown_cell("""# Error against run time

For each scene: relMSE and FLIP against a converged render of the same light
transport, as a function of wall time, for whitted with jittered
supersampling and for the path tracer on Whitted's light paths. On a
log-log plot Monte Carlo error falls with slope −1 once the fixed cost per
render is small next to the sampling; the dotted lines mark when each
method reaches relMSE 1e-3.

At the full size the curves span more than two decades of time, and the
reference has 16 times the samples of whitted's last point, so that its own
noise hardly bends the curves (relMSE against a reference of N samples is
about σ²/n + σ²/N). Each render is timed three times and its time is the
median: the machine is shared with other jobs, and one timing may catch a
burst of their load.

""" + _stored_note("error_vs_time")),
    new_code_cell(SETUP),
    new_code_cell("""from benchmarks.error_vs_time import plot_scene, slope_table
from course import root as course_root
from notebooks.support import retimed
from validation import convergence
from validation.crossval import scene_paths
if QUICK:
    size, spps, reference = convergence.settings(QUICK)
else:
    size, spps, reference = 200, {"whitted": [2 ** k for k in range(11)], "path": [4 ** k for k in range(7)]}, 16384
paths = scene_paths(course_root(), quick=True)
repeats = 1 if QUICK else 2   # each render timed again: its time is the median (this machine is shared)
renders = len(paths) * (1 + sum(len(counts) * (1 + repeats) for counts in spps.values()))   # 1: the reference
with counting(convergence, ["render_timed"], desc="renders", total=renders):
    results = retimed(convergence.measure(paths, size, spps, reference, progress=lambda line: None), paths, repeats)
errors = [p["relmse"] for p in results["points"]]
assert all(0 < e < float("inf") for e in errors)
# more samples, less error: each curve's last point beats its first by the sample ratio, within 4x
for scene in dict.fromkeys(p["scene"] for p in results["points"]):
    for method, counts in spps.items():
        curve = [p for p in results["points"] if p["scene"] == scene and p["method"] == method]
        gain = curve[0]["relmse"] / curve[-1]["relmse"]
        assert gain > counts[-1] / counts[0] / 4, (scene, method, gain)
print(f"{len(results['points'])} renders of {len(paths)} scenes at {size}×{size} pixels, reference {reference} spp")"""),
    _figure_cell("""for scene in dict.fromkeys(p["scene"] for p in results["points"]):
    figure = plot_scene(results, scene)
    check_figure(figure, panels=2)
    show(figure)"""),
    new_markdown_cell("""Slopes over time are meaningful only where the sampling, not the fixed
cost of a render, dominates the time: at the full size. The fit takes the
upper half of each curve's spp ladder (`validation.convergence`'s rule,
fixed before any data was taken); the interval is the slope's 95 %
confidence interval of that least-squares fit. Over the sample count the
slope holds at any size: relMSE ∝ 1/spp is slope −1 on a log-log plot."""),
    new_code_cell("""import math
import numpy as np
from notebooks.figures import slope_interval
display(Markdown(slope_table(results)))
rows = ["| scene | method | slope over log seconds [95 % interval] | decades of time (curve) | slope over log spp |",
        "|---|---|---|---|---|"]
for s in results["slopes"]:
    curve = [p for p in results["points"] if p["scene"] == s["scene"] and p["method"] == s["method"]]
    slope, low, high = slope_interval(curve)
    decades = math.log10(max(p["seconds"] for p in curve) / min(p["seconds"] for p in curve))
    over_spp = np.polyfit(np.log([p["spp"] for p in curve]), np.log([p["relmse"] for p in curve]), 1)[0]
    rows.append(f"| {s['scene']} | {s['method']} | {slope:.3f} [{low:.3f}, {high:.3f}] | {decades:.1f} | {over_spp:.3f} |")
    assert abs(slope - s["slope"]) < 1e-9   # the same fit as the library's
    assert -1.4 < over_spp < -0.6, (s["scene"], s["method"], over_spp)   # Monte Carlo: 1/spp
    if not QUICK:   # over time, once sampling dominates
        assert decades >= 2, (s["scene"], s["method"], decades)
        assert abs(slope + 1) <= 0.15, (s["scene"], s["method"], slope)
display(Markdown("\\n".join(rows)))"""),
]

INVERSE_RENDERING = [
    new_markdown_cell("""# Inverse rendering: a material and a light from one image

The `whitted` integrator is differentiable: `mi.render(scene, params)`
records how each pixel depends on the scene's parameters, and `dr.backward`
sends the gradient of a loss back to them. Here that recovers, from a
target image alone, the Phong material of a sphere (`kd` and `ks` per
colour channel, the shininess `s`) and the position of the point light,
starting from a grey material with a broad highlight and the light
elsewhere. The floor's material and the light's colour are known.

The loop is that of Mitsuba's inverse-rendering tutorials, in
`validation.inverse_rendering.fit_material_and_light`:

```python
params = mi.traverse(scene)
opt = mi.ad.Adam(lr=...)
opt[key] = params[key]          # for each fitted parameter (s: its logarithm)
params.update(opt)
for step in range(steps):
    image = mi.render(scene, params, spp=1)
    loss = dr.mean(dr.square(image - target), axis=None)
    dr.backward(loss)           # through whitted's shading and phong's eval
    opt.step()
    params.update(opt)
```

Pixels are sampled at their centres, so the renders have no noise and the
loss can reach 0. Recovered means: every colour channel and `s` within 2 %
of the truth, the light within 1 % of the scene's size (how far the camera
looks: `converters.description.view_scale`).

""" + _stored_note("inverse_rendering")),
    new_code_cell(SETUP),
    new_code_cell("""import mitsuba as mi
import numpy as np
from notebooks.support import progress_bar
from validation import inverse_rendering as ir
size, steps = (64, 300) if QUICK else (200, 300)
scene = ir.make_scene(size)
params = mi.traverse(scene)
keys = ir.parameter_keys(scene, params)
display(Markdown("Fitted parameters and their `mi.traverse` keys: " + ", ".join(f"{name} `{key}`" for name, key in keys.items())))
assert max(ir.parameter_errors(ir.read_parameters(scene, params)).values()) < 1e-6   # the scene holds the truth
target = ir.render(scene)
ir.write_parameters(scene, params, ir.START)
start_image = ir.render(scene)
print(f"target and start: {size}×{size} pixels; mean squared difference at the start {np.mean((start_image - target) ** 2):.3g}; "
      f"scene size {ir.scene_size():.3f}")"""),
    new_code_cell("""bar = progress_bar(steps, "gradient descent")
history = ir.fit_material_and_light(scene, target, iterations=steps, progress=lambda step: bar.update())
bar.close()
fitted, errors, within = history[-1], ir.parameter_errors(history[-1]), ir.recovered(history[-1])
def shown(value):
    return ", ".join(f"{v:.4f}" for v in value) if isinstance(value, list) else f"{value:.4f}"
rows = ["| parameter | truth | start | fitted | error | tolerance | recovered |", "|---|---|---|---|---|---|---|"]
for name, tolerance in ir.TOLERANCE.items():
    unit = "of the scene's size" if name == "light" else "relative"
    rows.append(f"| {name} | {shown(ir.TRUTH[name])} | {shown(ir.START[name])} | {shown(fitted[name])} | "
                f"{100 * errors[name]:.3g} % | {100 * tolerance:g} % {unit} | {'yes' if within[name] else 'NO'} |")
display(Markdown("\\n".join(rows)))
assert all(within.values()), errors
assert fitted["loss"] < 1e-4 * history[0]["loss"], (history[0]["loss"], fitted["loss"])
print(f"{steps} steps: loss {history[0]['loss']:.3g} -> {fitted['loss']:.3g}")"""),
    _figure_cell("""from notebooks.figures import plot_fit, plot_images
figure = plot_fit(history)
check_figure(figure, panels=3)
show(figure)"""),
    new_markdown_cell("""The start, the fit and the target; how far the start was from the target,
and the fit's remaining difference magnified a hundred times (black: none)."""),
    _figure_cell("""fitted_image = ir.render(scene)
difference = np.abs(fitted_image - target)
figure = plot_images({"start": start_image, "fitted": fitted_image, "target (the truth)": target,
                      "|start − target|": np.abs(start_image - target), "|fitted − target| × 100": 100 * difference})
check_figure(figure, panels=5)
assert difference.max() < 0.01 * target.max(), difference.max()
print(f"{size}×{size} pixels: largest difference after the fit {difference.max():.2g} (target's largest value {target.max():.3g})")
show(figure)"""),
    new_markdown_cell("""A parameter whose derivative is lost (`dr.detach` on it inside the BSDF)
stays where it started while the others try to make up for it, and the
fit misses the tolerances: `tests/test_inverse_rendering.py` checks that."""),
]

NOTEBOOKS = {"crossval": CROSSVAL, "error_vs_time": ERROR_VS_TIME, "inverse_rendering": INVERSE_RENDERING}


def make(name: str) -> nbformat.NotebookNode:
    return new_notebook(cells=[nbformat.from_dict(c) for c in NOTEBOOKS[name]],
                        metadata={"kernelspec": {"name": "python3", "display_name": "Python 3",
                                                 "language": "python"},
                                  "language_info": {"name": "python"}})


def execute(notebook: nbformat.NotebookNode, quick: bool = True, timeout: int = 3600) -> nbformat.NotebookNode:
    """Runs ``notebook`` in a fresh kernel of this Python, in the project folder."""
    from jupyter_client import KernelManager  # noqa: PLC0415  only where notebooks run (not for --help)
    from nbclient import NotebookClient  # noqa: PLC0415  as above

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


def write(notebook: nbformat.NotebookNode, path: Path, size: str) -> None:
    """Writes ``notebook`` to ``path`` atomically (a full disk leaves the old file
    as it was), its size recorded in its metadata under :data:`METADATA`."""
    notebook.metadata[METADATA] = {"size": size}
    with atomic_path(path, ".ipynb") as tmp:
        try:
            nbformat.write(notebook, tmp)
        except OSError as error:
            raise OutputError(f"{path}: cannot write: {write_failure(error)}") from None


def stored_size(notebook: nbformat.NotebookNode) -> str | None:
    """The size a written notebook was run at ("full" or "quick"; None: not written by build)."""
    return notebook.metadata.get(METADATA, {}).get("size")


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0],
                            formatter_class=argparse.RawDescriptionHelpFormatter,
                            epilog="example:\n  python -m notebooks.build --only crossval")
    parser.add_argument("--quick", action="store_true",
                        help="run at the quick size (default: full, what is stored)")
    parser.add_argument("--check", action="store_true", help="run, but write nothing (default: write)")
    parser.add_argument("--out", type=Path, default=HERE, metavar="DIR",
                        help="folder to write the notebooks into (default: notebooks/)")
    parser.add_argument("--only", choices=sorted(NOTEBOOKS), action="append",
                        help="this notebook only (default: all)")
    args = parser.parse_args(argv)
    size = "quick" if args.quick else "full"
    failed = False
    for name in args.only or NOTEBOOKS:
        start = time.perf_counter()
        notebook = tidy(execute(make(name), quick=args.quick))
        seconds = time.perf_counter() - start
        found = problems(notebook)
        for line in found:
            print(f"notebooks/{name}.ipynb: {line}", file=sys.stderr)
        failed |= bool(found)
        target = args.out / f"{name}.ipynb"
        if not args.check and not found:
            write(notebook, target, size)
        print(f"{target}: {size} size, ran in {seconds:.0f} s" + ("" if args.check or found else ", written"),
              flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    from core import entry

    entry.finish(entry.run(PROG, main))
