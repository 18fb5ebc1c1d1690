"""Converts course scenes to Mitsuba XML (meshes as PLY files beside it).

The render flags go into the XML: -size into the film, -bounces and -shadows
into the whitted integrator, -jitter into the camera and the sampler (16
samples per pixel, or --spp). A flag left at its default takes the value of
the scene's "# render:" header line, if it has one.

-filter: plain Mitsuba has no step after the film, so the XML renders at 3x
the size (the course renders at 3x, then filters down); apply the course's
3x3 Gaussian to the result with imaging.filters.downsample_3x to get the
image that render.py -filter writes.

With one scene, -o names the .xml file (or a folder); with several, -o names
a folder and each scene becomes FOLDER/SCENE.xml. Existing files of the same
name are replaced; two scenes that would write the same file are refused
before anything is written.
"""
from __future__ import annotations

if __name__ == "__main__":
    # first: Ctrl-C and SIGTERM during the imports are one line (core.entry is standard library only)
    from core.start_up import exit_on_signals
    exit_on_signals("python -m converters")
    # then ./.venv's Python, the libLLVM and Dr.Jit (see core.launcher)
    from core.launcher import start
    start("python -m converters", "converters")

import argparse
import os
import sys
import tempfile
from pathlib import Path

import mitsuba as mi

from converters.render_flags import RenderJob, check_numbers, check_samples
from converters.scene_flags import DEFAULTS, with_scene_flags
from core.entry import ArgumentParser, finish, printable, run
from core.errors import OutputError, UsageError
from core.numbers import ascii_int

EXAMPLES = """examples:
  python -m converters scenes/showcase.txt -o showcase.xml
  python -m converters scenes/*.txt -o scenes_xml
  python -m converters ../shared/course/data/scene07_arch.txt -o arch.xml -size 400 400 -bounces 4 -shadows

Load the result in plain Mitsuba with the project's plugins registered and
shape merging off (it would fuse the plane's tiles into one imprecise mesh):
  import mitsuba as mi, mi_plugins
  mi.set_variant("llvm_ad_rgb"); mi_plugins.register()
  image = mi.render(mi.load_file("showcase.xml", optimize=False))
  mi.util.write_bitmap("showcase.exr", image)   # linear EXR; a .png would be sRGB-encoded
"""


def build_parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(
        prog="python -m converters", allow_abbrev=False, formatter_class=argparse.RawDescriptionHelpFormatter,
        description=__doc__, epilog=EXAMPLES)
    parser.add_argument("scenes", nargs="+", type=Path, metavar="SCENE.txt", help="course scene files")
    parser.add_argument("-o", "--output", type=Path, required=True, metavar="OUT",
                        help="the .xml file (one scene) or a folder (required)")
    flags = parser.add_argument_group("render flags (as render.py's; written into the XML)")
    flags.add_argument("-size", nargs=2, type=ascii_int, metavar=("W", "H"),
                       help="image size, the film's width and height (default 800 800)")
    flags.add_argument("-bounces", type=ascii_int, metavar="N", help="mirror bounces, the integrator's bounces "
                                                              "(default 0)")
    flags.add_argument("-shadows", action="store_true", default=None,
                       help="trace shadow rays (default: off)")
    flags.add_argument("-jitter", action="store_true", default=None,
                       help="jittered sample positions, 16 samples per pixel (default: off, pixel centres)")
    flags.add_argument("-filter", action="store_true", default=None,
                       help="a film 3x the size; downsample the render with imaging.filters.downsample_3x "
                            "(default: off)")
    flags.add_argument("--spp", type=ascii_int, metavar="N", help="samples per pixel (default 1, 16 with -jitter)")
    return parser


def render_settings(args: argparse.Namespace) -> dict:
    """The flags given on the command line (None where not given), as settings."""
    settings = {"bounces": args.bounces, "shadows": args.shadows, "jitter": args.jitter, "filter": args.filter,
                "spp": args.spp}
    if args.size is not None:
        settings["width"], settings["height"] = args.size
    for name, value in (("width", settings.get("width")), ("height", settings.get("height")),
                        ("spp", args.spp)):
        if value is not None and value < 1:
            raise UsageError(f"{'--spp' if name == 'spp' else '-size'} wants numbers >= 1, got {value}")
    if args.bounces is not None and args.bounces < 0:
        raise UsageError(f"-bounces wants a number >= 0, got {args.bounces}")
    return {name: value for name, value in settings.items() if value is not None}


def flags_text(settings: dict) -> str:
    """The render flags of ``settings`` as a command line (defaults left out)."""
    words = []
    if (settings.get("width", 800), settings.get("height", 800)) != (800, 800):
        words.append(f"-size {settings['width']} {settings['height']}")
    if settings.get("bounces", 0):
        words.append(f"-bounces {settings['bounces']}")
    words += [f"-{name}" for name in ("shadows", "jitter", "filter") if settings.get(name, DEFAULTS[name])]
    if settings.get("spp") is not None:
        words.append(f"--spp {settings['spp']}")
    return " ".join(words)


def convert(source: Path, target: Path, root: Path | None = None, settings: dict | None = None) -> list[Path]:
    """Writes ``source`` as Mitsuba XML to ``target``; returns the files written.

    ``settings``: render flags as in :func:`render_settings`; the scene's
    ``# render:`` header fills in the ones left out.
    """
    from .course_scene import load_scene  # noqa: PLC0415  NumPy loads on use: --help stays quick
    from .description import scene_dict  # noqa: PLC0415  NumPy loads on use: --help stays quick
    from .xml_writer import write_xml  # noqa: PLC0415  NumPy loads on use: --help stays quick

    scene = load_scene(source.resolve())  # absolute paths, written relative to the XML
    final = with_scene_flags(source, dict(settings or {}))
    job = RenderJob(scene=source, **final)
    # the limits render.py enforces: an XML that no render could run is refused here too
    check_numbers(job.width, job.height, job.bounces, job.spp)
    check_samples(job)  # not its memory: the XML is rendered elsewhere
    options = job.options()
    shown = source.resolve().relative_to(root) if root and source.resolve().is_relative_to(root) else source.name
    note = f"with {flags_text(final)}" if flags_text(final) else "with the default flags"
    if final.get("filter"):
        note += f" (a {options.width}x{options.height} film: downsample with imaging.filters.downsample_3x)"
    return write_xml(scene_dict(scene, options), target, source=str(shown), note=note)


def plan_targets(scenes: list[Path], output: Path) -> list[tuple[Path, Path]]:
    """(scene, XML file) pairs; refuses outputs that collide or cannot be written."""
    if output.suffix.lower() == ".xml" and not output.is_dir():
        if len(scenes) > 1:
            raise UsageError(f"-o {output} names one file; give a folder for {len(scenes)} scenes")
        pairs = [(scenes[0], output)]
    else:
        if output.exists() and not output.is_dir():
            raise OutputError(f"{output} is a file; -o wants a folder here (or a name ending in .xml)")
        pairs = [(scene, output / f"{scene.stem}.xml") for scene in scenes]
    by_target: dict[Path, Path] = {}
    for scene, target in pairs:
        key = Path(os.path.abspath(target))
        if key in by_target:
            raise OutputError(f"{by_target[key]} and {scene} would both be written to {target}; "
                              "convert them into different folders")
        by_target[key] = scene
        if target.is_dir():
            raise OutputError(f"{target} is a folder; cannot write the XML file there")
        meshes = target.parent / f"{target.stem}_meshes"
        if printable(target.stem) != target.stem:  # XML 1.0 holds neither, and reads a newline as a space
            raise UsageError(f"-o {printable(target)}: the XML names its meshes folder {printable(meshes.name)}, "
                             "and an XML file cannot hold a control character or a byte that is not UTF-8: "
                             "choose another name")
        if meshes.exists() and not meshes.is_dir():
            raise OutputError(f"{meshes} is a file; the converter writes the meshes into a folder of that name")
    for folder in dict.fromkeys(target.parent for _, target in pairs):
        _check_writable(folder)
    return pairs


def _check_writable(folder: Path) -> None:
    """Creates ``folder`` and writes a probe file there: the only test that also
    holds for read-only file systems and for root."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as error:
        raise OutputError(f"cannot write into {folder}: {error.strerror or error}") from None


def _main(argv: list[str] | None) -> int:
    args = build_parser().parse_args(argv)
    settings = render_settings(args)
    missing = [str(scene) for scene in args.scenes if not scene.is_file()]
    if missing:
        raise UsageError(f"no scene file {', '.join(missing)}")
    pairs = plan_targets(args.scenes, args.output)
    if mi.variant() is None:
        mi.set_variant("scalar_rgb")  # only for the transform type; no rendering here
    if settings.get("filter"):
        print("converters: note: -filter writes a film 3x the size; downsample the render with "
              "imaging.filters.downsample_3x to get render.py's image", file=sys.stderr)
    for source, target in pairs:
        for path in convert(source, target, root=Path.cwd(), settings=settings):
            print(printable(path))
    return 0


def main(argv: list[str] | None = None) -> int:
    return run("python -m converters", lambda: _main(argv))


if __name__ == "__main__":
    finish(main())
