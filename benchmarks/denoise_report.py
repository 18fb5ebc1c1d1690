"""The denoising benchmark's report: its tables, the bars it checks and the
results page, every number from a run's results (``python -m benchmarks.denoise``)."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from benchmarks.denoise_front import tail_mean
from core.markdown import replace_section
from denoise.methods.oidn import QUALITIES
from denoise.temporal_metrics import QUALITY_FROM

ROOT = Path(__file__).resolve().parent.parent
#: OIDN alone, one name per quality mode: the baselines
OIDN_ALONE = tuple(f"oidn-{quality}" for quality in QUALITIES)
#: the baseline of the speed ratios and the quality comparisons
BASELINE = "oidn-high"
#: the reference's own noise must be at most this fraction of the best method's relMSE
REFERENCE_NOISE_BAR = 0.1
#: asvgf's quality bars: mean relMSE over frames >= QUALITY_FROM at most this times OIDN's, on every sequence
ASVGF_RELMSE_BAR = 1.5
#: asvgf's response to a sudden change, in frames
RESPONSE_BAR = 2
#: the hard sequence: the results page's still and video
HARD = "light_switch"
STILL_METHODS = ("raw", "svgf", "asvgf", BASELINE)


def mean_of(rows, sequence, method, key):
    values = [r[key] for r in rows if r["sequence"] == sequence and r["method"] == method and r[key] is not None]
    return float(np.mean(values)) if values else float("nan")


def best_method(results: dict, sequence: str) -> tuple[str, float] | None:
    """The denoising method of least mean relMSE on ``sequence`` (None: only raw ran)."""
    rows = results["results"]
    scores = {m: mean_of(rows, sequence, m, "relmse") for m in dict.fromkeys(r["method"] for r in rows) if m != "raw"}
    scores = {m: v for m, v in scores.items() if np.isfinite(v)}
    if not scores:
        return None
    best = min(scores, key=scores.get)
    return best, scores[best]


def reference_checks(results: dict) -> list[str]:
    """One line per sequence; the ones that fail start with 'FAIL'."""
    lines = []
    for s in results["sequences"]:
        if best_method(results, s["name"]) is None:
            lines.append(f"not judged: {s['name']}: no method besides raw ran to set the reference noise against")
            continue
        best, value = best_method(results, s["name"])
        ratio = s["reference_noise"] / value
        s["reference_noise_ratio"] = ratio
        verdict = "ok" if ratio <= REFERENCE_NOISE_BAR else "FAIL"
        lines.append(f"{verdict}: {s['name']}: reference noise {s['reference_noise']:.2e} = {100 * ratio:.1f} % of "
                     f"the best method's relMSE ({best}, {value:.2e}); bar {100 * REFERENCE_NOISE_BAR:.0f} %")
    return lines


def summary(results: dict) -> str:
    rows = results["results"]
    stability = {s["name"]: s["stability"] for s in results["sequences"]}
    lines = ["| sequence | method | mean relMSE | relMSE last frame | mean FLIP | temporal stability | ms per frame |",
             "|---|---|---|---|---|---|---|"]
    for sequence in dict.fromkeys(r["sequence"] for r in rows):
        for method in dict.fromkeys(r["method"] for r in rows):
            pts = [r for r in rows if r["sequence"] == sequence and r["method"] == method]
            if pts:
                lines.append(f"| {sequence} | {method} | {np.mean([p['relmse'] for p in pts]):.4f} | "
                             f"{pts[-1]['relmse']:.4f} | {np.mean([p['flip'] for p in pts]):.4f} | "
                             f"{stability[sequence][method]:.2f} | {np.median([p['ms'] for p in pts]):.0f} |")
    return "\n".join(lines)


def bar_lines(results: dict) -> list[str]:
    """The assignment's bars, measured in this run."""
    rows, lines = results["results"], []
    for s in results["sequences"]:
        name = s["name"]
        last = max(r["frame"] for r in rows if r["sequence"] == name)
        value = {r["method"]: r["relmse"] for r in rows if r["sequence"] == name and r["frame"] == last}
        ours = {m: v for m, v in value.items() if m != "raw" and m not in OIDN_ALONE}
        best = min(ours, key=ours.get)
        lines.append(
            f"{name}, frame {last + 1}: svgf relMSE {value['svgf']:.4f} is "
            f"{value['atrous+temporal'] / value['svgf']:.1f}x "
            f"lower than atrous+temporal (bar 2x) and {value['raw'] / value['svgf']:.0f}x lower than raw (bar 10x); "
            f"our best ({best}) {ours[best]:.4f} vs {BASELINE} {value[BASELINE]:.4f} "
            f"({'lower' if ours[best] < value[BASELINE] else 'not lower'}); stability svgf "
            f"{s['stability']['svgf']:.2f} vs atrous {s['stability']['atrous']:.2f} "
            f"({'lower' if s['stability']['svgf'] < s['stability']['atrous'] else 'not lower'})")
    return lines + asvgf_lines(results) + speed_lines(results)


def speed_lines(results: dict) -> list[str]:
    """The speed bars of the run's 1280x720 timing, where it has one (every bar whose two methods ran)."""
    lines = []
    timing = results.get("timing")
    if timing:
        size = "x".join(map(str, timing["size"]))
        cpu = timing.get("cpu_ms", {})

        def cpu_text(key: str) -> str:  # this process's CPU time, all threads: what other jobs inflate least
            method, base = key.split(" / ")
            return f"; CPU time {cpu[method] / cpu[base]:.3f}x" if method in cpu and cpu.get(base) else ""

        parts = [f"{key} = {b['ratio']:.3f}x (bar {b['bar']}x: {'met' if b['met'] else 'not met'}{cpu_text(key)})"
                 for key, b in timing["bars"].items()]
        times = ", ".join(f"{m} {ms:.0f} ms" for m, ms in timing["ms"].items())
        parts += [f"{key}: not checked" for key in timing.get("bars_not_checked", [])]
        lines.append(f"speed at {size} ({times})" + (": " + "; ".join(parts) if parts else ""))
    return lines


def tail_text(ours: float | None, theirs: float | None) -> str:
    """asvgf's tail mean against the baseline's, or why there is none."""
    if ours is None or theirs is None:
        return f"asvgf mean relMSE: no frames >= {QUALITY_FROM}"
    return (f"asvgf mean relMSE (frames >= {QUALITY_FROM}) {ours:.4f} = {ours / theirs:.2f}x {BASELINE}'s "
            f"{theirs:.4f} (bar {ASVGF_RELMSE_BAR}x: {'met' if ours <= ASVGF_RELMSE_BAR * theirs else 'not met'})")


def frames_text(response_frames: int | None) -> str:
    return "never" if response_frames is None else f"{response_frames} frames"


def asvgf_lines(results: dict) -> list[str]:
    """asvgf's bars, per sequence: mean relMSE over frames >= QUALITY_FROM against
    OIDN 2 high's, temporal stability against OIDN's, the response to a sudden
    change against svgf's, and on a sequence longer than 8 frames the last frame
    against frame 8."""
    rows, lines = results["results"], []
    if not any(r["method"] == "asvgf" for r in rows):
        return lines
    for s in results["sequences"]:
        name = s["name"]
        ours, oidn = tail_mean(rows, name, "asvgf"), tail_mean(rows, name, BASELINE)
        stability = s["stability"]
        line = (f"{name}: {tail_text(ours, oidn)}; "
                f"stability {stability['asvgf']:.2f} vs {BASELINE} {stability[BASELINE]:.2f} "
                f"({'met' if stability['asvgf'] < stability[BASELINE] else 'not met'})")
        if "response" in s:
            r = s["response"]
            met = (r["asvgf"] is not None and r["asvgf"] <= RESPONSE_BAR
                   and (r["svgf"] is None or r["svgf"] > r["asvgf"]))
            line += (f"; response to the change at frames {s['switch']}: asvgf {frames_text(r['asvgf'])}, svgf "
                     f"{frames_text(r['svgf'])}, {BASELINE} {frames_text(r[BASELINE])} "
                     f"(bar <= {RESPONSE_BAR} and below svgf's: {'met' if met else 'not met'})")
        values = {r["frame"]: r["relmse"] for r in rows if r["sequence"] == name and r["method"] == "asvgf"}
        if len(values) > 8:
            last, eighth = values[max(values)], values[7]
            # the view changes too: against the baseline on the same frames, drift apart from content
            base = {r["frame"]: r["relmse"] for r in rows if r["sequence"] == name and r["method"] == BASELINE}
            line += (f"; asvgf at the last frame {last:.4f} vs frame 8 {eighth:.4f} "
                     f"({'met' if last <= eighth else 'not met'}; {eighth / base[7]:.2f}x and "
                     f"{last / base[max(values)]:.2f}x {BASELINE}'s on those frames)")
        lines.append(line)
    return lines


#: The page ``--docs`` writes its section into
RESULTS_PAGE = ROOT / "docs" / "results" / "denoise.md"


def results_section(results: dict, still: str | None, video: str | None, front: str | None, command: str) -> str:
    """The denoising results of docs/results/denoise.md: every number from ``results``."""
    described = "; ".join("{}: {}x{}, {} frames, {} spp, ground truth {} spp as two halves".format(
        s["name"], s["size"][0], s["size"][1], s["frames"], s["spp"], s["reference_spp"])
        for s in results["sequences"])
    lines = [f"Results of `{command}` on {results.get('date', 'this machine')}"
             + (f" ({results['machine']}; load average {results['load_average_at_start']} at the start, "
                f"{results['load_average_at_end']} at the end; {results['wall_s'] / 60:.1f} min in all, frames "
                "already rendered reused)" if "wall_s" in results else "")
             + f" ({described}; OIDN "
             f"{results.get('oidn', '')}; times in llvm_ad_rgb, median over frames after a "
             "warm-up; temporal stability: mean relMSE between consecutive back-projected outputs divided by the "
             "ground truth's, 1 = as stable as the truth):", "", summary(results), ""]
    lines += [f"- {line}" for line in reference_checks(results)]
    lines += [f"- {line}" for line in bar_lines(results)]
    if still:
        lines += ["", f"{HARD}, last frame: " + " | ".join(STILL_METHODS + ("reference",)) + ":", "",
                  f"![{HARD}, last frame]({still})"]
    if video:
        lines.append(f"\nVideo of {HARD} (the same panels, every frame): [{video}]({video})")
    if front:
        size = "x".join(map(str, results["timing"]["size"]))
        lines += ["", f"Error against time per frame at {size}, every method and OIDN mode (mean relMSE over frames "
                  f">= {QUALITY_FROM}; the last panel the geometric mean over the sequences, with the Pareto front; "
                  "`python -m benchmarks.denoise_front` redraws it from the JSON):", "",
                  f"![error against time]({front})"]
    return "\n".join(lines)


def write_results_page(results: dict, still: Path | None, video: Path | None, front: Path | None,
                       command: str) -> None:
    """Section ``denoise`` of :data:`RESULTS_PAGE`; links relative to the page."""
    def link(p):
        return Path(os.path.relpath(Path(p).resolve(), RESULTS_PAGE.parent)).as_posix() if p else None

    replace_section(RESULTS_PAGE, "denoise", results_section(results, link(still), link(video), link(front),
                                                             command))
