"""The live page's speed, end to end, as the page itself counts it.

    python -m benchmarks.live [--json PATH] [--scene S] [--size W H] [--method M]
                              [--variant V] [--seconds T] [--screenshot PNG] [--no-freeze]

Starts ``python -m denoise.live``, opens its page in Debian's chromium
(headless, driven by Playwright), waits for the first frames (every kernel
compiled), then drives a fixed camera path for ``--seconds``: an orbit
drag of 1 pixel per step (about 16 ms), a tenth of the view's width to
either side and back (0.4 degrees of orbit per pixel). It records
the frames the page showed and their rate (the page's own count: frames
drawn per second of its clock; its fps readout is read four times a second,
each read being a round trip through the browser that takes its CPU), and the median and 90th percentile of each
stage's milliseconds as the server reports them per frame (render,
G-buffers, denoise, encode, transport: sent to shown). ``--screenshot``
saves the page as that browser draws it.
"""
from __future__ import annotations

import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

# started as `python benchmarks/x.py`, this folder would shadow the course and denoise packages
if __name__ == "__main__" and not __package__:
    sys.path[0] = str(Path(__file__).resolve().parents[1])

if __name__ == "__main__":  # first: ./.venv's Python, the libLLVM, then Dr.Jit (see core.launcher)
    from core.launcher import start
    start("python -m benchmarks.live", "benchmarks.live" if __package__ else None)

from benchmarks.records import check_json, stamp, write_json
from core.entry import ArgumentParser
from core.errors import UsageError
from core.numbers import ascii_int

ROOT = Path(__file__).resolve().parent.parent
CHROMIUM = Path("/usr/bin/chromium")
STAGES = ("render", "gbuffers", "denoise", "encode", "transport")
#: seconds between two reads of the page's fps readout
READOUT_EVERY_S = 0.25
#: the page collects each frame's header here while the benchmark runs
COLLECT = "() => { window.benchmark = []; window.live.onFrame = (h) => window.benchmark.push([performance.now(), h]); }"


def start_server(scene: str, size, method: str, variant: str | None, freeze: bool):
    command = [sys.executable, "-m", "denoise.live", scene, "--size", str(size[0]), str(size[1]), "--method", method,
               "--port", "0"] + (["--variant", variant] if variant else []) + ([] if freeze else ["--no-freeze"])
    process = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = process.stdout.readline()
    if "http://" not in line:
        process.kill()

        raise UsageError(f"the live server did not start: {process.stderr.read().strip()[-300:]}")
    return process, line.split("open ", 1)[1].split()[0]


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


def measure(url: str, seconds: float, screenshot: Path | None) -> dict:
    from playwright.sync_api import sync_playwright  # noqa: PLC0415  playwright loads on use: --help and the paths without it stay quick

    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=["--no-sandbox"])
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 720})
            page.goto(url)
            page.wait_for_function("window.live.frames >= 5", timeout=600_000)
            page.evaluate(COLLECT)
            box = page.locator("#canvas").bounding_box()
            x, y = box["x"] + box["width"] * 0.3, box["y"] + box["height"] / 2
            page.mouse.move(x, y)
            page.mouse.down()
            start, fps_readouts, offset, sign = time.perf_counter(), [], 0, 1
            read_at = start
            while time.perf_counter() - start < seconds:
                page.mouse.move(x + offset, y)
                offset += sign
                if abs(offset) >= box["width"] * 0.1:
                    sign = -sign
                page.wait_for_timeout(16)
                if time.perf_counter() >= read_at:  # each read is a round trip through the browser: a few a second
                    fps_readouts.append(page.evaluate("window.live.fps"))
                    read_at += READOUT_EVERY_S
            page.mouse.up()
            frames = page.evaluate("window.benchmark")
            if screenshot is not None:
                page.screenshot(path=str(screenshot))
        finally:
            browser.close()
    if len(frames) < 2:
        return {"frames": len(frames), "fps": 0.0}
    span_s = (frames[-1][0] - frames[0][0]) / 1000
    result = {"frames": len(frames), "seconds": round(span_s, 2), "fps": round((len(frames) - 1) / span_s, 2),
              "fps_readout_median": round(statistics.median(v for v in fps_readouts if v is not None), 2)}
    for stage in STAGES:
        values = [h["ms"][stage] for _, h in frames if h["ms"].get(stage) is not None]
        if values:
            result[f"{stage}_ms_median"] = round(statistics.median(values), 2)
            result[f"{stage}_ms_p90"] = round(percentile(values, 0.9), 2)
    header = frames[-1][1]
    result.update(width=header["width"], height=header["height"], method=header["method"],
                  variant=header["variant"], frozen=header["frozen"])
    return result


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog="python -m benchmarks.live", description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", type=Path, metavar="PATH", help="also write the numbers as JSON")
    parser.add_argument("--scene", default="showcase")
    parser.add_argument("--size", type=ascii_int, nargs=2, default=(320, 180), metavar=("W", "H"))
    parser.add_argument("--method", default="svgf")
    parser.add_argument("--variant", default="llvm_ad_rgb")
    parser.add_argument("--seconds", type=ascii_int, default=20, help="length of the camera path (default 20)")
    parser.add_argument("--screenshot", type=Path, metavar="PNG", help="save the page as the browser shows it")
    parser.add_argument("--no-freeze", action="store_true", help="the server traces every frame (no dr.freeze)")
    args = parser.parse_args(argv)
    check_json(args.json)
    if not CHROMIUM.exists():
        raise UsageError(f"{CHROMIUM} missing: ./dev setup installs Debian's chromium")
    load_at_start = round(os.getloadavg()[0], 2)
    process, url = start_server(args.scene, args.size, args.method, args.variant, not args.no_freeze)
    try:
        result = measure(url, args.seconds, args.screenshot)
    finally:
        process.terminate()
        process.wait(30)
    command = ["python -m benchmarks.live", *(sys.argv[1:] if argv is None else argv)]
    result = dict(stamp(command), **result, load_average_at_start=load_at_start,
                  load_average_at_end=round(os.getloadavg()[0], 2))
    for key, value in result.items():
        print(f"{key}: {value}")
    if args.json:
        write_json(args.json, result)
    return 0


if __name__ == "__main__":
    from core import entry

    entry.finish(entry.run("python -m benchmarks.live", main))
