"""Regenerates the results pages docs/results/rendering.md and docs/results/validation.md from measurements.

    python -m benchmarks.report                     # runs the measurements below, then writes
    python -m benchmarks.report --steps crossval    # runs only some of them (comma-separated)
    python -m benchmarks.report --no-run            # only rewrites the pages from docs/'s JSON

Steps, each writing a JSON (with the machine, the date and the command) that
the sections are written from:

- ``course_images``: ``python -m benchmarks.course --record`` ->
  ``docs/validation/course_images.json``;
- ``crossval``: ``python -m benchmarks.crossval`` -> ``docs/validation/crossval.json``;
- ``crossval_power``: the same agreement check with whitted's shading biased by
  +1 % and -1 % (``--bias +-0.01 --agreement-only``), which must fail on every
  scene -> ``docs/validation/crossval_bias.json``;
- ``error_vs_time``: ``python -m benchmarks.error_vs_time`` ->
  ``docs/validation/error_vs_time.json`` and its plots;
- ``scalar_suite``: the fast test suite with the LLVM backend made unusable
  (``DRJIT_LIBLLVM_PATH`` at libLLVM 15), so image tests run on ``scalar_rgb``
  -> ``docs/validation/scalar_suite.json`` (its verdict: failures, required skips).

Render speed is not a step (it needs a quiet machine): run
``python -m benchmarks.render_speed --json docs/results/render_speed.json [--peer PATH]``,
then ``--no-run``. Every number on the two pages comes from these files; each page's
generated part is one section (``core.markdown.replace_section``).
"""
from __future__ import annotations

import datetime as dt
import json
import os
import subprocess
import sys
from pathlib import Path

# started as `python benchmarks/x.py`, this folder would shadow the course and denoise packages
if __name__ == "__main__" and not __package__:
    sys.path[0] = str(Path(__file__).resolve().parents[1])

if __name__ == "__main__":  # first: ./.venv's Python, the libLLVM, then Dr.Jit (see core.launcher)
    from core.launcher import start
    start("python -m benchmarks.report", "benchmarks.report" if __package__ else None)

import tempfile

from benchmarks import crossval, error_vs_time, render_speed
from benchmarks.course import record
from benchmarks.records import machine, write_json
from core.entry import ArgumentParser
from core.markdown import replace_section
from course import root as course_root
from imaging.metrics import MAX_BAD_FRACTION
from validation.crossval import FURNACE_SIGMAS

ROOT = Path(__file__).resolve().parent.parent

DOCS = ROOT / "docs" / "validation"
SPEED = ROOT / "docs" / "results" / "render_speed.json"
STEPS = ("course_images", "crossval", "crossval_power", "error_vs_time", "scalar_suite")
#: The pages this command writes, each one section of the same name
RENDERING_PAGE = ROOT / "docs" / "results" / "rendering.md"
VALIDATION_PAGE = ROOT / "docs" / "results" / "validation.md"
OLD_LLVM = "/usr/lib/x86_64-linux-gnu/libLLVM-15.so"


def stamp(command: str) -> dict:
    return {"command": command, "machine": machine(), "date": dt.date.today().isoformat()}


def _load(path: Path) -> dict | None:
    return json.loads(path.read_text()) if path.exists() else None


def run_scalar_suite(path: Path) -> dict:
    """The fast suite with no usable LLVM; its conftest writes the skip report.

    Only the verdict is kept (failures, required skips, exit status): test
    counts and durations change with every test and belong in the run's log."""
    env = dict(os.environ, DRJIT_LIBLLVM_PATH=OLD_LLVM if Path(OLD_LLVM).exists() else "/nonexistent/libLLVM-15.so",
               PYTEST_SKIP_REPORT=str(path))
    result = subprocess.run([sys.executable, "-m", "pytest", "-q", "-m", "not slow", "-p", "no:cacheprovider"],
                            cwd=ROOT, env=env)
    report = json.loads(path.read_text())
    data = {"variant": report["variant"], "failed": report["failed"], "required_skipped": report["required_skipped"],
            "exit_status": result.returncode, **stamp("DRJIT_LIBLLVM_PATH=libLLVM-15 python -m pytest -m 'not slow'")}
    write_json(path, data)
    return data


def run_power(path: Path, biases=(0.01, -0.01)) -> dict:
    """The full agreement check under an injected bias: which scenes fail."""
    runs = {}
    for bias in biases:
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "cv.json"
            crossval.main(["--bias", str(bias), "--agreement-only", "--json", str(out)])
            results = json.loads(out.read_text())
        scenes = list(dict.fromkeys(a["scene"] for a in results["agreement"]))
        runs[str(bias)] = {"scenes": len(scenes), "failed_scenes": results["failed_scenes"],
                           "failed_rows": sum(not a["passed"] for a in results["agreement"]),
                           "rows": len(results["agreement"])}
    data = {"runs": runs, **stamp("python -m benchmarks.crossval --bias +-0.01 --agreement-only")}
    write_json(path, data)
    return data


# -- sections ---------------------------------------------------------------------
def results_section(images: dict | None, speed: dict | None) -> str:
    lines = []
    if images:
        counts = images["images"]
        worst = sorted(counts.items(), key=lambda kv: -kv[1]["bad"])
        rest = max(c["bad"] for _, c in worst[2:]) if len(worst) > 2 else 0
        lines += [f"All {len(counts)} images of `sample_out`, rendered through `render.py` with the course's "
                  f"command lines (`{images['command']}`, {images['variant']}, {images['machine']}, "
                  f"{images['date']}): pixels more than {images['tolerance']}/255 off — "
                  + ", ".join(f"`{name}` {c['bad']} ({100 * c['bad'] / c['pixels']:.3f} %)" for name, c in worst[:2])
                  + f", the other {len(worst) - 2} at most {rest} each (the course's bar is "
                  f"{100 * MAX_BAD_FRACTION:g} %). `tests/test_course_images.py` fails an image over that bar "
                  "or over twice its count here (+10 pixels). The slow tests compare `scalar_rgb` with "
                  "`llvm_ad_rgb` at 200×200 on all seven scenes; our scenes (`scenes/`) are compared with an "
                  "independent NumPy implementation of the course's semantics (`validation/reference_tracer.py`).",
                  ""]
    if speed and "machine" in speed:
        lines += [f"`{speed['command']}`: the course's {len(speed['scenes'])} command lines at their sizes, "
                  f"{speed['scenes'][0]['variant']}, "
                  f"{speed['machine']}, {speed['date']}, medians of {speed['repeat']}. Process times are whole "
                  "processes from start to exit"
                  + (", ours and the peer binary's interleaved in the same run" if "peer" in speed else
                     " (no peer binary was given, so there is no course column)")
                  + "; render times are `mi.render` inside a warm process and not comparable with them; "
                  "`direct` takes as many emitter samples as the scene has lights, each to a light picked at "
                  "random.", "", render_speed.report(speed), ""]
    else:
        lines += ["Render speed: not measured in this form yet (run `python -m benchmarks.render_speed --json "
                  "docs/results/render_speed.json [--peer PATH]` on a quiet machine, then "
                  "`python -m benchmarks.report --no-run`).", ""]
    return "\n".join(lines)


def validation_section(cv: dict, evt: dict | None, suite: dict | None) -> str:
    chi2, furnace, agreement = cv["chi2"], cv["furnace"], cv["agreement"]
    settings = cv["settings"]
    materials = ", ".join(dict.fromkeys("{}/{}/{:g}".format(c["kd"], c["ks"], c["shininess"]) for c in chi2))
    angles = ", ".join(f"{a:g}°" for a in sorted({c["theta_deg"] for c in chi2}))
    lines = ["Regenerate with `python -m benchmarks.report` (each paragraph names its command, machine and "
             "date). Raw numbers in `docs/validation/`; the notebooks `notebooks/crossval.ipynb` and "
             "`notebooks/error_vs_time.ipynb` show the same with explanations.", "",
             f"`{cv['command']}` ({settings['variant']}, {cv['machine']}, {cv['date']}):", "",
             f"**phong BSDF.** Mitsuba's chi-square test (`mitsuba.chi2`, {settings['chi2_samples']:,} samples, "
             f"1 % significance): {sum(c['passed'] for c in chi2)}/{len(chi2)} cases pass (kd/ks/shininess "
             f"{materials}; θi ∈ {{{angles}}}); lowest p-value {min(c['p_value'] for c in chi2):.3f}. "
             f"Two-sided white furnace (albedo from the BSDF's own sampling against the model's formula "
             f"integrated by quadrature, within {FURNACE_SIGMAS:g} standard errors): "
             f"{sum(f['passed'] for f in furnace)}/{len(furnace)} pass, largest |z| "
             f"{max(abs(f['z']) for f in furnace):.2f}.", "",
             f"**whitted vs Mitsuba's path tracer** restricted to Whitted's light paths (ambient 0, no "
             f"background light, {settings['image_size']}² pixels, bounces "
             f"{', '.join(map(str, settings['bounces']))}, the same jittered pixel samples): a row passes when no "
             f"{settings['tile']}×{settings['tile']} tile nor the whole image, in any channel, has a mean "
             f"difference beyond its Bonferroni-corrected {100 * settings['significance']:g} % bound (|z|), and "
             f"relMSE(whitted, path) ≤ 2 × relMSE(path, path′). {sum(a['passed'] for a in agreement)}/"
             f"{len(agreement)} rows pass. Per scene, the largest |z| / its bound and the measured bias "
             "mean(whitted)/mean(path) − 1:", "",
             "| scene | " + " | ".join(f"max abs z / bound, {spp} spp" for spp in settings["spp"])
             + f" | bias at {max(settings['spp'])} spp, 4 bounces | passed |",
             "|---|" + "---|" * (len(settings["spp"]) + 2)]
    for scene in dict.fromkeys(a["scene"] for a in agreement):
        cells = []
        for spp in settings["spp"]:
            rows = [a for a in agreement if a["scene"] == scene and a["spp"] == spp]
            cells.append(f"{max(a['max_abs_z'] / a['z_critical'] for a in rows):.2f}")
        deepest = max((a for a in agreement if a["scene"] == scene and a["spp"] == max(settings["spp"])),
                      key=lambda a: a["bounces"])
        ok = all(a["passed"] for a in agreement if a["scene"] == scene)
        lines.append(f"| {scene} | " + " | ".join(cells)
                     + f" | {round(100 * deepest['relative_bias'], 3) + 0.0:+.3f} ± "
                     f"{100 * deepest['relative_bias_stderr']:.3f} % | {'yes' if ok else 'NO'} |")
    power = _load(DOCS / "crossval_bias.json")
    if power:
        lines += ["", f"Power: with whitted's shading scaled by 1 ± 1 % (`{power['command']}`, {power['date']}), "
                  + "; ".join(f"{'+' if b > 0 else '−'}1 %: {len(r['failed_scenes'])}/{r['scenes']} scenes and "
                              f"{r['failed_rows']}/{r['rows']} rows fail"
                              for b, r in sorted(((float(k), v) for k, v in power["runs"].items()), reverse=True))
                  + ". `tests/test_mutations.py` checks the same in CI (±3 % on the quick set, ±1 % on every "
                  "scene at 48², 256 spp)."]
    if evt:
        lines += ["", f"**Error against time** (`{evt.get('command', 'python -m benchmarks.error_vs_time')}`, "
                  f"{evt.get('variant', '')}, {evt.get('machine', '?')}, {evt.get('date', '?')}; "
                  f"{evt['settings']['image_size']}² pixels): whitted 1–{max(evt['settings']['spp']['whitted'])} "
                  f"spp and the path tracer on the same light paths 1–{max(evt['settings']['spp']['path'])} spp, "
                  f"both against one reference (whitted, {evt['settings']['reference_spp']} spp, another seed). "
                  "Slopes of log relMSE over log seconds and over log spp, fitted over the upper half of each "
                  "spp ladder (a rule fixed before measuring), and the time to relMSE 1e-3:", "",
                  error_vs_time.slope_table(evt), ""]
        scenes = list(dict.fromkeys(p["scene"] for p in evt["points"]))
        lines += [" ".join(f'<img src="../validation/{s}.png" width="49%" alt="{s}">' for s in scenes)]
    if suite:
        verdict = ("every test passed and no required test was skipped"
                   if not suite["failed"] and not suite["required_skipped"] and not suite.get("exit_status")
                   else "FAILED: tests failed or required tests were skipped (counts in the JSON and CI's log)")
        lines += ["", f"**Without a usable LLVM** (`{suite['command']}`, {suite['machine']}, {suite['date']}): "
                  f"image tests run on {suite['variant']}; {verdict}."]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog="python -m benchmarks.report", description=__doc__.split("\n\n")[0])
    parser.add_argument("--no-run", action="store_true", help="only rewrite the pages from docs/'s JSON")
    parser.add_argument("--steps", default=",".join(STEPS), help=f"comma-separated, of {', '.join(STEPS)}")
    args = parser.parse_args(argv)
    steps = [] if args.no_run else [s for s in args.steps.split(",") if s]
    unknown = set(steps) - set(STEPS)
    if unknown:
        parser.error(f"unknown steps: {', '.join(sorted(unknown))}")
    os.chdir(ROOT)  # the commands recorded in docs/ name paths relative to the checkout
    if "course_images" in steps:
        record(course_root(), None)
    if "crossval" in steps:
        if crossval.main(["--json", str(DOCS / "crossval.json")]) != 0:
            print("report: crossval criteria failed; the section shows which", file=sys.stderr)
    if "crossval_power" in steps:
        run_power(DOCS / "crossval_bias.json")
    if "error_vs_time" in steps:
        error_vs_time.main(["--json", str((DOCS / "error_vs_time.json").relative_to(ROOT)),
                            "--out", str(DOCS.relative_to(ROOT))])
    if "scalar_suite" in steps:
        run_scalar_suite(DOCS / "scalar_suite.json")

    cv, evt = _load(DOCS / "crossval.json"), _load(DOCS / "error_vs_time.json")
    if evt and "spp_slope" not in evt["slopes"][0]:
        evt = None  # measured against separate references by an older version: not shown
    print(replace_section(RENDERING_PAGE, "rendering",
                          results_section(_load(DOCS / "course_images.json"), _load(SPEED))))
    if cv and "machine" in cv:
        print(replace_section(VALIDATION_PAGE, "validation",
                              validation_section(cv, evt, _load(DOCS / "scalar_suite.json"))))
    return 0


if __name__ == "__main__":
    from core import entry

    entry.finish(entry.run("python -m benchmarks.report", main))
