"""Command line of ``render.py``: scene names, or the course binary's flags verbatim.

    python render.py                         # our default scene, into out/
    python render.py scene06 --variant scalar_rgb
    python render.py -input data/scene07_arch.txt -size 800 800 -bounces 4 -shadows \\
                     -output a07.png -normals a07n.png -depth 8 18 a07d.png
    python render.py --batch grading.sh      # one course command line per line
"""
from __future__ import annotations

import argparse
import os
import shlex
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from core.errors import SceneError, UsageError

from .job import DepthOutput, RenderJob, render, with_outputs_in, write_outputs

ROOT = Path(__file__).resolve().parent.parent
OUR_SCENES = ROOT / "scenes"
DEFAULT_SCENE = "showcase"
#: Where CI and the development machines keep the course's data
DEFAULT_COURSE_DATA = ROOT.parent / "shared" / "course" / "data"


def course_data_dir(explicit: str | None) -> Path | None:
    value = explicit or os.environ.get("COURSE_DATA")
    if value:
        return Path(value)
    return DEFAULT_COURSE_DATA if DEFAULT_COURSE_DATA.is_dir() else None


def resolve_scene(name: str, data: Path | None) -> Path:
    """A scene by path, or by name in ``scenes/`` then the course data folder.

    A name matches ``<name>.txt`` or, if unique, ``<name>_*.txt`` (so
    ``scene06`` finds ``scene06_bunny_1k.txt``).
    """
    path = Path(name)
    if path.suffix == ".txt" and path.exists():
        return path
    folders = [OUR_SCENES] + ([data] if data else [])
    for folder in folders:
        exact = folder / f"{name}.txt"
        if exact.exists():
            return exact
        matches = sorted(folder.glob(f"{name}_*.txt"))
        if len(matches) == 1:
            return matches[0]
        if len(matches) > 1:
            raise UsageError(f"scene name {name!r} is ambiguous in {folder}: "
                             + ", ".join(m.name for m in matches))
    where = ", ".join(str(f) for f in folders)
    hint = "" if data else " (set --data or COURSE_DATA to the course's data folder)"
    raise UsageError(f"no scene {name!r} in {where}{hint}")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="render.py", allow_abbrev=False,
        description="Render course scenes with Mitsuba (whitted integrator, course camera and cube map).",
        epilog="The course binary's flags (-input -size -output -normals -depth -bounces -shadows "
               "-jitter -filter) are accepted verbatim.")
    parser.add_argument("scenes", nargs="*", metavar="SCENE",
                        help=f"scene names or .txt paths (default: {DEFAULT_SCENE}); "
                             "names are looked up in scenes/ and then the course data folder")
    course = parser.add_argument_group("course binary flags")
    course.add_argument("-input", metavar="FILE", help="scene file")
    course.add_argument("-size", nargs=2, type=int, metavar=("W", "H"), default=[800, 800])
    course.add_argument("-output", metavar="FILE", help="beauty image (.png, .bmp, .tga or .exr)")
    course.add_argument("-normals", metavar="FILE", help="normal image, (N + 1) / 2")
    course.add_argument("-depth", nargs=3, metavar=("MIN", "MAX", "FILE"),
                        help="depth image, (t - MIN) / (MAX - MIN)")
    course.add_argument("-bounces", type=int, default=0, metavar="N", help="mirror bounces (default 0)")
    course.add_argument("-shadows", action="store_true", help="trace shadow rays")
    course.add_argument("-jitter", action="store_true", help="16 jittered samples per pixel")
    course.add_argument("-filter", action="store_true", help="render at 3x, then a 3x3 Gaussian down")
    ours = parser.add_argument_group("toolkit options")
    ours.add_argument("--variant", help="Mitsuba variant (default: llvm_ad_rgb if a usable LLVM exists, "
                                        "else scalar_rgb)")
    ours.add_argument("--data", metavar="DIR", help="course data folder for scene names "
                                                    "(default: $COURSE_DATA, else ../shared/course/data)")
    ours.add_argument("--out", metavar="DIR", default="out", help="output folder for named scenes (default: out)")
    ours.add_argument("--exr", nargs="?", const=True, metavar="FILE",
                      help="also write a multilayer EXR (beauty + depth, normal, position, albedo, id); "
                           "a FILE with -input, <out>/<scene>.exr for named scenes")
    ours.add_argument("--spp", type=int, metavar="N", help="samples per pixel (default 1, 16 with -jitter)")
    ours.add_argument("--batch", metavar="FILE",
                      help="run course command lines from FILE, one per line, in this one process")
    ours.add_argument("--stats", action="store_true",
                      help="print what each render traced: camera, shadow and mirror rays, environment "
                           "lookups, AOVs and kernels launched (adds counting to the kernel)")
    ours.add_argument("--quiet", action="store_true", help="print nothing but errors")
    return parser


def _checked(args: argparse.Namespace) -> None:
    w, h = args.size
    if w < 1 or h < 1:
        raise UsageError(f"-size wants positive numbers, got {w} {h}")
    if args.bounces < 0:
        raise UsageError(f"-bounces wants a number >= 0, got {args.bounces}")
    if args.spp is not None and args.spp < 1:
        raise UsageError(f"--spp wants a number >= 1, got {args.spp}")


def _depth(values: list[str] | None) -> DepthOutput | None:
    if values is None:
        return None
    try:
        near, far = float(values[0]), float(values[1])
    except ValueError:
        raise UsageError(f"-depth wants MIN MAX FILE, got {' '.join(values)}") from None
    return DepthOutput(near, far, Path(values[2]))


def jobs_from_args(args: argparse.Namespace) -> list[RenderJob]:
    """The render jobs one command line asks for."""
    _checked(args)
    base = dict(width=args.size[0], height=args.size[1], bounces=args.bounces, shadows=args.shadows,
                jitter=args.jitter, filter=args.filter, spp=args.spp, stats=args.stats)
    single_outputs = dict(output=Path(args.output) if args.output else None,
                          normals=Path(args.normals) if args.normals else None, depth=_depth(args.depth),
                          exr=Path(args.exr) if isinstance(args.exr, str) else None)
    if args.input:
        if args.scenes:
            raise UsageError("give either -input or scene names, not both")
        if not any(single_outputs.values()):
            raise UsageError("-input needs at least one of -output, -normals, -depth, --exr")
        return [RenderJob(scene=Path(args.input), **base, **single_outputs)]

    data = course_data_dir(args.data)
    scenes = [resolve_scene(name, data) for name in (args.scenes or [DEFAULT_SCENE])]
    from .scene_flags import with_scene_flags  # a scene's "# render:" header, where no flag overrides it
    if len(scenes) == 1 and any(single_outputs.values()):
        return [RenderJob(scene=scenes[0], **with_scene_flags(scenes[0], base), **single_outputs)]
    if any(single_outputs.values()):
        raise UsageError("-output, -normals and -depth name one file: use them with one scene")
    folder = Path(args.out)
    return [with_outputs_in(RenderJob(scene=path, **with_scene_flags(path, base)), folder, path.stem,
                            exr=bool(args.exr)) for path in scenes]


def jobs_from_batch(parser: argparse.ArgumentParser, path: Path) -> list[RenderJob]:
    """One job per course command line; a leading program name is skipped."""
    jobs = []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        words = shlex.split(line, comments=True)
        if not words:
            continue
        if not words[0].startswith("-"):
            words = words[1:]  # the course binary's name, e.g. a2 or ${BIN}
        try:
            jobs += jobs_from_args(parser.parse_args(words))
        except UsageError as error:
            raise UsageError(f"{path}:{number}: {error}") from None
    if not jobs:
        raise UsageError(f"{path}: no command lines")
    return jobs


def _write_and_report(result, progress, variant: str) -> None:
    written = write_outputs(result)
    progress.done(result.job, variant, result.seconds, written, result.stats)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        jobs = jobs_from_batch(parser, Path(args.batch)) if args.batch else jobs_from_args(args)
        from .variants import set_variant
        variant = set_variant(args.variant, quiet=args.quiet)
        from .progress import RenderProgress
        # Files are written in the background while the next scene renders
        with RenderProgress(total=len(jobs), enabled=not args.quiet) as progress, \
                ThreadPoolExecutor(max_workers=1) as writer:
            pending = []
            for job in jobs:
                result = render(job)
                pending.append(writer.submit(_write_and_report, result, progress, variant))
            for future in pending:
                future.result()
    except (SceneError, UsageError, ValueError, OSError) as error:
        print(f"render.py: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("render.py: interrupted; finished files are complete, others were not written", file=sys.stderr)
        return 130
    return 0
