"""Stress cases for inputs, the error contract, files and batches.

Two kinds:

- :class:`~validation.stress.cases_renderer.Case` scenes: numbers that are legal text
  but not float32 values (or give non-finite derived values), negative
  shininess, deep nesting, damaged and non-square cube-map faces: each must be
  one located ``file:line:col`` error; deep but allowed nesting must render
  like the flat scene;
- :class:`CliCase` command lines of ``render.py`` (run in-process through
  :func:`renderer.cli.main`, in a fresh folder): limits (samples, memory,
  bounces), outputs (distinct, writable, known formats, links, long names),
  entry-point errors (paths, variants, flags) and ``--batch`` files. Each
  states its exit code (0, or 2 with one ``render.py: error:`` line per
  problem) and what the message or the written files must show.
"""
from __future__ import annotations

import contextlib
import io
import os
import struct
import tempfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image

from imaging.image_io import CUBE_FACES
from renderer.cli import main
from validation.stress.cases_inputs_denoiser import denoiser_input_cases
from validation.stress.scene import Case, material, scene


def run_render_cli(folder: Path, argv: list[str]) -> tuple[int, str]:
    """``render.py``'s ``main(argv)`` run in-process in ``folder``: (exit code, stderr).
    Whatever escapes ``main`` propagates (the callers decide what that means)."""
    stderr = io.StringIO()
    cwd = os.getcwd()
    os.chdir(folder)
    try:
        with contextlib.redirect_stderr(stderr), contextlib.redirect_stdout(io.StringIO()):
            code = main(argv)
    finally:
        os.chdir(cwd)
    return code, stderr.getvalue()

FACES = CUBE_FACES
TINY = ["-size", "8", "6", "--quiet"]


def _png(width: int, height: int, seed: int = 0) -> bytes:
    pixels = np.random.default_rng(seed).integers(0, 256, (height, width, 3), np.uint8)
    buffer = io.BytesIO()
    Image.fromarray(pixels).save(buffer, format="PNG")
    return buffer.getvalue()


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _png_header_only(width: int, height: int) -> bytes:
    return (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
            + _chunk(b"IEND", b""))


def _corrupt_idat(data: bytes) -> bytes:
    """The image data's zlib stream garbled (its chunk CRC kept valid)."""
    start = data.index(b"IDAT") - 4
    length = struct.unpack(">I", data[start:start + 4])[0]
    payload = bytes(b ^ 0x5A for b in data[start + 8:start + 8 + length])
    return data[:start] + _chunk(b"IDAT", payload) + data[start + 12 + length:]


def _cube(face: str | None = None, data: bytes = b"") -> dict:
    """Six good 16x16 faces in sky/, ``face`` replaced by ``data``."""
    files = {f"sky/{f}.png": _png(16, 16, i) for i, f in enumerate(FACES)}
    if face is not None:
        files[f"sky/{face}.png"] = data
    return files


def _nested(depth: int, kind: str) -> str:
    """One sphere inside ``depth`` nested Groups or Transforms."""
    inner = "Sphere { center -0.8 0.8 0 radius 0.8 }"
    for level in range(depth):
        if kind == "Group" or (kind == "mixed" and level % 2):
            inner = f"Group {{ numObjects 1 {inner} }}"
        else:
            inner = f"Transform {{ Translate 0 0 0 {inner} }}"
    return inner


def scene_cases() -> list[Case]:
    flat = scene(num_objects=1, objects="MaterialIndex 0 Sphere { center -0.8 0.8 0 radius 0.8 }")
    good_png = _png(64, 64, 7)
    cases = [
        Case("number beyond float32 (1e39)", scene(center="0 1e39 6"), "error", expect="float32"),
        Case("negative number beyond float32", scene(angle="40", up="0 1 -4e38"), "error", expect="float32"),
        Case("OBJ vertex beyond float32", scene(objects="MaterialIndex 0 TriangleMesh { obj_file big.obj }",
                                                num_objects=1), "error",
             expect="big.obj:2:3: expected a number of magnitude",
             files={"big.obj": b"v 0 0 0\nv 5e38 0 0\nv 0 1 0\nf 1 2 3\n"}),
        Case("falloff 1e-40 makes the intensity infinite",
             scene(lights="PointLight { position 1 3 2 color 1 1 1 falloff 1e-40 } "
                          "DirectionalLight { direction 0 -1 0 color 0.2 0.2 0.2 }"),
             "error", expect="light intensity (color * pi / falloff)"),
        Case("bright colour times pi overflows", scene(lights="DirectionalLight { direction 0 -1 0 color 2e38 1 1 } "
                                                              "DirectionalLight { direction 1 -1 0 color 1 1 1 }"),
             "error", expect="light irradiance"),
        Case("nested scales overflow float32", scene(num_objects=1, objects=(
            "MaterialIndex 0 Transform { UniformScale 1e20 Transform { UniformScale 1e20 "
            "Sphere { center 0 0 0 radius 1 } } }")), "error", expect="transform matrix within float32"),
        Case("scale of 1e-39 (its inverse overflows float32)", scene(num_objects=1, objects=(
            "MaterialIndex 0 Transform { UniformScale 1e-39 Sphere { center 0 0 0 radius 1 } }")), "error",
             expect="inverse transform matrix within float32"),
        Case("vertex moved beyond float32", scene(num_objects=1, objects=(
            "MaterialIndex 0 Transform { Translate 3e38 0 0 Triangle { vertex0 3e38 0 0 vertex1 0 1 0 "
            "vertex2 0 0 1 } }")), "error", expect="world-space coordinates"),
        Case("light direction of length 1e-39 (float32 squares it to 0)",
             scene(lights="DirectionalLight { direction -3e-40 -1e-39 -5e-40 color 0.7 0.7 0.7 } "
                          "PointLight { position 1 3 2 color 1 1 1 falloff 0.2 }"), "error",
             expect="light direction of length"),
        Case("light direction of length 1e-10 renders like a unit one",
             scene(lights="DirectionalLight { direction -0.3e-10 -1e-10 -0.5e-10 color 0.7 0.7 0.7 } "
                          "PointLight { position 1 3 2 color 1 1 1 falloff 0.2 }"), "render", match=scene()),
        Case("camera direction of length 1e-40", scene(direction="0 -1e-41 -1e-40"), "error",
             expect="finite float32 rays"),
        Case("camera angle 1e-50 degrees", scene(angle="1e-50"), "error", expect="finite float32 rays"),
        Case("camera up of length 1e30", scene(up="0 1e30 0"), "error", expect="finite float32 rays"),
        Case("camera direction of length 1e-12 renders like a unit one", scene(direction="0 -0.1e-12 -1e-12"),
             "render", match=scene()),
        Case("negative shininess", scene(materials=material(shininess="-3")), "error", expect="shininess >= 0"),
        Case("shininess -1e-9", scene(materials=material(shininess="-1e-9")), "error", expect="shininess >= 0"),
        Case("1000 nested groups", scene(num_objects=1, objects="MaterialIndex 0 " + _nested(1000, "Group")),
             "error", expect="nested groups"),
        Case("600 nested transforms", scene(num_objects=1, objects="MaterialIndex 0 " + _nested(600, "Transform")),
             "error", expect="nested groups"),
        Case("5000 nested groups and transforms", scene(num_objects=1,
                                                        objects="MaterialIndex 0 " + _nested(5000, "mixed")),
             "error", expect="nested groups"),
        Case("150 nested groups and transforms render like the flat scene",
             scene(num_objects=1, objects="MaterialIndex 0 " + _nested(150, "mixed")), "render", match=flat),
        Case("cube-map face truncated", scene(background="cubeMap sky"), "error", expect="sky/up.png:1:1",
             files=_cube("up", good_png[: len(good_png) * 3 // 4])),
        Case("cube-map face with garbled image data", scene(background="cubeMap sky"), "error",
             expect="front.png:1:1", files=_cube("front", _corrupt_idat(good_png))),
        Case("cube-map face declaring 10^10 pixels", scene(background="cubeMap sky"), "error",
             expect="down.png:1:1", files=_cube("down", _png_header_only(100000, 100000))),
        Case("cube-map face of size 0", scene(background="cubeMap sky"), "error", expect="left.png:1:1",
             files=_cube("left", _png_header_only(0, 0))),
        Case("cube-map face with a bad header CRC", scene(background="cubeMap sky"), "error",
             expect="back.png:1:1", files=_cube("back", _png(16, 16)[:29] + b"\0\0\0\0" + _png(16, 16)[33:])),
        Case("cube-map face not square", scene(background="cubeMap sky"), "error", expect="square",
             files=_cube("right", _png(16, 8))),
        Case("cube-map faces of different sizes", scene(background="cubeMap sky"), "error", expect="same size",
             files=_cube("up", _png(32, 32))),
        Case("cube-map face that is text", scene(background="cubeMap sky"), "error", expect="up.png:1:1",
             files=_cube("up", b"P3\n2 2\n255\n")),
    ]
    return cases


# -- command lines ---------------------------------------------------------------------
@dataclass(frozen=True)
class CliCase:
    """``render.py ARGV`` in a fresh folder (``{dir}`` in an argument is that folder).

    ``files``: name -> bytes to create first (``"->target"`` makes a symbolic
    link, ``"/"`` a folder, ``"|"`` a named pipe, ``"ro:"`` prefix a read-only file); ``code``: the
    exit code; ``expect``: pieces of stderr; ``written``/``absent``: files
    that must / must not exist afterwards (``links``: must still be links).
    """
    name: str
    argv: tuple[str, ...]
    code: int
    expect: tuple[str, ...] = ()
    files: dict = field(default_factory=dict)
    written: tuple[str, ...] = ()
    absent: tuple[str, ...] = ()
    links: tuple[str, ...] = ()
    lines: int | None = None  # exactly this many lines on stderr
    fast: bool = True
    kind: str = "cli"

    def check(self) -> tuple[bool, str]:
        with tempfile.TemporaryDirectory() as tmp:
            folder = Path(tmp)
            _make_files(folder, self.files)
            argv = [a.replace("{dir}", str(folder)) for a in self.argv]
            try:
                code, text = run_render_cli(folder, argv)
            except BaseException as error:  # noqa: BLE001 - anything escaping main is the failure
                return False, f"escaped main: {type(error).__name__}: {error}"
            text = text.replace(str(folder) + os.sep, "").replace(str(folder), ".")
            problems = contract_problems(code, text, batch="--batch" in argv)
            if code != self.code:
                problems.append(f"exit code {code}, expected {self.code}")
            problems += [f"no {piece!r} in stderr" for piece in self.expect if piece not in text]
            if self.lines is not None and len(text.strip().splitlines()) != self.lines:
                problems.append(f"{len(text.strip().splitlines())} lines on stderr, expected {self.lines}")
            problems += [f"{name} not written" for name in self.written if not (folder / name).exists()]
            problems += [f"{name} exists" for name in self.absent if os.path.lexists(folder / name)]
            problems += [f"{name} is no longer a link" for name in self.links if not (folder / name).is_symlink()]
            leftovers = [p.name for p in folder.rglob(".*") if p.is_file()]
            problems += [f"temporary file {name} left" for name in leftovers]
            detail = " ".join(text.split())[:300] or f"exit {code}"
            return not problems, "; ".join(problems) or detail


def contract_problems(code: int, stderr: str, batch: bool) -> list[str]:
    """The error contract: exit 0, or exit 2 with one ``render.py: error:`` line
    (a batch: one per bad line, then a summary); never a traceback."""
    lines = [line for line in stderr.splitlines() if line.strip()]
    problems = []
    if "Traceback" in stderr:
        problems.append("traceback")
    if code not in (0, 2):
        problems.append(f"exit code {code}")
    errors = [line for line in lines if line.startswith("render.py: error: ")]
    if code == 2 and not errors:
        problems.append("exit 2 without an error line")
    if code == 2 and not batch and len(lines) != 1:
        problems.append(f"{len(lines)} lines on stderr, expected 1")
    if code == 0 and errors:
        problems.append("error lines with exit 0")
    return problems


def _make_files(folder: Path, files: dict) -> None:
    for name, data in files.items():
        path = folder / name
        path.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(data, str) and data.startswith("->"):
            os.symlink(data[2:].replace("{dir}", str(folder)), path)
        elif data == "/":
            path.mkdir(exist_ok=True)
        elif data == "|":
            os.mkfifo(path)
        elif isinstance(data, str) and data.startswith("ro:"):
            path.write_text(data[3:])
            path.chmod(0o444)
        else:
            path.write_bytes(data.replace(b"{dir}", str(folder).encode()) if isinstance(data, bytes) else data)


SCENE = scene().encode()


def cli_cases() -> list[CliCase]:
    scene_file = {"s.txt": SCENE}
    inp = ["-input", "s.txt"]
    long_name = "n" * 251 + ".png"  # 255 bytes, the longest name most file systems allow
    cases = [
        # limits: refused at once, before the variant is set
        CliCase("more than 2^32 samples (-jitter -filter at 5600^2)",
                (*inp, "-size", "5600", "5600", "-jitter", "-filter", "-output", "a.png"), 2,
                ("samples", "32-bit"), scene_file, absent=("a.png",)),
        CliCase("more than 2^32 samples (70000^2)", (*inp, "-size", "70000", "70000", "-output", "a.png"), 2,
                ("samples",), scene_file),
        CliCase("--spp of 10^9", (*inp, "-size", "8", "8", "--spp", "1000000000", "-output", "a.png"), 2,
                ("--spp wants",), scene_file),
        CliCase("render needing terabytes of memory", (*inp, "-size", "60000", "60000", "--exr", "a.exr"), 2,
                ("memory", "available"), scene_file, absent=("a.exr",)),
        CliCase("-bounces 10^9", (*inp, *TINY, "-bounces", "1000000000", "-output", "a.png"), 2,
                ("-bounces wants a number in 0..",), scene_file),
        CliCase("-bounces -1", (*inp, *TINY, "-bounces", "-1", "-output", "a.png"), 2, ("-bounces",), scene_file),
        CliCase("-size 0 6", (*inp, "-size", "0", "6", "-output", "a.png"), 2, ("-size",), scene_file),
        CliCase("-size 1e3 8 (not an integer)", (*inp, "-size", "1e3", "8", "-output", "a.png"), 2,
                ("-size",), scene_file),
        CliCase("-depth with nan", (*inp, *TINY, "-depth", "0", "nan", "d.png"), 2, ("-depth",), scene_file),
        CliCase("a mistyped flag", (*inp, *TINY, "-bouncez", "2", "-output", "a.png"), 2,
                ("unrecognized arguments",), scene_file),
        # outputs: checked before rendering
        CliCase("two outputs on one file", (*inp, *TINY, "-output", "a.png", "-normals", "a.png"), 2,
                ("same file",), scene_file, absent=("a.png",)),
        CliCase("one file spelt two ways", (*inp, *TINY, "-output", "a.png", "-depth", "0", "1", "sub/../a.png"), 2,
                ("same file",), {**scene_file, "sub": "/"}),
        CliCase("one file through a link", (*inp, *TINY, "-output", "a.png", "-normals", "link.png"), 2,
                ("same file",), {**scene_file, "link.png": "->a.png"}),
        CliCase("two named scenes onto one out/<stem>.png", ("one/s.txt", "two/s.txt", *TINY, "--out", "o"), 2,
                ("same file",), {"one/s.txt": SCENE, "two/s.txt": SCENE}, absent=("o",)),
        CliCase("unknown image format", (*inp, *TINY, "-output", "a.jpg"), 2, ("unknown image format",),
                scene_file),
        CliCase("--exr FILE that is not .exr", (*inp, *TINY, "--exr", "a.png"), 2, (".exr",), scene_file),
        CliCase("output without a suffix", (*inp, *TINY, "-normals", "normals"), 2, ("format",), scene_file),
        CliCase("output is a folder", (*inp, *TINY, "-output", "out.png"), 2, ("is a folder",),
                {**scene_file, "out.png": "/"}),
        CliCase("output folder is a file", (*inp, *TINY, "-output", "notes.txt/a.png"), 2, ("is a file",),
                {**scene_file, "notes.txt": b"x"}),
        CliCase("output onto a named pipe (not replaced by a file)", (*inp, *TINY, "-normals", "pipe.png"), 2,
                ("not a regular file",), {**scene_file, "pipe.png": "|"}),
        CliCase("read-only existing output", (*inp, *TINY, "-output", "a.png"), 2, ("read-only",),
                {**scene_file, "a.png": "ro:old"}),
        CliCase("255-byte output name", (*inp, *TINY, "-output", long_name), 0, (), scene_file,
                written=(long_name,)),
        CliCase("output through a link replaces its target", (*inp, *TINY, "-output", "link.png"), 0, (),
                {**scene_file, "real/a.png": b"old", "link.png": "->real/a.png"}, written=("real/a.png",),
                links=("link.png",)),
        CliCase("output into new folders", (*inp, *TINY, "-output", "x/y/z/a.png"), 0, (), scene_file,
                written=("x/y/z/a.png",)),
        CliCase("--exr --png writes a preview", (*inp, *TINY, "--exr", "a.exr", "--png"), 0, (), scene_file,
                written=("a.exr", "a.png")),
        CliCase("bare --exr beside -output (would be ignored)", ("one/s.txt", *TINY, "-output", "a.png", "--exr"), 2,
                ("--exr",), {"one/s.txt": SCENE}, absent=("a.png",)),
        CliCase("--png without --exr", (*inp, *TINY, "-output", "a.png", "--png"), 2, ("--png",), scene_file),
        # the entry point: paths, variants
        CliCase("mistyped absolute scene path", ("/nonexistent-folder/scenes/s.txt", *TINY), 2,
                ("/nonexistent-folder/scenes/s.txt",)),
        CliCase("scene path to a folder", ("sub/", *TINY), 2, ("is a folder",), {"sub": "/"}),
        CliCase("-input that does not exist", ("-input", "nowhere.txt", *TINY, "-output", "a.png"), 2,
                ("nowhere.txt",)),
        CliCase("unknown variant", (*inp, *TINY, "-output", "a.png", "--variant", "llvm_ad_rbg"), 2,
                ("--variant",), scene_file),
        CliCase("spectral variant", (*inp, *TINY, "-output", "a.png", "--variant", "scalar_spectral"), 2,
                ("RGB variant",), scene_file),
        # batches
        CliCase("batch: bad lines reported, good lines rendered",
                ("--batch", "b.sh", "--quiet"), 2,
                ("b.sh:2: -size wants positive", "b.sh:3: expected a course command line",
                 "b.sh:5: bad.txt:1:1: expected a PerspectiveCamera"),
                {**scene_file, "bad.txt": b"", "b.sh": b"a2 -input s.txt -size 8 6 -output a.png\n"
                                                      b"a2 -input s.txt -size 0 6 -output b.png\n"
                                                      b"clear\n"
                                                      b"a2 -input s.txt -size 8 6 -output c.png\n"
                                                      b"a2 -input bad.txt -size 8 6 -output d.png\n"},
                written=("a.png", "c.png"), absent=("out", "b.png", "d.png")),
        CliCase("batch: a stray word renders nothing", ("--batch", "b.sh", "--quiet"), 2,
                ("b.sh:1: expected a course command line",), {"b.sh": b"clear\n"}, absent=("out",)),
        CliCase("batch: shell lines, continuations, comments", ("--batch", "b.sh", "--quiet"), 0, (),
                {**scene_file, "b.sh": b"#!/bin/sh\n# grading\nmkdir -p results\necho rendering...\n\n"
                 b"${BIN} -size 8 6 \\\n    -input s.txt \\\n    -output results/a.png   # first\n"
                 b"python3 render.py -input s.txt -size 8 6 -normals 'results/n n.png'\n"},
                written=("results/a.png", "results/n n.png")),
        CliCase("batch: two lines onto one file", ("--batch", "b.sh", "--quiet"), 2, ("b.sh:2:", "same file"),
                {**scene_file, "b.sh": b"a2 -input s.txt -size 8 6 -output a.png\n"
                                       b"a2 -input s.txt -size 8 6 -normals a.png\n"}, written=("a.png",)),
        CliCase("batch: unclosed quote", ("--batch", "b.sh", "--quiet"), 2, ("b.sh:1:",),
                {**scene_file, "b.sh": b"a2 -input s.txt -output 'a.png\n"}),
        CliCase("batch: cd is not ours", ("--batch", "b.sh", "--quiet"), 2, ("b.sh:1: expected a course",),
                {**scene_file, "b.sh": b"cd data\n"}),
        CliCase("batch: --help on a line", ("--batch", "b.sh", "--quiet"), 2, ("b.sh:2: -h/--help",),
                {**scene_file, "b.sh": b"a2 -input s.txt -size 8 6 -output a.png\na2 -input s.txt --help\n"},
                written=("a.png",)),
        CliCase("batch with render flags on the command line", ("--batch", "b.sh", "-size", "8", "8"), 2,
                ("remove -size",), {**scene_file, "b.sh": b"a2 -input s.txt -size 8 6 -output a.png\n"},
                absent=("a.png",)),
        CliCase("batch file missing", ("--batch", "nowhere.sh"), 2, ("nowhere.sh",)),
        CliCase("batch: an empty file is one line", ("--batch", "b.sh"), 2, ("no course command lines",),
                {"b.sh": b""}, lines=1),
        CliCase("batch: only comments and shell lines is one line", ("--batch", "b.sh"), 2,
                ("no course command lines",), {"b.sh": b"# grading\nmkdir -p res\necho done\n"}, lines=1,
                written=("res",)),
        CliCase("output into a folder reached through a link", (*inp, *TINY, "-output", "link/a.png"), 0, (),
                {**scene_file, "real/deep": "/", "link": "->real/deep"}, written=("real/deep/a.png",),
                links=("link",)),
        CliCase("output through a dangling link", (*inp, *TINY, "-output", "a.png"), 0, (),
                {**scene_file, "a.png": "->gone/a.png"}, written=("gone/a.png",), links=("a.png",)),
        CliCase("batch file is binary", ("--batch", "b.sh"), 2, ("binary",), {"b.sh": b"\xff\xfe\x00garbage"}),
    ]
    return cases


def all_input_cases() -> list:
    return scene_cases() + cli_cases() + denoiser_input_cases()
