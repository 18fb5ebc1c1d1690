"""python -m denoise: denoise a folder of 1-spp frames with G-buffers.

Reads IN_DIR (the course framework's frame layout: beauty_i.exr, normal_i.exr,
position_i.exr, depth_i.exr, ID_i.exr, matrix_i.mat, optional albedo_i.exr)
and writes OUT_DIR/result_i.exr per frame.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

if __name__ == "__main__":  # started by a Python without the project's packages: use ./.venv's
    from core.launcher import use_project_python
    use_project_python("python -m denoise", "denoise")

from core.entry import ArgumentParser
from core.numbers import ascii_float, ascii_int

from .pipeline import METHODS

EXAMPLE = """methods:
  bilateral  the assignment's joint bilateral filter ((2 radius + 1)^2 window)
  atrous     the assignment's A-Trous wavelet filter (--levels passes)
  svgf       spatiotemporal variance-guided filtering (Schied et al. 2017)
  oidn       Intel Open Image Denoise (HDR, albedo and normals); with temporal
             accumulation first unless --no-temporal
  oidn-guided  OIDN on the input accumulated over time, its history clamped to
             the neighbourhood of OIDN's output on the frame alone (two OIDN
             runs per frame)
bilateral and atrous blend each filtered frame with the back-projected,
clamped previous result unless --no-temporal.

examples:
  python -m denoise out/seq/lamps out/seq/lamps_denoised --method svgf --png
  python -m denoise out/seq/lamps out/den --method atrous --video out/den.mp4 --reference out/seq/lamps_reference
"""


def _parser() -> argparse.ArgumentParser:
    from .filters import AtrousLevels, BilateralWindow, EdgeWeights, OutlierParams, TemporalParams
    from .pipeline import DenoiseOptions
    from .svgf import SVGFParams

    edges, window, levels = EdgeWeights(), BilateralWindow(), AtrousLevels()
    temporal, outliers, svgf = TemporalParams(), OutlierParams(), SVGFParams()
    parser = ArgumentParser(prog="python -m denoise", description=__doc__.split("\n", 1)[0].split(": ", 1)[1],
                                     formatter_class=argparse.RawDescriptionHelpFormatter, epilog=EXAMPLE)
    parser.add_argument("source", type=Path, metavar="IN_DIR", help="the frame folder")
    parser.add_argument("target", type=Path, metavar="OUT_DIR", help="where result_i.exr are written")
    parser.add_argument("--method", choices=METHODS, default="atrous", help="the filter (default: atrous)")
    parser.add_argument("--no-temporal", action="store_true", help="each frame on its own (no history)")
    parser.add_argument("--demodulate", action="store_true",
                        help="filter beauty / albedo and multiply back (needs albedo_i.exr for every frame; "
                             "svgf does so whenever the frames have it)")
    parser.add_argument("--outliers", type=ascii_float, metavar="K", default=None,
                        help=f"first clamp each pixel's luminance to its 7x7 mean +- K sigma (off by default; "
                             f"{outliers.k:g} is a usual K)")
    group = parser.add_argument_group("edge-stopping weights (bilateral, atrous)")
    group.add_argument("--sigma-color", type=ascii_float, default=edges.sigma_color, help=f"default {edges.sigma_color}")
    group.add_argument("--sigma-normal", type=ascii_float, default=edges.sigma_normal,
                       help=f"on the normals' angle in radians (default {edges.sigma_normal})")
    group.add_argument("--sigma-plane", type=ascii_float, default=edges.sigma_plane, help=f"default {edges.sigma_plane}")
    group = parser.add_argument_group("bilateral window")
    group.add_argument("--radius", type=ascii_int, default=window.radius,
                       help=f"window (2 radius + 1)^2, 0..64 (default {window.radius})")
    group.add_argument("--sigma-coord", type=ascii_float, default=window.sigma_coord,
                       help=f"pixels (default {window.sigma_coord})")
    group = parser.add_argument_group("a-trous and svgf")
    group.add_argument("--levels", type=ascii_int, default=None,
                       help=f"passes, 1..12 (default {levels.levels} for atrous; for svgf the paper's 5 at 1280 "
                            "pixels wide, one fewer per halving of the width)")
    group = parser.add_argument_group("temporal accumulation (bilateral, atrous, oidn, oidn-guided)")
    oidn_temporal, oidn_guided = DenoiseOptions().oidn_temporal, DenoiseOptions().oidn_guided
    group.add_argument("--alpha", type=ascii_float, default=None,
                       help=f"weight of the current frame, in (0, 1] (default {temporal.alpha}; "
                            f"{oidn_temporal.alpha} for oidn, {oidn_guided.alpha} for oidn-guided)")
    group.add_argument("--k", type=ascii_float, default=None,
                       help=f"clamp the history to the 7x7 mean +- k sigma, k >= 0 (default {temporal.k}; "
                            f"{oidn_temporal.k} for oidn; oidn-guided: the guide's 3x3, {oidn_guided.k})")
    group = parser.add_argument_group("svgf")
    group.add_argument("--sigma-luminance", type=ascii_float, default=svgf.sigma_luminance,
                       help=f"luminance weight, in standard deviations (default {svgf.sigma_luminance})")
    group.add_argument("--normal-exponent", type=ascii_float, default=svgf.sigma_normal,
                       help=f"normal weight max(0, n.n')^exponent (default {svgf.sigma_normal:g})")
    group = parser.add_argument_group("previews")
    group.add_argument("--png", action="store_true", help="also write result_i.png (tone-mapped sRGB) beside the EXRs")
    group.add_argument("--video", type=Path, metavar="OUT.mp4",
                       help="input | output (| reference) per frame, tone-mapped sRGB, H.264")
    group.add_argument("--reference", type=Path, metavar="REF_DIR",
                       help="ground truth folder (beauty_i.exr) for the video's third panel")
    group.add_argument("--fps", type=ascii_int, default=4, help="video frames per second (default 4)")
    parser.add_argument("--variant", help="Mitsuba variant (default: llvm_ad_rgb where usable)")
    return parser


def options_from(args):
    """The validated options (a parameter out of range is a UsageError)."""
    from dataclasses import replace

    from .filters import AtrousLevels, BilateralWindow, EdgeWeights, OutlierParams, TemporalParams
    from .pipeline import DenoiseOptions
    from .svgf import SVGFParams

    edges = EdgeWeights(args.sigma_color, args.sigma_normal, args.sigma_plane)
    window = BilateralWindow(args.radius, args.sigma_coord)
    atrous = AtrousLevels(args.levels if args.levels is not None else AtrousLevels().levels)
    defaults = DenoiseOptions()
    base = {"oidn": defaults.oidn_temporal, "oidn-guided": defaults.oidn_guided}.get(args.method,
                                                                                     defaults.temporal_params)
    temporal = TemporalParams(alpha=base.alpha if args.alpha is None else args.alpha,
                              k=base.k if args.k is None else args.k, clamp_radius=base.clamp_radius)
    from core.errors import UsageError

    try:
        svgf = SVGFParams(sigma_luminance=args.sigma_luminance, sigma_normal=args.normal_exponent)
    except UsageError as error:  # name the command's option, not the parameter
        raise UsageError(str(error).replace("sigma_normal", "--normal-exponent")
                         .replace("sigma_luminance", "--sigma-luminance")) from None
    if args.levels is not None:
        svgf = replace(svgf, levels=args.levels)
    return DenoiseOptions(
        method=args.method, temporal=not args.no_temporal, edges=edges, window=window, atrous=atrous,
        temporal_params=temporal, oidn_temporal=temporal, oidn_guided=temporal, svgf=svgf,
        outliers=OutlierParams(k=args.outliers) if args.outliers is not None else None,
        demodulate=args.demodulate or args.method == "svgf")


def _main(argv: list[str] | None) -> int:
    from core.errors import FrameError, UsageError

    args = _parser().parse_args(argv)
    options = options_from(args)  # every parameter checked before any work
    if args.fps < 1 or args.fps > 240:
        raise UsageError(f"--fps must be from 1 to 240, got {args.fps}")
    if args.reference is not None and args.video is None:
        raise UsageError("--reference is used by --video only")
    if args.video is not None and args.video.suffix.lower() != ".mp4":
        raise UsageError(f"--video writes H.264 MP4: name it .mp4, got {args.video}")
    if args.reference is not None and not args.reference.is_dir():
        raise FrameError(f"{args.reference}: not a folder")
    from renderer.variants import set_variant

    from .pipeline import denoise_folder

    set_variant(args.variant, quiet=True)
    panels: list[list] = []

    def on_frame(index, frame, result):
        from imaging.colour import tone_map
        from imaging.image_io import read_exr_rgb, write_image

        if args.png:
            write_image(args.target / f"result_{index}.png", tone_map(result))
        if args.video is not None:
            row = [frame.beauty, result]
            if args.reference is not None:
                path = args.reference / f"beauty_{index}.exr"
                if not path.exists():
                    raise FrameError(f"{path}: missing (the reference folder lacks frame {index})")
                truth = read_exr_rgb(path)
                if truth.shape != result.shape:
                    raise FrameError(f"{path}: {truth.shape[1]}x{truth.shape[0]} pixels, the frames have "
                                     f"{result.shape[1]}x{result.shape[0]}")
                row.append(truth)
            panels.append(row)

    report = denoise_folder(args.source, args.target, options, on_frame, require_albedo=args.demodulate)
    if args.video is not None:
        from imaging.colour import side_by_side
        from imaging.image_io import write_video

        write_video(args.video, [side_by_side(row) for row in panels], fps=args.fps)
    extra = (" with PNG previews" if args.png else "") + (f", video {args.video}" if args.video else "")
    print(f"{len(report.written)} frames -> {args.target}{extra}")
    if report.replaced_values:
        from .pipeline import RADIANCE_LIMIT

        print(f"python -m denoise: note: {report.replaced_values} beauty values in {report.frames_with_replaced} "
              f"frames were NaN, infinite or beyond +-{RADIANCE_LIMIT:g}: filtered as 0 or +-{RADIANCE_LIMIT:g}",
              file=sys.stderr)
    return 0


def main(argv: list[str] | None = None) -> int:
    from core.entry import run

    return run("python -m denoise", lambda: _main(argv))


if __name__ == "__main__":
    sys.exit(main())
