"""Writes the notebooks (no outputs): ``python notebooks/make_notebooks.py``.

The notebooks only call library functions (``benchmarks.crossval``,
``benchmarks.error_vs_time``); with ``NOTEBOOK_QUICK=1`` they run the small
versions (as CI does).
"""
from pathlib import Path

import nbformat
from nbformat.v4 import new_code_cell, new_markdown_cell, new_notebook

HERE = Path(__file__).resolve().parent
SETUP = """import os
QUICK = os.environ.get("NOTEBOOK_QUICK", "0") == "1"   # CI sets NOTEBOOK_QUICK=1
from renderer.variants import set_variant
print("variant:", set_variant(None))
from IPython.display import Markdown, display"""

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
   renders with different seeds."""),
    new_code_cell(SETUP),
    new_code_cell("""from benchmarks import crossval
results = crossval.run(crossval.DEFAULT_COURSE, quick=QUICK)
failed = crossval.failures(results)
print("all criteria hold" if not failed else "\\n".join(failed))
display(Markdown(crossval.summary_table(results)))"""),
    new_markdown_cell("""Where the scene has one light, whitted and the restricted path tracer compute
the same thing sample for sample (ratio ≈ 0). With several lights the path
tracer picks one light per sample, so it is noisier; the ratio is then about
0.5, since the two path renders carry that noise twice."""),
    new_code_cell("crossval.plot_agreement(results)"),
    new_markdown_cell("""## What Whitted leaves out

Whitted follows only mirror reflections and light arriving straight from
the lights. The full path tracer also samples the Phong lobes (glossy
inter-reflection, colour bleeding) and lets the background light the scene."""),
    new_code_cell("""for path in crossval.scene_paths(crossval.DEFAULT_COURSE, quick=True):
    display(crossval.plot_light_paths(path, size=64 if QUICK else 200, spp=16 if QUICK else 256))"""),
]

ERROR_VS_TIME = [
    new_markdown_cell("""# Error against run time

For each scene: relMSE and FLIP against a converged render of the same light
transport, as a function of wall time, for whitted with jittered
supersampling and for the full path tracer. On a log-log plot Monte Carlo
error falls with slope −1 once the fixed cost per render is small next to
the sampling; the dotted lines mark when each method reaches relMSE 1e-3."""),
    new_code_cell(SETUP),
    new_code_cell("""from benchmarks import error_vs_time as evt
from benchmarks.crossval import scene_paths, DEFAULT_COURSE
size, spps, reference = evt.settings(QUICK)
results = evt.measure(scene_paths(DEFAULT_COURSE, quick=QUICK), size, spps, reference)"""),
    new_code_cell("""for scene in dict.fromkeys(p["scene"] for p in results["points"]):
    display(evt.plot_scene(results, scene))"""),
    new_code_cell("""display(Markdown(evt.slope_table(results)))"""),
]


def write(name: str, cells) -> None:
    notebook = new_notebook(cells=cells, metadata={"kernelspec": {"name": "python3", "display_name": "Python 3",
                                                                  "language": "python"}})
    nbformat.write(notebook, HERE / name)


if __name__ == "__main__":
    write("crossval.ipynb", CROSSVAL)
    write("error_vs_time.ipynb", ERROR_VS_TIME)
