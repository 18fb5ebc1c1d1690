"""The outside round's input classes: every JSON input read by one reader with
limits and one error shape; frame numbers far apart; every PNG mode read as its pixels."""
from __future__ import annotations

import re
import struct
import subprocess
import sys
import time
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from core.errors import FrameError, SpecError, UsageError
from denoise.methods.asvgf import load_parameter_file
from denoise.pipeline import check_folder
from denoise.score import check_consecutive
from export.frames import frame_indices
from export.spec import Spec
from imaging.image_io import read_png
from validation.stress.cases_inputs_denoiser import denoiser_input_cases

ROOT = Path(__file__).resolve().parents[1]
GOOD = '{"scene": "box", "frames": 4, "lights": {"0": {"scale": 2}}}'

#: name -> (the file's bytes, what the one-line error says)
DAMAGED = {
    "utf-16": (GOOD.encode("utf-16"), "UTF-16"),
    "latin-1": (GOOD.replace("box", "b\u00f6x").encode("latin-1"), "not UTF-8"),
    "5000 digits": (GOOD.replace('"frames": 4', '"frames": ' + "9" * 5000).encode(), "5000 digits"),
    "deep": (GOOD.replace('"frames": 4', '"frames": ' + "[" * 100000 + "]" * 100000).encode(), "nested"),
    "key twice": (GOOD.replace('"0": {"scale": 2}', '"0": {"scale": 2}, "0": {"scale": 3}').encode(),
                  'key "0" given twice'),
    "too large for a float": (GOOD.replace("2}", "1e999}").encode(), "too large for a float"),
    "NaN": (GOOD.replace("2}", "NaN}").encode(), "NaN"),
    "megabytes": (GOOD.replace("box", "x" * (2 << 20)).encode(), "larger than"),
    "lone surrogate": (GOOD.replace("box", "\\ud800").encode(), "surrogate"),
}


@pytest.mark.parametrize("name", DAMAGED)
def test_a_damaged_spec_is_one_spec_error_naming_the_file(tmp_path, name):
    data, words = DAMAGED[name]
    path = tmp_path / "spec.json"
    path.write_bytes(data)
    with pytest.raises(SpecError) as error:
        Spec.load(path)
    assert str(error.value).startswith(f"{path}: ") and words in str(error.value)
    assert "\n" not in str(error.value)


@pytest.mark.parametrize("name", DAMAGED)
def test_a_damaged_parameter_file_is_one_usage_error(tmp_path, name):
    data, words = DAMAGED[name]
    text = data.replace(b'"scene": "box", ', b'"parameters": {"slow_frames": 4}, "scene": "box", ') \
        if name not in ("utf-16",) else '{"parameters": {"slow_frames": 4}}'.encode("utf-16")
    path = tmp_path / "asvgf_params.json"
    path.write_bytes(text)
    with pytest.raises(UsageError) as error:
        load_parameter_file(path)
    assert str(error.value).startswith(f"{path}: ") and "\n" not in str(error.value)


WRONG_TYPES = {
    "size of strings": ('{"scene": "box", "size": ["a", "b"]}', "size[0]"),
    "light frames of a string": ('{"scene": "box", "lights": {"0": {"scale": 1, "frames": "ab"}}}',
                                 "lights.0.frames"),
    "objects a list": ('{"scene": "box", "objects": [1]}', "objects"),
    "scale a string": ('{"scene": "box", "lights": {"0": {"scale": "2"}}}', "lights.0.scale"),
}


@pytest.mark.parametrize("name", WRONG_TYPES)
def test_a_value_of_the_wrong_type_names_its_key(tmp_path, name):
    text, key = WRONG_TYPES[name]
    path = tmp_path / "spec.json"
    path.write_text(text)
    with pytest.raises(SpecError, match=re.escape(f"{path}: {key}")):
        Spec.load(path)


def test_a_damaged_parameter_file_leaves_other_methods_alone(tmp_path):
    """`--method svgf` does not read asvgf_params.json; `--method asvgf` says the file in one line."""
    params = ROOT / "denoise" / "asvgf_params.json"
    saved = params.read_bytes()
    try:
        params.write_bytes(b'{"parameters": {"slow_frames": 4, "slow_frames": 5}}')
        done = {method: subprocess.run([sys.executable, "-m", "denoise", str(tmp_path / "none"), str(tmp_path / "o"),
                                        "--method", method], cwd=ROOT, capture_output=True, text=True, timeout=120)
                for method in ("svgf", "asvgf")}
        # svgf is made and goes on to the folder; asvgf names the damaged file
        assert done["svgf"].stderr.strip().endswith("none: not a folder"), done["svgf"].stderr
        assert f"{params}: not a JSON parameter file (key \"slow_frames\" given twice" in done["asvgf"].stderr, \
            done["asvgf"].stderr
        assert {d.returncode for d in done.values()} == {2}
        with pytest.raises(UsageError, match="given twice"):
            load_parameter_file()
    finally:
        params.write_bytes(saved)


FAR_APART = (0, 10 ** 12)


def test_frame_numbers_far_apart_are_read_sparse(tmp_path):
    """beauty_0 and beauty_10^12: one line naming the first missing file, at once (no list of the gap)."""
    for index in FAR_APART:
        (tmp_path / f"beauty_{index}.exr").write_bytes(b"")
    start = time.perf_counter()
    with pytest.raises(FrameError, match=re.escape(f"without {tmp_path / 'beauty_1.exr'} (and {10 ** 12 - 2} more")):
        check_folder(tmp_path)
    with pytest.raises(FrameError, match=re.escape("without beauty_1.exr (and")):
        check_consecutive(tmp_path, frame_indices(tmp_path))
    assert time.perf_counter() - start < 1.0


def test_a_frame_number_too_long_for_an_integer_is_one_line(tmp_path):
    (tmp_path / f"beauty_{'1' * 200}.exr").write_bytes(b"")
    with pytest.raises(FrameError, match="a frame number of 200 digits"):
        frame_indices(tmp_path)


# Every PNG mode and bit depth Pillow reads is read as its pixels (read_png, which the course scorer uses)
RNG = np.random.default_rng(3)
RGB = RNG.integers(0, 256, (6, 9, 3), dtype=np.uint8)
GREY = RGB[..., 1]


def png16_rgb(path, rgb8: np.ndarray) -> None:
    """A 16-bit-per-channel RGB PNG (Pillow writes none), each value v as v * 257."""
    height, width, _ = rgb8.shape
    rows = (rgb8.astype(">u2") * 257).reshape(height, width * 3)
    raw = b"".join(b"\0" + row.tobytes() for row in rows)

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", width, height, 16, 2, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw))
                     + chunk(b"IEND", b""))


#: mode -> (how it is written, the RGB it must read as)
MODES = {
    "RGB": (lambda p: Image.fromarray(RGB).save(p), RGB),
    "RGBA": (lambda p: Image.fromarray(np.dstack([RGB, np.full(GREY.shape, 255, np.uint8)])).save(p), RGB),
    "P": (lambda p: Image.fromarray(RGB).quantize(256, method=Image.Quantize.MAXCOVERAGE).save(p), None),
    "L": (lambda p: Image.fromarray(GREY).save(p), np.dstack([GREY] * 3)),
    "LA": (lambda p: Image.fromarray(np.dstack([GREY, np.full(GREY.shape, 255, np.uint8)]), "LA").save(p),
           np.dstack([GREY] * 3)),
    "I;16": (lambda p: Image.fromarray(GREY.astype(np.uint16) * 257).save(p), np.dstack([GREY] * 3)),
    "1": (lambda p: Image.fromarray(GREY > 127).save(p), np.dstack([np.where(GREY > 127, 255, 0)] * 3)),
    "16-bit RGB": (lambda p: png16_rgb(p, RGB), RGB),
}


@pytest.mark.parametrize("mode", MODES)
def test_every_png_mode_reads_as_its_pixels(tmp_path, mode):
    write, expected = MODES[mode]
    path = tmp_path / f"{mode.replace(';', '_').replace(' ', '_')}.png"
    write(path)
    image = read_png(path)
    assert image.shape == RGB.shape and image.dtype == np.uint8
    if expected is None:  # a palette: its colours are the image's up to quantisation
        with Image.open(path) as palette:
            expected = np.asarray(palette.convert("RGB"))
        assert np.abs(expected.astype(int) - RGB).mean() < 16
    assert np.abs(image.astype(int) - expected).max() <= 1


# No output path inside an input folder: one line naming both, exit 2, before any work
@pytest.mark.parametrize("flag, inside", [("--plot", "reference"), ("--json", "results"), ("--plot", "frames"),
                                          ("--json", "reference/sub")])
def test_a_score_never_writes_into_its_inputs(tmp_path, capsys, flag, inside):
    from denoise.score import main

    for name in ("results", "reference", "frames"):
        (tmp_path / name).mkdir()
    output = tmp_path / inside / ("p.png" if flag == "--plot" else "s.json")
    before = sorted(tmp_path.rglob("*"))
    status = main([str(tmp_path / "results"), "--reference", str(tmp_path / "reference"),
                   "--frames", str(tmp_path / "frames"), flag, str(output)])
    err = capsys.readouterr().err
    assert status == 2 and err.count("\n") == 1, err
    assert f"{flag} {output} is inside the input folder" in err and str(tmp_path / inside.split("/")[0]) in err
    assert sorted(tmp_path.rglob("*")) == before


@pytest.mark.parametrize("case", ["results into the frames", "results inside the frames", "video in the reference"])
def test_denoise_never_writes_into_its_inputs(tmp_path, capsys, case):
    from denoise.__main__ import main

    source, reference = tmp_path / "frames", tmp_path / "reference"
    source.mkdir()
    reference.mkdir()
    target = {"results into the frames": source, "results inside the frames": source / "out"}.get(case, tmp_path / "o")
    extra = ["--video", str(reference / "v.mp4"), "--reference", str(reference)] if case.startswith("video") else []
    status = main([str(source), str(target), "--method", "svgf", *extra])
    err = capsys.readouterr().err
    words = "is the input IN_DIR" if case == "results into the frames" else "is inside the input folder"
    assert status == 2 and err.count("\n") == 1 and words in err, err
    assert not (source / "out").exists() and not (reference / "v.mp4").exists()


@pytest.mark.parametrize("case", denoiser_input_cases(), ids=lambda case: case.name)
def test_the_stress_cases_of_these_classes_pass(variant_vectorised_rgb, case):
    passed, detail = case.check()
    assert passed, detail


@pytest.mark.parametrize("command", ["export", "fit"])
def test_export_and_fit_never_write_onto_their_inputs(tmp_path, capsys, command):
    from denoise.fit import main as fit
    from export.cli import main as export

    spec, data = tmp_path / "seq.json", tmp_path / "data"
    spec.write_text('{"scene": "lamps", "frames": 2}')
    data.mkdir()
    if command == "export":
        cases = {"OUT is the spec": [spec, spec, "--local"], "OUT inside --data": [spec, data / "o", "--data", data]}
        main, words = export, {"OUT is the spec": "OUT", "OUT inside --data": "OUT"}
    else:
        cases = {"--out is the spec": [spec, "--out", spec], "--work is the spec": [spec, "--work", spec]}
        main, words = fit, {name: name.split()[0] for name in cases}
    for name, argv in cases.items():
        status = main([str(a) for a in argv])
        err = capsys.readouterr().err
        assert status == 2 and err.count("\n") == 1 and f"{words[name]} " in err and "the input" in err, (name, err)
    assert spec.read_text() == '{"scene": "lamps", "frames": 2}' and list(data.iterdir()) == []
