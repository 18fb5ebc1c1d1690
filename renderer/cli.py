"""Command line of ``render.py``: scene names, or the course binary's flags verbatim.

    python render.py                         # our default scene, into out/
    python render.py scene06 --variant scalar_rgb
    python render.py -input data/scene07_arch.txt -size 800 800 -bounces 4 -shadows \\
                     -output a07.png -normals a07n.png -depth 8 18 a07d.png
    python render.py --batch grading.sh      # one course command line per line

Every input is checked (:mod:`renderer.checks`) before the variant is set and
anything is rendered; every refusal is one line and exit code 2
(:func:`core.entry.run`).
"""
from __future__ import annotations

import argparse
import math
import shlex
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

from converters.render_flags import DepthOutput, RenderJob
from converters.scene_flags import with_scene_flags
from core.entry import ArgumentParser, one_line, run
from core.errors import ToolkitError, UsageError, describe
from core.inputs import NotAnInputFile, read_input
from core.numbers import ascii_int
from course import ENVIRONMENT as COURSE_ENVIRONMENT, check_data_flag, data_dir, resolve_scene

from . import checks
from .job import render, with_outputs_in, write_outputs
from .progress import RenderProgress
from .variants import set_variant

DEFAULT_SCENE = "showcase"
#: The course binary's default image size (its -size)
DEFAULT_SIZE = (800, 800)
#: Batch lines that are shell, not course command lines: skipped (mkdir also
#: makes its folders; every output's folder is created anyway)
SHELL_WORDS = ("echo", "mkdir", "true", ":")
EXAMPLE = f"""example:
  render.py -size 800 800 -input data/scene07_arch.txt -bounces 4 -shadows \\
            -output a07.png -normals a07n.png -depth 8 18 a07d.png --exr a07.exr

Every problem (a scene error at file:line:col, a bad flag, an output that
cannot be written, a render too large for the machine) is one line on stderr
and exit code 2, found before rendering starts. In a --batch file each course
command line ([PROGRAM] -input FILE ... ; '\\' continues a line) renders on
its own: a bad line prints FILE:LINE: MESSAGE, the other lines still render,
and the exit code is 2 at the end. Blank lines, '#' comments, 'echo ...' and
'mkdir [-p] DIR ...' (which makes DIR) are allowed; any other line is an error.
Limits: -bounces <= {checks.MAX_BOUNCES}; at most {checks.MAX_SAMPLES:,} samples per
render (pixels x spp, x9 with -filter); the memory a render needs must be free."""


@dataclass(frozen=True)
class Preview:
    """--png: a tone-mapped sRGB PNG of the beauty, beside the EXR."""
    exr: Path
    path: Path


class Once(argparse.Action):
    """A flag that takes a value and may be given once: a repeated one (``-output
    a.png -output b.png``) would silently drop the first, and an empty value
    (``--variant ''``) would silently mean "not given"."""

    def __call__(self, parser, namespace, values, option_string=None):
        given = getattr(namespace, "_given", set())
        if self.dest in given:
            raise UsageError(f"{option_string} given twice; give it once")
        words = values if isinstance(values, list) else [values]
        if any(isinstance(word, str) and not word.strip() for word in words):
            raise UsageError(f"{option_string} wants a value, got an empty one")
        namespace._given = given | {self.dest}
        setattr(namespace, self.dest, values)


def build_parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(
        prog="render.py", allow_abbrev=False, formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Render course scenes with Mitsuba (whitted integrator, course camera and cube map).\n"
                    "The course binary's flags (-input -size -output -normals -depth -bounces -shadows\n"
                    "-jitter -filter) are accepted verbatim.",
        epilog=EXAMPLE)
    parser.add_argument("scenes", nargs="*", metavar="SCENE",
                        help=f"scene names or .txt paths (default: {DEFAULT_SCENE}); names are looked up in "
                             "scenes/ and then the course data folder; each renders into --out")
    course = parser.add_argument_group("course binary flags")
    course.add_argument("-input", action=Once, metavar="FILE", help="scene file in the course format (default: none; "
                                                       "then SCENE names are rendered)")
    course.add_argument("-size", action=Once, nargs=2, type=ascii_int, metavar=("W", "H"), default=list(DEFAULT_SIZE),
                        help=f"image width and height in pixels (default: {DEFAULT_SIZE[0]} {DEFAULT_SIZE[1]})")
    course.add_argument("-output", action=Once, metavar="FILE",
                        help="beauty image, .png .bmp .tga (8-bit, course encoding) or .exr (float) (default: none)")
    course.add_argument("-normals", action=Once, metavar="FILE", help="normal image, (N + 1) / 2 (default: none)")
    course.add_argument("-depth", action=Once, nargs=3, metavar=("MIN", "MAX", "FILE"),
                        help="depth image, (t - MIN) / (MAX - MIN), clamped (default: none)")
    course.add_argument("-bounces", action=Once, type=ascii_int, default=0, metavar="N",
                        help=f"mirror bounces, 0..{checks.MAX_BOUNCES} (default: 0, plain ray casting)")
    course.add_argument("-shadows", action="store_true", help="trace shadow rays (default: off)")
    course.add_argument("-jitter", action="store_true", help="16 jittered samples per pixel (default: off)")
    course.add_argument("-filter", action="store_true",
                        help="render at 3x the size, then a 3x3 Gaussian down (default: off)")
    ours = parser.add_argument_group("toolkit options")
    ours.add_argument("--variant", action=Once, help="Mitsuba variant (default: llvm_ad_rgb if a usable LLVM exists, "
                                        "else scalar_rgb with one line saying why)")
    ours.add_argument("--data", action=Once, metavar="DIR",
                      help="course data folder for scene names "
                           f"(default: ${COURSE_ENVIRONMENT}/data, else ../shared/course/data)")
    ours.add_argument("--out", action=Once, metavar="DIR", default="out",
                      help="output folder for named scenes: <out>/<scene>.png (default: out)")
    ours.add_argument("--exr", action=Once, nargs="?", const=True, metavar="FILE",
                      help="also write a multilayer EXR (beauty + depth, normal, position, albedo, id); "
                           "a FILE with -input, <out>/<scene>.exr for named scenes (default: none)")
    ours.add_argument("--png", action="store_true",
                      help="with --exr: also write a tone-mapped sRGB preview PNG beside the EXR "
                           "(<exr name>.png) unless the beauty is already a PNG (default: off)")
    ours.add_argument("--spp", action=Once, type=ascii_int, metavar="N",
                      help=f"samples per pixel, 1..{checks.MAX_SPP} (default: 1, 16 with -jitter)")
    ours.add_argument("--batch", action=Once, metavar="FILE",
                      help="run course command lines from FILE, one per line, in this one process "
                           "(default: none)")
    ours.add_argument("--stats", action="store_true",
                      help="print what each render traced: camera, shadow and mirror rays, environment "
                           "lookups, AOVs and kernels launched (adds counting to the kernel) (default: off)")
    ours.add_argument("--quiet", action="store_true", help="print nothing but errors (default: off)")
    return parser


def _depth(values: list[str] | None):
    if values is None:
        return None
    try:
        near, far = float(values[0]), float(values[1])
    except ValueError:
        raise UsageError(f"-depth wants MIN MAX FILE, got {' '.join(values)}") from None
    if not (math.isfinite(near) and math.isfinite(far)):
        raise UsageError(f"-depth wants finite MIN and MAX, got {values[0]} {values[1]}")
    return DepthOutput(near, far, Path(values[2]))


def jobs_from_args(args: argparse.Namespace) -> list:
    """The render jobs one command line asks for (checked: numbers here, limits
    and outputs in :func:`checked_jobs`)."""
    checks.check_numbers(args.size[0], args.size[1], args.bounces, args.spp)
    check_data_flag(args.data)  # given, it exists: also where no scene is looked up in it
    base = dict(width=args.size[0], height=args.size[1], bounces=args.bounces, shadows=args.shadows,
                jitter=args.jitter, filter=args.filter, spp=args.spp, stats=args.stats)
    single_outputs = dict(output=Path(args.output) if args.output else None,
                          normals=Path(args.normals) if args.normals else None, depth=_depth(args.depth),
                          exr=Path(args.exr) if isinstance(args.exr, str) else None)
    if args.png and not args.exr:
        raise UsageError("--png writes a preview beside the EXR: use it with --exr")
    if args.input:
        if args.scenes:
            raise UsageError("give either -input or scene names, not both")
        if not any(single_outputs.values()):
            raise UsageError("-input needs at least one of -output, -normals, -depth, --exr FILE")
        if args.exr is True:
            raise UsageError("--exr with -input needs a FILE name (--exr out.exr)")
        return [RenderJob(scene=Path(args.input), **base, **single_outputs)]

    data = data_dir(args.data)
    scenes = [resolve_scene(name, data) for name in (args.scenes or [DEFAULT_SCENE])]
    if len(scenes) == 1 and any(single_outputs.values()):
        if args.exr is True:
            raise UsageError("--exr without a FILE writes <out>/<scene>.exr beside <out>/<scene>.png; "
                             "with -output, -normals or -depth give it a FILE (--exr out.exr)")
        return [RenderJob(scene=scenes[0], **with_scene_flags(scenes[0], base), **single_outputs)]
    if any(single_outputs.values()):
        given = [flag for flag, key in (("-output", "output"), ("-normals", "normals"), ("-depth", "depth"),
                                        ("--exr FILE", "exr")) if single_outputs[key]]
        raise UsageError(f"{', '.join(given)} name{'s' if len(given) == 1 else ''} one file: use "
                         f"{'it' if len(given) == 1 else 'them'} with one scene (or --out FOLDER for several)")
    folder = Path(args.out)
    return [with_outputs_in(RenderJob(scene=path, **with_scene_flags(path, base)), folder, path.stem,
                            exr=bool(args.exr)) for path in scenes]


def preview_of(job, wanted: bool) -> Preview | None:
    """--png: ``<exr>.png`` unless the beauty already is a PNG."""
    if not wanted or job.exr is None:
        return None
    if job.output is not None and job.output.suffix.lower() == ".png":
        return None
    return Preview(job.exr, job.exr.with_suffix(".png"))


def checked_jobs(args: argparse.Namespace, seen: dict[str, str] | None = None,
                 memory: int | None = None) -> list[tuple]:
    """``(job, preview)`` pairs for one command line, every check passed."""
    pairs = []
    seen = {} if seen is None else seen
    for job in jobs_from_args(args):
        if not job.scene.is_file():
            kind = ("is a folder" if job.scene.is_dir() else "not a regular file (a device or a pipe?)"
                    if job.scene.exists() else "no such file")
            raise UsageError(f"scene file {job.scene}: {kind}")
        preview = preview_of(job, args.png)
        checks.check_limits(job, memory)
        checks.check_outputs(job, seen, [("--png", preview.path)] if preview else [])
        pairs.append((job, preview))
    return pairs


# -- batches -----------------------------------------------------------------------
#: a batch file is command lines: anything larger is not one (e.g. a device that never ends)
BATCH_BYTES = 16 << 20


def batch_lines(path: Path) -> list[tuple[int, str]]:
    """``(line number, text)`` of each logical line: ``\\`` at the end of a line continues it."""
    try:
        data = read_input(path, limit=BATCH_BYTES, allow_pipe=True)  # `--batch <(grep ...)` is a pipe
    except OSError as error:
        raise UsageError(f"--batch {path}: cannot read it: {error.strerror or error}") from None
    except NotAnInputFile as error:
        raise UsageError(f"--batch {path}: cannot read it: {error}") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as error:
        line = data[: error.start].count(b"\n") + 1
        raise UsageError(f"{path}:{line}: expected text, found binary data") from None
    lines, pending, start = [], None, 0
    for number, line in enumerate(text.splitlines(), start=1):
        if pending is None:
            pending, start = "", number
        trailing = len(line) - len(line.rstrip("\\"))
        if trailing % 2 == 1:  # an odd number of backslashes: the last one escapes the newline
            pending += line[:-1]
            continue
        lines.append((start, pending + line))
        pending = None
    if pending is not None:
        lines.append((start, pending))
    return lines


def _course_words(words: list[str]) -> list[str] | None:
    """The flags of a course command line ``[PROGRAM [SCRIPT]] -flag ...``, or None."""
    skipped = 0
    while words and not words[0].startswith("-") and skipped < 2:
        words, skipped = words[1:], skipped + 1
    if words and words[0].startswith("-") and "-input" in words:
        return words
    return None


@dataclass
class BatchLine:
    where: str  # FILE:LINE
    pairs: list  # (job, preview)


def jobs_from_batch(parser: argparse.ArgumentParser, path: Path, memory: int | None = None
                    ) -> tuple[list[BatchLine], list[str]]:
    """The good lines' jobs, and one ``FILE:LINE: message`` per bad line."""
    from converters.course_scene import load_scene  # noqa: PLC0415  NumPy loads on use: --help stays quick

    good, errors, seen = [], [], {}
    for number, line in batch_lines(path):
        where = f"{path}:{number}"
        try:
            words = shlex.split(line, comments=True)
        except ValueError as error:  # e.g. an unclosed quote
            errors.append(f"{where}: expected a course command line, found {describe(line.strip())} ({error})")
            continue
        if not words:
            continue
        if words[0] in SHELL_WORDS:
            if words[0] == "mkdir":
                folders = [w for w in words[1:] if not w.startswith("-")]
                try:
                    for folder in folders:
                        Path(folder).mkdir(parents=True, exist_ok=True)
                except OSError as error:
                    errors.append(f"{where}: cannot make folder {folder}: {error.strerror or error}")
            continue
        flags = _course_words(words)
        if flags is None:
            errors.append(f"{where}: expected a course command line ([PROGRAM] -input FILE -output FILE ...), "
                          f"found {describe(line.strip())}")
            continue
        try:
            if "-h" in flags or "--help" in flags:
                raise UsageError("-h/--help in a batch file")
            args = parser.parse_args(flags)
            if args.batch:
                raise UsageError("--batch inside a batch file")
            claimed = dict(seen)  # this line's outputs count only if the line is good
            pairs = checked_jobs(args, claimed, memory)
            for job, _ in pairs:  # scene errors now, in line order, not after the lines before render
                load_scene(job.scene)
            seen.update(claimed)
            good.append(BatchLine(where, pairs))
        except ToolkitError as error:
            errors.append(f"{where}: {one_line(error)}")
    if not good and not errors:  # one line saying so, not a count of bad lines that do not exist
        raise UsageError(f"--batch {path}: no course command lines in it (only blank lines, comments "
                         "and shell lines); nothing to render")
    return good, errors


# -- running -------------------------------------------------------------------------
def _write_and_report(result, preview: Preview | None, progress, variant: str) -> None:
    from imaging import colour, image_io  # noqa: PLC0415  NumPy loads on use: --help stays quick


    written = write_outputs(result)
    if preview is not None:
        image_io.write_image(preview.path, colour.to_srgb_8bit(result.layers[""]))
        written.append(preview.path)
    progress.done(result.job, variant, result.seconds, written, result.stats)


def _report(where: str, error: BaseException) -> str:
    return f"{where}: {one_line(error)}" if where else one_line(error)


def _run(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    if args.batch:
        given = [flag for flag, value, default in (
            ("SCENE", args.scenes, []), ("-input", args.input, None), ("-size", args.size, list(DEFAULT_SIZE)),
            ("-output", args.output, None), ("-normals", args.normals, None), ("-depth", args.depth, None),
            ("-bounces", args.bounces, 0), ("-shadows", args.shadows, False), ("-jitter", args.jitter, False),
            ("-filter", args.filter, False), ("--exr", args.exr, None), ("--png", args.png, False),
            ("--spp", args.spp, None), ("--stats", args.stats, False)) if value != default]
        if given:
            raise UsageError(f"--batch takes every render flag from its file; remove {', '.join(given)}")
        lines, errors = jobs_from_batch(parser, Path(args.batch))
        for message in errors:
            print(f"render.py: error: {message}", file=sys.stderr)
    else:
        lines, errors = [BatchLine("", checked_jobs(args))], []
    work = [(line.where, job, preview) for line in lines for job, preview in line.pairs]
    if not work:
        raise UsageError(f"{args.batch}: no line can be rendered ({len(errors)} bad)")

    variant = set_variant(args.variant, quiet=args.quiet)

    failed = len(errors)
    batch = bool(args.batch)
    # Files are written in the background while the next scene renders
    with RenderProgress(total=len(work), enabled=not args.quiet) as progress, \
            ThreadPoolExecutor(max_workers=1) as writer:
        pending = []
        for where, job, preview in work:
            try:
                result = render(job)
            except (ToolkitError, MemoryError) as error:
                if not batch:
                    raise
                failed += 1
                print(f"render.py: error: {_report(where, error)}", file=sys.stderr)
                continue
            pending.append((where, writer.submit(_write_and_report, result, preview, progress, variant)))
        for where, future in pending:
            try:
                future.result()
            except (ToolkitError, OSError) as error:
                if not batch:
                    raise
                failed += 1
                print(f"render.py: error: {_report(where, error)}", file=sys.stderr)
    if failed:
        raise UsageError(f"{args.batch}: {failed} bad line(s) or render(s); the others were rendered")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    return run("render.py", lambda: _run(parser.parse_args(argv), parser))
