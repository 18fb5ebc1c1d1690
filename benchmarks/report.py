"""Regenerates the README's "Validation" section.

    python -m benchmarks.report            # runs crossval and error_vs_time (full), then writes
    python -m benchmarks.report --no-run   # only rewrites the section from docs/validation/*.json

Results, plots and the machine and date they came from live in
``docs/validation/``; the README section between the ``validation`` markers
is replaced.
"""
from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
import re
import sys
from pathlib import Path

from benchmarks import crossval, error_vs_time, write_json
from benchmarks.course import ROOT

DOCS = ROOT / "docs" / "validation"
START, END = "<!-- validation:start -->", "<!-- validation:end -->"


def machine() -> str:
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{model}, {os.cpu_count()} cores, {platform.system()} {platform.release()}, Python {platform.python_version()}"


def section(cv: dict, evt: dict, meta: dict) -> str:
    chi2, furnace, agreement = cv["chi2"], cv["furnace"], cv["agreement"]
    materials = ", ".join(dict.fromkeys("{}/{}/{:g}".format(c["kd"], c["ks"], c["shininess"]) for c in chi2))
    angles = ", ".join("{:g}°".format(a) for a in sorted({c["theta_deg"] for c in chi2}))
    lines = [START, "## Validation", "",
             f"Regenerate with `python -m benchmarks.report` (numbers below: {meta['machine']}; {meta['date']}; "
             f"variant {meta['variant']}). Raw numbers in `docs/validation/`; the notebooks "
             "`notebooks/crossval.ipynb` and `notebooks/error_vs_time.ipynb` show the same with explanations.", "",
             f"**phong BSDF.** Mitsuba's chi-square test (`mitsuba.chi2`, 10⁶ samples, 1 % significance): "
             f"{sum(c['passed'] for c in chi2)}/{len(chi2)} cases pass (kd/ks/shininess {materials}; "
             f"θi ∈ {{{angles}}}); lowest p-value {min(c['p_value'] for c in chi2):.3f}. White furnace: highest "
             f"albedo {max(f['albedo'] for f in furnace):.4f} (all ≤ 1 within 4 standard errors: "
             f"{'yes' if all(f['passed'] for f in furnace) else 'NO'}).", "",
             f"**whitted vs Mitsuba's path tracer** restricted to Whitted's light paths (ambient 0, no "
             f"background light, {cv['settings']['image_size']}² pixels, bounces "
             f"{', '.join(map(str, cv['settings']['bounces']))}): criterion relMSE(whitted, path) ≤ 2 × "
             f"relMSE(path, path′); {sum(a['passed'] for a in agreement)}/{len(agreement)} pass. "
             "Largest ratio per scene:", "",
             "| scene | " + " | ".join(f"ratio at {spp} spp" for spp in cv["settings"]["spp"]) + " | passed |",
             "|---|" + "---|" * (len(cv["settings"]["spp"]) + 1)]
    for scene in dict.fromkeys(a["scene"] for a in agreement):
        cells = []
        for spp in cv["settings"]["spp"]:
            rows = [a for a in agreement if a["scene"] == scene and a["spp"] == spp]
            cells.append(f"{max(a['relmse_whitted_path'] / a['relmse_path_path'] for a in rows):.2f}")
        ok = all(a["passed"] for a in agreement if a["scene"] == scene)
        lines.append(f"| {scene} | " + " | ".join(cells) + f" | {'yes' if ok else 'NO'} |")
    lines += ["", "Ratios near 0: one light, the two compute the same samples; near 0.5: several lights, "
              "which the path tracer samples one at a time.", "",
              f"**Error against time** ({evt['settings']['image_size']}² pixels; whitted 1–"
              f"{max(evt['settings']['spp']['whitted'])} spp jittered, the full path tracer 1–"
              f"{max(evt['settings']['spp']['path'])} spp; references at "
              f"{evt['settings']['reference_spp']['whitted']} and {evt['settings']['reference_spp']['path']} spp). "
              "Slope of log relMSE over log time (fitted over the renders that take at least 3× the quickest, where sampling, not fixed cost, dominates) and the time each needs to reach relMSE "
              "1e-3:", "", error_vs_time.slope_table(evt), ""]
    scenes = list(dict.fromkeys(p["scene"] for p in evt["points"]))
    lines += [" ".join(f'<img src="docs/validation/{s}.png" width="49%" alt="{s}">' for s in scenes), "", END]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.report", description=__doc__.split("\n\n")[0])
    parser.add_argument("--no-run", action="store_true", help="only rewrite the README from docs/validation")
    args = parser.parse_args(argv)
    if not args.no_run:
        if crossval.main(["--json", str(DOCS / "crossval.json")]) != 0:
            print("report: crossval criteria failed; the section shows which", file=sys.stderr)
        error_vs_time.main(["--json", str(DOCS / "error_vs_time.json"), "--out", str(DOCS)])
        import mitsuba as mi

        write_json(DOCS / "meta.json", {"machine": machine(), "date": dt.date.today().isoformat(),
                                        "variant": mi.variant()})
    cv = json.loads((DOCS / "crossval.json").read_text())
    # slopes and plots follow the current fitting rule, also for stored points
    evt = error_vs_time.refit(json.loads((DOCS / "error_vs_time.json").read_text()))
    write_json(DOCS / "error_vs_time.json", evt)
    error_vs_time.write_outputs(evt, DOCS)
    meta = json.loads((DOCS / "meta.json").read_text())
    readme = ROOT / "README.md"
    text = readme.read_text()
    new = section(cv, evt, meta)
    text = re.sub(re.escape(START) + ".*?" + re.escape(END), lambda _: new, text, flags=re.S) \
        if START in text else text.rstrip() + "\n\n" + new + "\n"
    readme.write_text(text)
    print(readme)
    return 0


if __name__ == "__main__":
    sys.exit(main())
