"""``python -m converters SCENE.txt [SCENE.txt ...] -o OUT.xml|OUT_DIR``

Converts course scenes to Mitsuba XML (meshes as PLY beside it). With several
scenes, or an existing folder, ``-o`` names the folder and each scene becomes
``<folder>/<scene>.xml``. Errors are one line ``file:line:col: ...``.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .course_scene import load_scene
from .errors import SceneError


def convert(source: Path, target: Path, root: Path | None = None) -> list[Path]:
    from .to_mitsuba import RenderOptions, scene_dict
    from .xml_writer import write_xml

    scene = load_scene(source.resolve())  # absolute paths, written relative to the XML
    shown = source.resolve().relative_to(root) if root and source.resolve().is_relative_to(root) else source.name
    return write_xml(scene_dict(scene, RenderOptions()), target, source=str(shown))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m converters", description=__doc__.split("\n\n")[0])
    parser.add_argument("scenes", nargs="+", type=Path, metavar="SCENE.txt")
    parser.add_argument("-o", "--output", type=Path, required=True, metavar="OUT",
                        help="output .xml file, or folder for several scenes")
    args = parser.parse_args(argv)
    import mitsuba as mi

    mi.set_variant("scalar_rgb")  # only for the transform type; no rendering here
    to_folder = len(args.scenes) > 1 or args.output.is_dir() or args.output.suffix != ".xml"
    try:
        for source in args.scenes:
            target = args.output / f"{source.stem}.xml" if to_folder else args.output
            for path in convert(source, target, root=Path.cwd()):
                print(path)
    except SceneError as error:
        print(f"converters: error: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
