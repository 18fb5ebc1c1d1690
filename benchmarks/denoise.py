"""Denoising quality and speed on our animated sequences, beside Intel Open Image Denoise.

    python -m benchmarks.denoise [--json PATH] [--quick] [--video PATH] [--work DIR]

For each sequence of ``scenes/sequences/*.json`` (rendered once into
``--work``, 1 spp path-traced input, converged ground truth), each method
runs over all frames: ``raw`` (the input), ``bilateral``, ``atrous``,
``bilateral+temporal``, ``atrous+temporal`` (ours, Dr.Jit) and ``oidn`` (Intel
Open Image Denoise with albedo and normals, spatial only, through the ``oidn``
package). Per frame: relMSE and FLIP against the ground truth and
milliseconds (after one warm-up frame). JSON: ``{"sequences": [...],
"results": [{"sequence", "method", "frame", "relmse", "flip", "ms"}]}``.
``--video`` writes one sequence as input | atrous+temporal | ground truth.
"""
from __future__ import annotations

import argparse
import ctypes
import importlib.util
import sys
import time
from pathlib import Path

import numpy as np

from benchmarks import write_json
from benchmarks.course import ROOT
from benchmarks.crossval import relmse
from benchmarks.error_vs_time import flip_error

SEQUENCES = sorted((ROOT / "scenes" / "sequences").glob("*.json"))
METHODS = ("raw", "bilateral", "atrous", "bilateral+temporal", "atrous+temporal", "oidn")


def load_oidn():
    """The ``oidn`` module; its wheel ships libtbb.so.12.5 but not the libtbb.so.12
    name its library asks for, so that file is loaded first."""
    spec = importlib.util.find_spec("oidn")
    if spec is None:
        raise ImportError("the oidn package is not installed")
    library = Path(spec.origin).parent / "lib.linux.x64" / "libtbb.so.12.5"
    if library.exists():
        ctypes.CDLL(str(library), mode=ctypes.RTLD_GLOBAL)
    import oidn

    return oidn


class OIDNDenoiser:
    def __init__(self):
        self.oidn = load_oidn()
        self.device = self.oidn.NewDevice()
        self.oidn.CommitDevice(self.device)

    def step(self, frame) -> np.ndarray:
        oidn = self.oidn
        height, width = frame.beauty.shape[:2]
        images = {"color": frame.beauty, "albedo": frame.albedo, "normal": frame.normal}
        images = {k: np.ascontiguousarray(v, np.float32) for k, v in images.items() if v is not None}
        output = np.zeros_like(images["color"])
        flt = oidn.NewFilter(self.device, "RT")
        for name, image in images.items():
            oidn.SetSharedFilterImage(flt, name, image, oidn.FORMAT_FLOAT3, width, height)
        oidn.SetSharedFilterImage(flt, "output", output, oidn.FORMAT_FLOAT3, width, height)
        oidn.SetFilter1b(flt, "hdr", True) if hasattr(oidn, "SetFilter1b") else None
        oidn.CommitFilter(flt)
        oidn.ExecuteFilter(flt)
        oidn.ReleaseFilter(flt)
        return output


class RawMethod:
    def step(self, frame) -> np.ndarray:
        return frame.beauty


def make_method(name: str):
    from denoise.pipeline import DenoiseOptions, Denoiser

    if name == "raw":
        return RawMethod()
    if name == "oidn":
        return OIDNDenoiser()
    spatial, _, temporal = name.partition("+")
    return Denoiser(DenoiseOptions(method=spatial, temporal=bool(temporal)))


def run_sequence(folder: Path, name: str, methods=METHODS, outputs: dict | None = None) -> list[dict]:
    import drjit as dr

    from denoise.export import reference_folder
    from denoise.frames import frame_indices, read_frame
    from imaging.image_io import read_exr

    frames = [read_frame(folder, i) for i in frame_indices(folder)]
    truth = [np.stack([read_exr(reference_folder(folder) / f"beauty_{i}.exr")[c] for c in "RGB"], -1)
             for i in frame_indices(folder)]
    rows = []
    for method in methods:
        make_method(method).step(frames[0])  # warm-up: kernels compiled and cached
        runner = make_method(method)
        for index, (frame, reference) in enumerate(zip(frames, truth)):
            start = time.perf_counter()
            result = runner.step(frame)
            dr.sync_thread()
            ms = 1000 * (time.perf_counter() - start)
            rows.append({"sequence": name, "method": method, "frame": index, "relmse": relmse(result, reference),
                         "flip": flip_error(result, reference), "ms": ms})
            if outputs is not None:
                outputs.setdefault(method, []).append(result)
    return rows


def write_video(path: Path, panels: list[list[np.ndarray]], fps: int = 2, shrink: int = 2) -> None:
    """Side-by-side panels per frame, sRGB, each panel shrunk ``shrink`` times (box filter)."""
    import imageio.v2 as imageio

    from imaging.colour import to_srgb_8bit
    from imaging.image_io import atomic_path

    def small(image: np.ndarray) -> np.ndarray:
        h, w = image.shape[0] // shrink, image.shape[1] // shrink
        return image[: h * shrink, : w * shrink].reshape(h, shrink, w, shrink, -1).mean(axis=(1, 3))

    with atomic_path(path, path.suffix) as tmp:
        with imageio.get_writer(tmp, fps=fps, codec="libx264", quality=6, format="FFMPEG",
                                macro_block_size=8) as writer:
            for images in zip(*panels):
                writer.append_data(np.concatenate([to_srgb_8bit(small(i)) for i in images], axis=1))


def summary(results: dict) -> str:
    rows = results["results"]
    lines = ["| sequence | method | mean relMSE | relMSE last frame | mean FLIP | ms per frame |",
             "|---|---|---|---|---|---|"]
    for sequence in dict.fromkeys(r["sequence"] for r in rows):
        for method in METHODS:
            pts = [r for r in rows if r["sequence"] == sequence and r["method"] == method]
            if pts:
                lines.append(f"| {sequence} | {method} | {np.mean([p['relmse'] for p in pts]):.4f} | "
                             f"{pts[-1]['relmse']:.4f} | {np.mean([p['flip'] for p in pts]):.4f} | "
                             f"{np.median([p['ms'] for p in pts]):.0f} |")
    return "\n".join(lines)


def readme_section(results: dict, video: str | None) -> str:
    """The README's denoising results: the table, the 10x check and the speed targets."""
    rows = results["results"]
    described = "; ".join("{}: {}x{}, {} frames, {} spp, ground truth {} spp".format(
        s["name"], s["size"][0], s["size"][1], s["frames"], s["spp"], s["reference_spp"])
        for s in results["sequences"])
    lines = ["<!-- denoise:start -->", f"Results of `python -m benchmarks.denoise --readme` ({described}; "
             "times on this 2-core machine, llvm_ad_rgb, median over frames after a warm-up):", "",
             summary(results), ""]
    for sequence in dict.fromkeys(r["sequence"] for r in rows):
        last = max(r["frame"] for r in rows if r["sequence"] == sequence)
        value = {r["method"]: r["relmse"] for r in rows if r["sequence"] == sequence and r["frame"] == last}
        lines.append(f"- {sequence}, frame {last + 1}: raw relMSE / atrous+temporal relMSE = "
                     f"{value['raw'] / value['atrous+temporal']:.1f}x (OIDN: {value['raw'] / value['oidn']:.1f}x)")
    if video:
        lines.append(f"- video (input | atrous+temporal | ground truth): [{video}]({video})")
    atrous_ms = max(np.median([r["ms"] for r in rows if r["sequence"] == s and r["method"] == "atrous+temporal"])
                    for s in dict.fromkeys(r["sequence"] for r in rows))
    bilateral_ms = max(np.median([r["ms"] for r in rows if r["sequence"] == s and r["method"] == "bilateral"])
                       for s in dict.fromkeys(r["sequence"] for r in rows))
    lines.append(f"- speed targets: atrous+temporal {atrous_ms:.0f} ms per frame (target ≤ 100 ms: "
                 f"{'met' if atrous_ms <= 100 else 'not met'}); bilateral 33×33 {bilateral_ms / 1000:.1f} s "
                 f"(target ≤ 2 s: {'met' if bilateral_ms <= 2000 else 'not met'})")
    lines.append("<!-- denoise:end -->")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.denoise", description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", type=Path, metavar="PATH")
    parser.add_argument("--quick", action="store_true", help="small frames (CI)")
    parser.add_argument("--video", type=Path, metavar="PATH", help="input | ours | ground truth of the first sequence")
    parser.add_argument("--work", type=Path, default=Path("out/denoise"), help="where the sequences are rendered")
    parser.add_argument("--readme", action="store_true",
                        help="write docs/denoise/ (JSON, video) and the README's denoising results")
    args = parser.parse_args(argv)
    if args.readme:
        args.json = args.json or ROOT / "docs" / "denoise" / "denoise.json"
        args.video = args.video or ROOT / "docs" / "denoise" / "dolly_lamps.mp4"
    from denoise.export import Spec, export
    from renderer.variants import set_variant

    set_variant(None, quiet=True)
    overrides = dict(size=(160, 90), frames=4, reference_spp=64) if args.quick else {}
    results = {"sequences": [], "results": []}
    for number, spec_path in enumerate(SEQUENCES):
        spec = Spec.load(spec_path, **overrides)
        folder = args.work / (spec_path.stem + ("_quick" if args.quick else ""))
        export(spec, folder)
        results["sequences"].append({"name": spec_path.stem, "spec": str(spec_path.relative_to(ROOT)),
                                     "size": list(spec.size), "frames": spec.frames, "spp": spec.spp,
                                     "reference_spp": spec.reference_spp})
        outputs = {} if (args.video and number == 0) else None
        results["results"] += run_sequence(folder, spec_path.stem, outputs=outputs)
        print(f"{spec_path.stem}: done", file=sys.stderr)
        if outputs is not None:
            from denoise.export import reference_folder
            from imaging.image_io import read_exr

            truth = [np.stack([read_exr(p)[c] for c in "RGB"], -1)
                     for p in sorted(reference_folder(folder).glob("beauty_*.exr"),
                                     key=lambda p: int(p.stem.split("_")[1]))]
            write_video(args.video, [outputs["raw"], outputs["atrous+temporal"], truth])
    print(summary(results))
    if args.json:
        write_json(args.json, results)
    if args.readme:
        write_readme(results, args.video)
    return 0


def write_readme(results: dict, video: Path | None) -> None:
    import re

    readme = ROOT / "README.md"
    link = str(Path(video).resolve().relative_to(ROOT)) if video else None
    text = re.sub(r"<!-- denoise:start -->.*?<!-- denoise:end -->", lambda _: readme_section(results, link),
                  readme.read_text(), flags=re.S)
    readme.write_text(text)


if __name__ == "__main__":
    sys.exit(main())
