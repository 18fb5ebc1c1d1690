"""Stress cases for the denoiser's commands' inputs (the outside round's classes):
every JSON input one line through one reader, sizes that disagree, frame numbers
far apart, outputs into input folders, every PNG mode read as its pixels."""
from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np
from PIL import Image

from validation.stress.cases_surfaces import refusals
from validation.stress.cases_system import SystemCase, one_error_line
from validation.stress.system import python, run_command

#: the project's scene files
SCENES = Path(__file__).resolve().parents[2] / "scenes"
#: a spec's damage -> the words of its one line (the reader's limits and error shape)
DAMAGED_SPECS = {
    "UTF-16": ('{"scene": "lamps"}'.encode("utf-16"), "UTF-16"),
    "Latin-1": ('{"scene": "l\u00e4mps"}'.encode("latin-1"), "not UTF-8"),
    "5000 digits": (b'{"scene": "lamps", "seed": ' + b"9" * 5000 + b"}", "5000 digits"),
    "100000 deep": (b'{"scene": "lamps", "seed": ' + b"[" * 100000 + b"]" * 100000 + b"}", "nested"),
    "a light key twice": (b'{"scene": "lamps", "lights": {"0": {"scale": 2}, "0": {"scale": 3}}}',
                          'key "0" given twice'),
    "1e999": (b'{"scene": "lamps", "camera": {"dolly": 1e999}}', "too large for a float"),
    "NaN": (b'{"scene": "lamps", "camera": {"dolly": NaN}}', "NaN is not a JSON number"),
    "megabytes": (b'{"scene": "' + b"x" * (2 << 20) + b'"}', "larger than"),
    "a string for a number": (b'{"scene": "lamps", "camera": {"dolly": "1"}}', "camera.dolly: expected a finite"),
}


def damaged_json(folder: Path) -> list[str]:
    from export.cli import main as export  # noqa: PLC0415  Dr.Jit loads after the suite chose its variant

    cases = {}
    for k, (name, (data, words)) in enumerate(DAMAGED_SPECS.items()):
        (folder / f"spec{k}.json").write_bytes(data)
        cases[name] = ([folder / f"spec{k}.json", folder / "out", "--local"], words)
    return refusals("python -m export", export, cases)


def _exr_folder(folder: Path, sizes: list[tuple[int, int]], name: str = "beauty") -> Path:
    from imaging.image_io import write_exr  # noqa: PLC0415  as above

    folder.mkdir()
    for i, (height, width) in enumerate(sizes):
        write_exr(folder / f"{name}_{i}.exr", {"": np.ones((height, width, 3), np.float32)})
    return folder


def sizes_gaps_and_outputs(folder: Path) -> list[str]:
    """Sizes that disagree, frame numbers far apart, outputs into inputs: one line each, at once."""
    from denoise.__main__ import main as denoise  # noqa: PLC0415  as above
    from denoise.score import main as score  # noqa: PLC0415  as above

    reference = _exr_folder(folder / "ref", [(6, 8), (6, 4)])
    results = _exr_folder(folder / "res", [(6, 8), (6, 4)], "result")
    far = folder / "far"
    far.mkdir()
    for index in (0, 10 ** 12):
        (far / f"beauty_{index}.exr").write_bytes(b"")
    start = time.perf_counter()
    problems = refusals("python -m denoise.score", score, {
        "reference frames of two sizes": ([results, "--reference", reference], "ref/beauty_0.exr has 8x6"),
        "--plot into the reference": ([results, "--reference", reference, "--plot", reference / "p.png"],
                                      "is inside the input folder --reference"),
    }) + refusals("python -m denoise", denoise, {
        "frames 0 and 10^12": ([far, folder / "o", "--method", "svgf"], f"without {far / 'beauty_1.exr'}"),
        "results into the frames": ([far, far, "--method", "svgf"], "is the input IN_DIR"),
    })
    if time.perf_counter() - start > 30:
        problems.append(f"took {time.perf_counter() - start:.0f} s")
    return problems


def png_modes(folder: Path) -> list[str]:
    """Every PNG mode Pillow writes, from the same pixels, reads as those pixels; 16 bits per channel
    round to the nearest 8-bit value (not the high byte); transparent pixels and another format
    under a .png name are one line each, through the scores' one reader."""
    from mitsuba import Bitmap  # noqa: PLC0415  as above

    from core.errors import FrameError  # noqa: PLC0415  as above
    from imaging.image_io import read_png  # noqa: PLC0415  as above

    grey = np.random.default_rng(1).integers(0, 256, (5, 7), np.uint8)
    opaque = np.full_like(grey, 255)
    writes = {"L": Image.fromarray(grey), "I;16": Image.fromarray(grey.astype(np.uint16) * 257),
              "LA": Image.fromarray(np.dstack([grey, opaque]), "LA"), "RGB": Image.fromarray(np.dstack([grey] * 3)),
              "P": Image.fromarray(np.dstack([grey] * 3)).quantize(256)}
    problems = []
    for mode, image in writes.items():
        image.save(folder / "a.png")
        error = np.abs(read_png(folder / "a.png")[..., 1].astype(int) - grey).max()
        if error > (4 if mode == "P" else 0):
            problems.append(f"{mode}: off by {error}")
    offset = np.where((grey == 0) | ((grey >= 128) & (grey < 255)), 128, -128)  # the high byte is off by one
    deep = (grey.astype(np.int64) * 257 + offset).astype(np.uint16)
    Bitmap(np.dstack([deep] * 3)).write(str(folder / "deep.png"))  # Pillow writes no 16-bit colour
    if not np.array_equal(read_png(folder / "deep.png")[..., 0], grey):
        problems.append("16-bit RGB: not rounded to its 8-bit values")
    Image.fromarray(np.dstack([grey, grey, grey, np.where(grey > 9, 255, 0).astype(np.uint8)])).save(folder / "t.png")
    Image.fromarray(np.dstack([grey] * 3)).save(folder / "j.png", "JPEG")
    for name, words in (("t.png", "are transparent or translucent"), ("j.png", "a JPEG file, not a PNG")):
        try:
            read_png(folder / name)
            problems.append(f"{name}: read, expected {words!r}")
        except FrameError as error:
            if words not in str(error):
                problems.append(f"{name}: {error}")
    return problems


def flags_addresses_and_records(folder: Path) -> list[str]:
    """A flag over a damaged key, a flag out of range, a scene path out of a spec,
    scheduler addresses, a missing --data, outputs into a spec's folder or a truth,
    ids beyond any integer: one line each, before any work."""
    import warnings  # noqa: PLC0415  only this case turns warnings into errors

    from core.errors import FrameError  # noqa: PLC0415  as above
    from denoise.__main__ import main as denoise  # noqa: PLC0415  as above
    from export.cli import main as export  # noqa: PLC0415  as above
    from export.frames import FrameData, read_frame, write_frame  # noqa: PLC0415  as above
    from imaging.image_io import write_exr  # noqa: PLC0415  as above

    good, bad = folder / "good.json", folder / "bad.json"
    good.write_text('{"scene": "lamps", "frames": 2, "size": [8, 6], "reference_spp": 2}')
    bad.write_text('{"scene": "lamps", "frames": "8"}')
    (folder / "passwd.json").write_text('{"scene": "../../../../etc/passwd"}')
    out = [folder / "out", "--local"]
    cases = {"--frames over a damaged frames": ([bad, *out, "--frames", "2"], "bad.json: frames: expected an integer"),
             "--reference-spp 1": ([good, *out, "--reference-spp", "1"], "--reference-spp: expected 2..")}
    cases["a scene path out of the spec"] = ([folder / "passwd.json", *out], "passwd.json: scene: expected a scene")
    cases["--data missing"] = ([good, *out, "--data", folder / "missing"], "does not exist")
    cases["OUT is the spec's folder"] = ([good, folder, "--local"], "is the folder of the input SPEC.json")
    for address in ("bogus", "127.0.0.1", "tcp://", "tcp://[::1", "inproc://x", "ucx://127.0.0.1:1"):
        cases[f"--scheduler {address}"] = ([good, folder / "out", "--scheduler", address], "--scheduler")
    frames = folder / "seq"
    rgb = np.ones((2, 3, 3), np.float32)
    write_frame(frames, 0, FrameData(rgb, rgb, rgb, rgb[..., 0], np.zeros((2, 3), np.int32), [np.eye(4)],
                                     np.eye(4), np.eye(4)))
    problems = refusals("python -m export", export, cases) + refusals("python -m denoise", denoise, {
        "results into IN_DIR's ground truth": ([frames, folder / "seq_reference", "--method", "svgf"],
                                               "is the input IN_DIR's ground truth")})
    write_exr(frames / "ID_0.exr", {"": np.full((2, 3), 1e30, np.float32)})
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            read_frame(frames, 0)
        problems.append("an id of 1e30 was read")
    except FrameError as error:
        if "ID_0.exr: object id 1.0000000150" not in str(error):
            problems.append(f"an id of 1e30: {error}")
    except RuntimeWarning as warning:
        problems.append(f"an id of 1e30 warned: {warning}")
    return problems


def odd_names_on_stdout(folder: Path) -> list[str]:
    """A newline, an escape sequence and a byte that is not UTF-8 in the paths a user gives:
    every line on stdout stays one printable line, and an EXR is written and read there."""
    import contextlib  # noqa: PLC0415  as above
    import io  # noqa: PLC0415  as above

    from converters.__main__ import main as converters  # noqa: PLC0415  as above
    from course.score import main as course_score  # noqa: PLC0415  as above
    from denoise.__main__ import main as denoise  # noqa: PLC0415  as above
    from export.frames import FrameData, write_frame  # noqa: PLC0415  as above

    odd = os.fsdecode(b"x\ny\x1b[31m\xff")
    for name in ("mine", "ref"):
        (folder / name).mkdir()
        Image.fromarray(np.zeros((4, 6, 3), np.uint8)).save(folder / name / f"a{odd}.png")
    rgb = np.full((4, 6, 3), 0.5, np.float32)
    write_frame(folder / odd, 0, FrameData(rgb, rgb, rgb, rgb[..., 0] + 1, np.zeros((4, 6), np.int32), [np.eye(4)],
                                           np.eye(4), np.eye(4)))
    runs = {"python -m course.score": (course_score, [folder / "mine", "--reference", folder / "ref", "--report",
                                                      folder / f"{odd}.md"]),
            "python -m converters": (converters, [SCENES / "mirrors.txt", "-o", folder / odd / "m.xml"]),
            "python -m denoise": (denoise, [folder / odd, folder / f"{odd}2", "--method", "svgf"])}
    problems = []
    for prog, (main, argv) in runs.items():
        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = main([str(a) for a in argv])
        lines = out.getvalue().splitlines()
        if code != 0 or err.getvalue() or not lines or not all(line.isprintable() for line in lines):
            problems.append(f"{prog}: exit {code}, stdout {out.getvalue()[-120:]!r}, stderr {err.getvalue()[-200:]!r}")
    return problems


def training_inputs(folder: Path) -> list[str]:
    """``python -m denoise.train``: a zero-byte checkpoint, a benchmark scene by path and
    an output inside --work's frame folders are one line each, before any rendering."""
    from denoise.train import main as train  # noqa: PLC0415  as above

    tiny = {"scene": "showcase", "frames": 2, "size": [16, 9], "spp": 1, "reference_spp": 2}
    (folder / "tiny.json").write_text(json.dumps(tiny))
    (folder / "bench.json").write_text(json.dumps({**tiny, "scene": str(SCENES / "." / "lamps.txt")}))
    (folder / "work").mkdir()
    (folder / "work" / "w.checkpoint.npz").write_bytes(b"")
    base = ["--work", folder / "work", "--out", folder / "w.json", "--plot", folder / "w.png", "--steps", "1"]
    problems = refusals("python -m denoise.train", train, {
        "a zero-byte checkpoint": ([folder / "tiny.json", *base], "w.checkpoint.npz: not a training checkpoint"),
        "a benchmark scene by path": ([folder / "bench.json", *base], "is the benchmark's"),
        "--out in a frame folder": ([folder / "tiny.json", *base, "--out", folder / "work" / "tiny" / "x.json"],
                                    "inside the input frame folder (--work)")})
    return problems + [f"{p.name} was written" for p in (folder / "w.json", folder / "work" / "tiny") if p.exists()]


def validation_inputs(folder: Path) -> list[str]:
    """``python -m denoise.validate``: a sequence without judged frames, --json inside
    a sequence's folder under --work and a weights file with a string for a number are
    one line each, before any rendering."""
    from denoise.validate import main as validate  # noqa: PLC0415  as above

    short = {"scene": "showcase", "frames": 3, "size": [16, 9], "spp": 1, "reference_spp": 2}
    (folder / "short.json").write_text(json.dumps(short))
    (folder / "long.json").write_text(json.dumps({**short, "frames": 6}))
    weights = json.loads((SCENES.parent / "denoise" / "learned_asvgf.json").read_text())
    weights["w1"][0][0] = "0.5"
    (folder / "w.json").write_text(json.dumps(weights))
    base = ["--work", folder / "work", "--methods", "asvgf"]
    problems = refusals("python -m denoise.validate", validate, {
        "3 frames": ([folder / "short.json", *base], "at least"),
        "--json in a frame folder": ([folder / "long.json", *base, "--json", folder / "work" / "long" / "x.json"],
                                     "inside"),
        "a string for a weight": ([folder / "long.json", *base, "--network", folder / "w.json"], "not a number")})
    return problems + ["--work was rendered into"] * (folder / "work").exists()


#: a student's method file with ``{options}`` declared and ``{body}`` as its filter
METHOD_FILE = """from denoise.methods import DenoisingMethod, Option


class Mine(DenoisingMethod):
    name, description = "mine", "a broken method"
    options = {options}

    def filter(self, arrays, frame, index, valid):
        {body}
"""
#: (options, filter body, words of the one error line)
BROKEN_METHODS = {
    "an Option with action='version'": ("(Option('w', False, 'h', kind=None, action='version'),)",
                                        "return arrays.tensor(arrays.color)", "action"),
    "GeneratorExit in filter()": ("()", "raise GeneratorExit", "GeneratorExit"),
    "a % in a help text, then --help": ("(Option('w', 1.0, 'h %', low=0.0),)", "return arrays.tensor(arrays.color)",
                                       None)}


def broken_method_files(folder: Path) -> list[str]:
    """``python -m denoise --method-file``: a declaration argparse cannot take and an
    exception that is not an Exception are one line naming the file; a ``%`` in a
    help text is printed as written by ``--help``."""
    (folder / "tiny.json").write_text(json.dumps({"scene": "showcase", "frames": 2, "size": [16, 9], "spp": 1,
                                                  "reference_spp": 2}))
    code, _, err = run_command(python("-m", "export", folder / "tiny.json", folder / "seq", "--local"))
    if code:
        return [f"the export failed: {err.strip()[-200:]}"]
    problems = []
    for name, (options, body, expect) in BROKEN_METHODS.items():
        path = folder / "mine.py"
        path.write_text(METHOD_FILE.format(options=options, body=body))
        tail = ["--help"] if expect is None else [folder / "seq", folder / "out", "--method", "mine"]
        code, out, err = run_command(python("-m", "denoise", "--method-file", path, *tail))
        if expect is None:
            problems += [] if code == 0 and "h %" in out else [f"{name}: exit {code}: {err.strip()[-200:]!r}"]
            continue
        problems += [f"{name}: {p}: {err.strip()[-200:]!r}" for p in
                     one_error_line(code, err, "python -m denoise", expect) + ([] if "mine.py" in err else ["no file"])]
    return problems + ["results written"] * bool(list((folder / "out").glob("result_*")))


def denoiser_input_cases() -> list[SystemCase]:
    return [SystemCase("every JSON input: damaged specs are one line", damaged_json, fast=True, kind="inputs"),
            SystemCase("sizes, frame gaps, outputs into inputs: one line", sizes_gaps_and_outputs, fast=True,
                       kind="inputs"),
            SystemCase("every PNG mode reads as its pixels", png_modes, fast=True, kind="inputs"),
            SystemCase("flags over damaged keys, scheduler addresses, --data, outputs into inputs, ids: one line",
                       flags_addresses_and_records, fast=True, kind="inputs"),
            SystemCase("odd names in paths: stdout one printable line each, EXR written and read",
                       odd_names_on_stdout, fast=True, kind="inputs"),
            SystemCase("denoise.train: damaged checkpoint, benchmark scene by path, output in --work: one line",
                       training_inputs, fast=True, kind="inputs"),
            SystemCase("denoise.validate: no judged frames, output in --work, a weight not a number: one line",
                       validation_inputs, fast=True, kind="inputs"),
            SystemCase("method files: a declaration argparse cannot take, a BaseException in filter(): one line",
                       broken_method_files, kind="inputs")]
