"""``python -m denoise IN_DIR OUT_DIR [--method bilateral|atrous] [--no-temporal] ...``

Denoises a frame folder (see :mod:`denoise.frames`) into ``OUT_DIR/result_i.exr``.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

if __name__ == "__main__":  # started by a Python without the project's packages: use ./.venv's
    from core.launcher import use_project_python
    use_project_python("python -m denoise", "denoise")

from .filters import BilateralParams, TemporalParams
from .pipeline import METHODS, DenoiseOptions, denoise_folder


def main(argv: list[str] | None = None) -> int:
    defaults, temporal = BilateralParams(), TemporalParams()
    parser = argparse.ArgumentParser(prog="python -m denoise", description=__doc__.split("\n\n")[0])
    parser.add_argument("source", type=Path, metavar="IN_DIR")
    parser.add_argument("target", type=Path, metavar="OUT_DIR")
    parser.add_argument("--method", choices=METHODS, default="atrous")
    parser.add_argument("--no-temporal", action="store_true", help="spatial filtering only")
    parser.add_argument("--sigma-coord", type=float, default=defaults.sigma_coord)
    parser.add_argument("--sigma-color", type=float, default=defaults.sigma_color)
    parser.add_argument("--sigma-normal", type=float, default=defaults.sigma_normal)
    parser.add_argument("--sigma-plane", type=float, default=defaults.sigma_plane)
    parser.add_argument("--radius", type=int, default=defaults.radius, help="bilateral window radius")
    parser.add_argument("--levels", type=int, default=5, help="À-Trous levels")
    parser.add_argument("--alpha", type=float, default=temporal.alpha, help="weight of the current frame")
    parser.add_argument("--k", type=float, default=temporal.k, help="history clamp: mean ± k sigma")
    parser.add_argument("--variant", help="Mitsuba variant (default: llvm_ad_rgb where usable)")
    args = parser.parse_args(argv)
    from renderer.variants import set_variant

    set_variant(args.variant, quiet=True)
    options = DenoiseOptions(
        method=args.method, temporal=not args.no_temporal, levels=args.levels,
        bilateral=BilateralParams(args.sigma_coord, args.sigma_color, args.sigma_normal, args.sigma_plane, args.radius),
        temporal_params=TemporalParams(alpha=args.alpha, k=args.k))
    try:
        written = denoise_folder(args.source, args.target, options)
    except (OSError, ValueError) as error:
        print(f"denoise: error: {error}", file=sys.stderr)
        return 2
    print(f"{len(written)} frames -> {args.target}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
