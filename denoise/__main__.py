"""python -m denoise: denoise a folder of 1-spp frames with G-buffers.

Reads IN_DIR (the course framework's frame layout: beauty_i.exr, normal_i.exr,
position_i.exr, depth_i.exr, ID_i.exr, matrix_i.mat, optional albedo_i.exr)
and writes OUT_DIR/result_i.exr per frame.
"""
from __future__ import annotations

if __name__ == "__main__":  # first: ./.venv's Python, the libLLVM, then Dr.Jit (see core.launcher)
    from core.launcher import start
    start("python -m denoise", "denoise")

import argparse
import sys
import textwrap
from pathlib import Path

from core.entry import ArgumentParser, finish, printable, run
from core.errors import FrameError, UsageError
from core.inputs import check_outside
from core.numbers import ascii_int
from export.ground_truth import (
    check_ground_truth,
    check_not_an_export_folder,
    check_outside_exports,
    reference_folder,
)
from imaging.colour import side_by_side, tone_map
from imaging.image_io import read_exr_rgb, write_image, write_video
from renderer.variants import set_variant

from .methods import METHODS, DeclarationError, Option, declared_options, from_name, method_names, resolve
from .methods.base import RADIANCE_LIMIT
from .methods.user import add_method_file_option, load_method_files
from .pipeline import denoise_folder

PROG = "python -m denoise"
#: the video's frames per second where --fps is not given
VIDEO_FPS = 4
EXAMPLES = """examples:
  python -m denoise out/seq/lamps out/seq/lamps_denoised --method svgf --png
  python -m denoise out/seq/lamps out/den --method atrous+temporal --video out/den.mp4 \
      --reference out/seq/lamps_reference
"""


def methods_help() -> str:
    """The ``--help`` list of methods: each registered one's name and description."""
    width = max(len(name) for name in METHODS) + 4
    lines = ["methods (NAME: no history unless temporal by nature; NAME+temporal: with the clamped temporal "
             "accumulation; the names every command takes):"]
    for name, cls in METHODS.items():
        lines += textwrap.wrap(cls.description, 79, initial_indent=f"  {name}".ljust(width),
                               subsequent_indent=" " * width)
    text = "\n".join(lines) + "\n\n" + EXAMPLES
    return text.replace("%", "%%") if "%(prog)" in text else text  # argparse formats an epilog holding %(prog)


def _shown(option: Option) -> str:
    if option.default_text is not None:
        return option.default_text
    value = option.default
    return f"{value:g}" if isinstance(value, float) else str(value)


def check_options_apply(name: str, given: dict) -> None:
    """Refuses an option the method ``name`` does not read (e.g. ``--oidn-quality``
    for atrous, ``--alpha`` for atrous without +temporal), which would
    otherwise change nothing, silently."""
    cls, named = resolve(name)
    method = cls.name
    own = {option.key for option in cls.all_options()}
    for flag, (option, users) in declared_options().items():
        if option.key in given and option.key in own:  # checked against the method's own declaration
            declaration = next((o for n, o in users if n == method), option)
            declaration.check(given[option.key], method)
        if option.key in given and option.key not in own:
            suggested = next((n for n in method_names() if resolve(n)[0].name == users[0][0]
                              and (resolve(n)[1]["temporal"] or not option.temporal)), users[0][0])
            raise UsageError(f"{flag} is an option of {', '.join(name for name, _ in users)}, not of {method} "
                             f"(add --method {suggested}, or leave {flag} out)")
    preset = {key: value for key, value in named.items() if key not in ("temporal", "demodulate", "outliers")}
    for key, value in preset.items():
        if key in given and given[key] != value:
            flag = next(o.flag for o in cls.options if o.key == key)
            raise UsageError(f"{flag} {given[key]}: {name} means {flag} {value} (use --method {method} "
                             f"{flag} {given[key]}, or leave {flag} out)")
    if "temporal" in given and (not cls.temporal_by_nature):
        raise UsageError(f"--no-temporal: {name} " + (f"accumulates by its name; use {method}" if named["temporal"]
                                                        else "has no history already"))
    unused = next((o for o in cls.options if o.temporal and o.key in given and not named["temporal"]), None)
    if unused is not None:
        raise UsageError(f"{unused.flag} is an option of the temporal accumulation, which {name} has not "
                         f"(use --method {method}+temporal)")


def add_method_options(parser: argparse.ArgumentParser) -> set[str]:
    """Adds every method's options (no argparse defaults: a method fills its own);
    returns their keys."""
    declared = declared_options()
    groups: dict[str, list[str]] = {}
    for option, users in declared.values():
        if option.group is not None:
            methods = groups.setdefault(option.group, [])
            methods += [name for name, _ in users if name not in methods]
    titled = {group: parser.add_argument_group(f"{group} ({', '.join(methods)})") for group, methods in groups.items()}
    for flag, (option, users) in declared.items():
        help_text = option.help + (f", in {option.unit}" if option.unit else "")
        ranges: dict[str, list[str]] = {}
        for name, declaration in users or [("", option)]:
            if declaration.kind in (int, float) and declaration.choices is None:
                ranges.setdefault(declaration.range_text(), []).append(name)
        if ranges:
            help_text += ": " + "; ".join(text + (f" for {', '.join(names)}" if len(ranges) > 1 else "")
                                          for text, names in ranges.items())
        defaults: dict[str, list[str]] = {}
        for name, declaration in users:
            defaults.setdefault(_shown(declaration), []).append(name)
        if len(defaults) == 1:
            help_text += f" (default {next(iter(defaults))})"
        elif defaults:
            help_text += " (default " + "; ".join(f"{shown} for {', '.join(names)}"
                                                  for shown, names in defaults.items()) + ")"
        readers = [name for name, _ in users]
        if option.group is not None and readers != groups[option.group]:  # the title names more methods
            help_text += f"; {', '.join(readers)} only"
        help_text = help_text.replace("%", "%%")  # argparse formats help with %: the text as written
        where = parser if option.group is None else titled[option.group]
        try:
            if option.action is not None:
                where.add_argument(flag, dest=option.key, action=option.action, default=argparse.SUPPRESS,
                                   help=help_text)
            else:
                where.add_argument(flag, dest=option.key, type=option.parse, choices=option.choices,
                                   metavar=option.metavar, default=argparse.SUPPRESS, help=help_text)
        except argparse.ArgumentError:  # the command's own flag (--help, --method, --png, ...)
            raise DeclarationError(f"{option.origin}: {', '.join(name for name, _ in users) or 'every method'} "
                                   f"declares {flag}, which is {PROG}'s own option; choose another key") from None
    return {option.key for option, _ in declared.values()}


def _parser() -> tuple[argparse.ArgumentParser, set[str]]:
    parser = ArgumentParser(prog=PROG, description=__doc__.split("\n", 1)[0].split(": ", 1)[1],
                            formatter_class=argparse.RawDescriptionHelpFormatter, epilog=methods_help())
    parser.add_argument("source", type=Path, metavar="IN_DIR", help="the frame folder")
    parser.add_argument("target", type=Path, metavar="OUT_DIR",
                        help="where result_i.exr are written (the last run's results there that this run "
                        "does not replace are removed)")
    parser.add_argument("--method", type=method_name, default="atrous+temporal", metavar="NAME",
                        help="the filter: any name of the list below, with demod+ or outliers+ before it "
                             "(default: atrous+temporal)")
    add_method_file_option(parser)
    group = parser.add_argument_group("previews")
    group.add_argument("--png", action="store_true", help="also write result_i.png (tone-mapped sRGB) beside the EXRs")
    group.add_argument("--video", type=Path, metavar="OUT.mp4",
                       help="input | output (| reference) per frame, tone-mapped sRGB, H.264")
    group.add_argument("--reference", type=Path, metavar="REF_DIR",
                       help="ground truth folder (beauty_i.exr) for the video's third panel")
    group.add_argument("--fps", type=ascii_int,
                       help=f"video frames per second (default {VIDEO_FPS}; with --video only)")
    parser.add_argument("--variant", help="Mitsuba variant (default: llvm_ad_rgb where usable)")
    keys = add_method_options(parser)  # last: a method's flag that is one of the command's own is refused
    return parser, keys


def method_name(name: str) -> str:
    """``--method``'s value: any name :func:`resolve` takes (one line naming the known ones otherwise)."""
    resolve(name)
    return name


def _main(argv: list[str] | None) -> int:
    load_method_files(argv)  # before the parser: their methods and options are in --help
    parser, keys = _parser()
    args = parser.parse_args(argv)
    # every parameter checked before any work
    given = {k: v for k, v in vars(args).items() if k in keys}
    check_options_apply(args.method, given)
    method = from_name(args.method, **given)  # each parameter checked against its declaration
    for flag, value in (("--reference", args.reference), ("--fps", args.fps)):
        if value is not None and args.video is None:
            raise UsageError(f"{flag} is used by --video only")
    args.fps = VIDEO_FPS if args.fps is None else args.fps
    if args.fps < 1 or args.fps > 240:
        raise UsageError(f"--fps must be from 1 to 240, got {args.fps}")
    if args.video is not None and args.video.suffix.lower() != ".mp4":
        raise UsageError(f"--video writes H.264 MP4: name it .mp4, got {args.video}")
    check_outside({"OUT_DIR": args.target, "--video": args.video},
                  {"IN_DIR": args.source, "--reference": args.reference,
                   "IN_DIR's ground truth": reference_folder(args.source)})
    check_not_an_export_folder("OUT_DIR", args.target)
    check_outside_exports({"OUT_DIR": args.target, "--video": args.video})
    if args.reference is not None and not args.reference.is_dir():
        raise FrameError(f"{args.reference}: not a folder")
    if args.reference is not None:
        check_ground_truth("--reference", args.reference, args.source, frames_flag="IN_DIR")
    set_variant(args.variant, jit=True)
    panels: list[list] = []

    def on_frame(index, frame, result):
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

    report = denoise_folder(args.source, args.target, method, on_frame,  # demodulation asked by flag or demod+
                            require_albedo=bool(method.props["demodulate"]),
                            suffixes=(".exr", ".png") if args.png else (".exr",))
    if args.video is not None:
        write_video(args.video, [side_by_side(row) for row in panels], fps=args.fps)
    extra = (" with PNG previews" if args.png else "") + (f", video {printable(args.video)}" if args.video else "")
    count = len(report.written)
    print(f"{count} frame{'' if count == 1 else 's'} -> {printable(args.target)}{extra}")
    if report.removed:
        files = "file" if report.removed == 1 else "files"
        print(f"{PROG}: note: {report.removed} result {files} of the last run into {printable(args.target)}, which "
              "this run did not replace, removed", file=sys.stderr)
    if report.replaced_values:
        print(f"{PROG}: note: {report.replaced_values} beauty values in {report.frames_with_replaced} "
              f"frames were NaN, infinite or beyond +-{RADIANCE_LIMIT:g}: filtered as 0 or +-{RADIANCE_LIMIT:g}",
              file=sys.stderr)
    return 0


def main(argv: list[str] | None = None) -> int:
    return run(PROG, lambda: _main(argv))


if __name__ == "__main__":
    finish(main())
