"""The outside round's input classes: every JSON input read by one reader with
limits and one error shape; frame numbers far apart; every PNG mode read as its pixels."""
from __future__ import annotations

import json
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


#: ``python -m denoise`` with asvgf's parameter file at the path given first (not the checkout's file)
DENOISE_WITH_PARAMETER_FILE = """
import sys
from pathlib import Path
from core.launcher import start
start("python -m denoise", "denoise")
from denoise.methods import asvgf
asvgf.PARAMETER_FILE = Path(sys.argv.pop(1))
from denoise.__main__ import main
sys.exit(main(sys.argv[1:]))
"""


def test_a_damaged_parameter_file_leaves_other_methods_alone(tmp_path):
    """`--method svgf` does not read asvgf_params.json; `--method asvgf` says the file in one line."""
    params = tmp_path / "asvgf_params.json"
    params.write_bytes(b'{"parameters": {"slow_frames": 4, "slow_frames": 5}}')
    done = {method: subprocess.run([sys.executable, "-c", DENOISE_WITH_PARAMETER_FILE, str(params),
                                    str(tmp_path / "none"), str(tmp_path / "o"), "--method", method],
                                   cwd=ROOT, capture_output=True, text=True, timeout=120)
            for method in ("svgf", "asvgf")}
    # svgf is made and goes on to the folder; asvgf names the damaged file
    assert done["svgf"].stderr.strip().endswith("none: not a folder"), done["svgf"].stderr
    assert f"{params}: not a JSON parameter file (key \"slow_frames\" given twice" in done["asvgf"].stderr, \
        done["asvgf"].stderr
    assert {d.returncode for d in done.values()} == {2}
    with pytest.raises(UsageError, match="given twice"):
        load_parameter_file(params)


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


# A frame folder and a ground truth given together belong to one sequence (by the export's records)
def _another_sequence(exported: Path, where: Path) -> Path:
    """A copy of ``exported`` whose sequence.json records other settings (as SEQ2's would)."""
    import shutil

    shutil.copytree(exported, where)
    record = json.loads((where / "sequence.json").read_text())
    record["spec"]["seed"] += 1
    (where / "sequence.json").write_text(json.dumps(record))
    return where


@pytest.mark.parametrize("command", ["score --frames", "denoise --reference", "fit --evaluate"])
def test_a_ground_truth_of_another_sequence_is_refused(exported, tmp_path, capsys, command):
    import shutil

    from denoise.__main__ import main as denoise_main
    from denoise.fit import main as fit_main
    from denoise.score import main as score_main
    from export.ground_truth import reference_folder

    truth = reference_folder(exported)
    other = _another_sequence(exported, tmp_path / "other")
    results = tmp_path / "results"
    results.mkdir()
    for i in (0, 1):
        shutil.copy(exported / f"beauty_{i}.exr", results / f"result_{i}.exr")
    assert score_main([str(results), "--reference", str(truth), "--frames", str(exported)]) == 0
    capsys.readouterr()
    if command == "score --frames":
        status = score_main([str(results), "--reference", str(truth), "--frames", str(other)])
        flag = "--frames"
    elif command == "denoise --reference":
        status = denoise_main([str(other), str(tmp_path / "out"), "--method", "svgf", "--video",
                               str(tmp_path / "v.mp4"), "--reference", str(truth)])
        flag = "IN_DIR"
    else:
        shutil.copytree(truth, reference_folder(other))
        status = fit_main(["--evaluate", str(other), "--switch-frame", "1"])
        flag = "--evaluate"
    out, err = capsys.readouterr()
    assert status == 2 and err.count("\n") == 1, (out, err)
    assert "is the ground truth of the frames glossy_shadow" in err and f"not of {flag} {other}" in err, err
    assert not (tmp_path / "out").exists() and not (tmp_path / "v.mp4").exists()


BAD_SCHEDULERS = ["bogus", "127.0.0.1", "tcp://", "tcp://[::1", "inproc://x", "ucx://127.0.0.1:1", "",
                  "tcp://127.0.0.1:0", "localhost:65536", "999.1.1.1:8786", "tcp://[::g]:8786", "-a:1"]


@pytest.mark.parametrize("address", BAD_SCHEDULERS)
def test_a_bad_scheduler_address_is_one_line(tmp_path, capsys, address):
    from export.cli import main

    spec = tmp_path / "seq.json"
    spec.write_text('{"scene": "box", "frames": 1, "size": [4, 4], "reference_spp": 2}')
    status = main([str(spec), str(tmp_path / "out"), "--scheduler", address])
    err = capsys.readouterr().err
    assert status == 2 and err.count("\n") == 1 and "--scheduler" in err and "Traceback" not in err, err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("address", ["tcp://127.0.0.1:8786", "localhost:8786", "tcp://[::1]:8786",
                                     "scheduler.lab.example:1"])
def test_a_good_scheduler_address_passes(address):
    from export.cluster import check_scheduler

    assert check_scheduler(address) == address


def test_a_pipe_as_a_frame_file_is_one_line(exported, tmp_path):
    """A FIFO named beauty_1.exr: refused before any read (reading it blocked forever)."""
    import os
    import shutil

    copy = tmp_path / "fifo"
    shutil.copytree(exported, copy)
    (copy / "beauty_1.exr").unlink()
    os.mkfifo(copy / "beauty_1.exr")
    matrices = tmp_path / "fifo_matrix"
    shutil.copytree(exported, matrices)
    (matrices / "matrix_1.mat").unlink()
    os.mkfifo(matrices / "matrix_1.mat")
    results = tmp_path / "results"
    results.mkdir()
    shutil.copy(exported / "beauty_0.exr", results / "result_0.exr")
    os.mkfifo(results / "result_1.exr")
    commands = {"denoise": ["-m", "denoise", str(copy), str(tmp_path / "out"), "--method", "svgf"],
                "score": ["-m", "denoise.score", str(results), "--reference", f"{exported}_reference"],
                "matrix": ["-m", "denoise", str(matrices), str(tmp_path / "out2"), "--method", "svgf"]}
    for name, argv in commands.items():
        done = subprocess.run([sys.executable, *argv], cwd=ROOT, capture_output=True, text=True, timeout=120)
        bad = {"denoise": copy / "beauty_1.exr", "score": results / "result_1.exr",
               "matrix": matrices / "matrix_1.mat"}[name]
        assert done.returncode == 2 and done.stderr.count("\n") == 1, (name, done.stderr)
        assert f"{bad}: a pipe, not a regular file" in done.stderr, (name, done.stderr)


@pytest.mark.parametrize("value", [1e30, -1e30, 3e9, 7.0])
def test_an_id_out_of_range_is_one_line_without_a_warning(tmp_path, value):
    import warnings

    from export.frames import FrameData, read_frame, write_frame
    from imaging.image_io import write_exr

    rgb = np.ones((2, 3, 3), np.float32)
    write_frame(tmp_path, 0, FrameData(rgb, rgb, rgb, np.ones((2, 3), np.float32), np.zeros((2, 3), np.int32),
                                       [np.eye(4)], np.eye(4), np.eye(4)))
    ids = np.zeros((2, 3), np.float32)
    ids[1, 2] = value
    write_exr(tmp_path / "ID_0.exr", {"": ids})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(FrameError) as error:
            read_frame(tmp_path, 0)
    assert str(error.value).startswith(f"{tmp_path / 'ID_0.exr'}: object id ") and "\n" not in str(error.value)
    assert f"object id {np.float32(value):.15g}," in str(error.value)


# No output into an input: a spec's folder, the frames a fit trains on, a sequence's ground truth
@pytest.mark.parametrize("case", ["export OUT is the spec's folder", "export OUT's truth is the spec's folder",
                                  "fit --out in its frames", "fit --out in its truth",
                                  "denoise OUT is IN_DIR's truth", "denoise OUT holds an export's truth",
                                  "denoise OUT holds an export's frames"])
def test_no_output_goes_into_an_input(tmp_path, capsys, case):
    from denoise.__main__ import main as denoise
    from denoise.fit import main as fit
    from export.cli import main as export

    folder = tmp_path / "specs_reference" if "truth is" in case else tmp_path / "specs"
    folder.mkdir()
    spec = folder / "seq.json"
    spec.write_text('{"scene": "box", "frames": 2, "size": [4, 4], "reference_spp": 2}')
    seq, truth = tmp_path / "seq", tmp_path / "seq_reference"
    seq.mkdir()
    target = truth if "IN_DIR's truth" in case else tmp_path / "other"
    if case.startswith("denoise"):
        target.mkdir()
        if "holds" in case:
            (target / ("ground_truth.json" if "truth" in case else "sequence.json")).write_text("{}")
    before = sorted(tmp_path.rglob("*"))
    if case.startswith("export"):
        status = export([str(spec), str(tmp_path / "specs"), "--local"])
    elif case.startswith("fit"):
        inside = "seq" if "frames" in case else "seq_reference"
        status = fit([str(spec), "--steps", "1", "--work", str(tmp_path), "--out", str(tmp_path / inside / "p.json")])
    else:
        status = denoise([str(seq), str(target), "--method", "svgf"])
    err = capsys.readouterr().err
    assert status == 2 and err.count("\n") == 1 and "write outputs elsewhere" in err, err
    assert sorted(tmp_path.rglob("*")) == before


#: a damaged key, and the flag that replaces it: the spec as written is refused
HIDDEN = {"frames a string": ('"frames": "8"', dict(frames=2), "frames"),
          "frames -1": ('"frames": -1', dict(frames=2), "frames"),
          "frames 0": ('"frames": 0', dict(frames=2), "frames"),
          "frames true": ('"frames": true', dict(frames=2), "frames"),
          "frames 1e30": ('"frames": 1e30', dict(frames=2), "frames"),
          "size negative": ('"size": [-32, 18]', dict(size=(8, 6)), "size[0]"),
          "size of three": ('"size": [32, 18, 1]', dict(size=(8, 6)), "size"),
          "size 1e9": ('"size": [1000000000, 1000000000]', dict(size=(8, 6)), "size[0]"),
          "reference_spp 2**62": (f'"reference_spp": {2 ** 62}', dict(reference_spp=2), "reference_spp")}


@pytest.mark.parametrize("name", HIDDEN)
def test_a_flag_does_not_hide_a_damaged_key(tmp_path, name):
    text, flags, key = HIDDEN[name]
    path = tmp_path / "spec.json"
    path.write_text('{"scene": "box", ' + text + "}")
    with pytest.raises(SpecError) as error:
        Spec.load(path, **flags)
    assert str(error.value).startswith(f"{path}: {key}") and "\n" not in str(error.value), error.value


@pytest.mark.parametrize("flags, words", [(dict(reference_spp=1), "--reference-spp: expected 2..1048576, found 1"),
                                          (dict(reference_spp=3), "--reference-spp: expected an even number"),
                                          (dict(frames=0), "--frames: expected 1..100000, found 0"),
                                          (dict(size=(0, 6)), "--size W: expected 1..16384, found 0"),
                                          (dict(spp=0), "--spp: expected 1..1048576, found 0")])
def test_a_bad_flag_is_named_as_the_flag(tmp_path, flags, words):
    path = tmp_path / "spec.json"
    path.write_text('{"scene": "box"}')
    with pytest.raises(SpecError) as error:
        Spec.load(path, **flags)
    assert str(error.value).startswith(words) and "\n" not in str(error.value)


@pytest.mark.parametrize("scene", ["../../../../etc/passwd", "/etc/passwd", "a/b", "..", ""])
def test_a_spec_scene_is_a_name_or_a_txt_file(tmp_path, capsys, scene):
    from export.cli import main

    path = tmp_path / "spec.json"
    path.write_text(json.dumps({"scene": scene}))
    status = main([str(path), str(tmp_path / "out"), "--local"])
    err = capsys.readouterr().err
    assert status == 2 and err.count("\n") == 1, err
    assert f"{path}: scene: expected a scene name (box, scene06) or a .txt scene file" in err, err
    assert "root:" not in err and not (tmp_path / "out").exists()


def test_noisy_raw_input_is_refused_by_compare_raw(exported, tmp_path, capsys):
    """--compare raw on frames with NaN beauty: one line, as NaN results are, no NumPy warning."""
    import shutil

    from denoise.score import main
    from export.ground_truth import reference_folder
    from imaging.image_io import read_exr_rgb, write_exr

    frames, results = tmp_path / "nan_frames", tmp_path / "results"
    shutil.copytree(exported, frames)
    beauty = read_exr_rgb(frames / "beauty_1.exr")
    beauty[0, 0] = np.nan
    beauty[1, 1] = np.inf
    write_exr(frames / "beauty_1.exr", {"": beauty})
    results.mkdir()
    for i in (0, 1):
        shutil.copy(exported / f"beauty_{i}.exr", results / f"result_{i}.exr")
    status = main([str(results), "--reference", str(reference_folder(exported)), "--frames", str(frames),
                   "--compare", "raw"])
    out, err = capsys.readouterr()
    assert status == 2 and err.count("\n") == 1 and "Warning" not in err, err
    assert f"{frames / 'beauty_1.exr'}: 1 pixels NaN and 1 infinite of 576, which --compare raw scores" in err, err


def test_a_missing_data_folder_is_one_line(tmp_path, capsys):
    import socket

    from denoise.live.app import main as live
    from export.cli import main as export

    spec = tmp_path / "seq.json"
    spec.write_text('{"scene": "box", "frames": 1, "size": [4, 4], "reference_spp": 2}')
    (tmp_path / "file").write_text("")
    for data in (tmp_path / "missing", tmp_path / "file"):
        status = export([str(spec), str(tmp_path / "out"), "--local", "--data", str(data)])
        err = capsys.readouterr().err
        assert status == 2 and err.count("\n") == 1 and f"--data {data}: " in err, err
        assert not (tmp_path / "out").exists()
        with socket.socket() as busy:  # were --data passed over, the port would be the error
            busy.bind(("127.0.0.1", 0))
            busy.listen()
            status = live(["box", "--port", str(busy.getsockname()[1]), "--data", str(data)])
        err = capsys.readouterr().err
        assert status == 2 and err.count("\n") == 1 and f"--data {data}: " in err, err
        done = subprocess.run([sys.executable, "render.py", "lamps", "-size", "4", "4", "--out", str(tmp_path / "r"),
                               "--data", str(data)], cwd=ROOT, capture_output=True, text=True, timeout=120)
        lines = [line for line in done.stderr.splitlines() if "using scalar_rgb instead" not in line]
        assert done.returncode == 2 and len(lines) == 1 and f"--data {data}: " in lines[0], done.stderr
        assert not (tmp_path / "r").exists()


def error_cases():
    from core.errors import NEED_COURSE, LimitError, SceneError
    from export.store import FolderInUseError

    return {"usage": UsageError("no scene 'x' in scenes", "set --data to it", NEED_COURSE),
            "folder in use": FolderInUseError("out/seq: made with other settings"),
            "scene": SceneError("a.txt", 3, 7, "expected a number"),
            "plain": LimitError("too large")}


@pytest.mark.parametrize("name", ["usage", "folder in use", "scene", "plain"])
def test_an_error_keeps_its_parts_through_pickle_and_a_new_remedy(name):
    """Errors cross processes (Dask sends a worker's back) with problem, remedy and
    need kept, whatever the subclass's __init__ takes (SceneError's failed to
    unpickle); with_remedy swaps the remedy alone."""
    import pickle

    error = error_cases()[name]
    copy = pickle.loads(pickle.dumps(error))
    assert type(copy) is type(error) and str(copy) == str(error) and vars(copy) == vars(error)
    swapped = error.with_remedy("do this instead")
    assert type(swapped) is type(error) and swapped.need == error.need and swapped.problem == error.problem
    assert str(swapped) == f"{error.problem}; do this instead"
    if error.remedy:
        assert str(error) == f"{error.problem}; {error.remedy}"


@pytest.mark.parametrize("module, argv", [
    ("denoise.validate", ["--work", "{tmp}/work", "--json", "denoise/learned_asvgf.json"]),
    ("denoise.score", ["{tmp}/results", "--reference", "{tmp}/truth", "--json", "denoise/asvgf_params.json"]),
    ("denoise.fit", ["--work", "{tmp}/work", "--out", "denoise/learned_asvgf_half_hidden.json"]),
    ("denoise.train", ["--work", "{tmp}/work", "--out", "denoise/asvgf_params.json"]),
    ("benchmarks.crossval", ["--json", "denoise/learned_asvgf_no_temporal.json"]),
], ids=["validate --json", "score --json", "fit --out", "train --out", "a benchmark's --json"])
def test_no_output_lands_on_a_file_a_method_reads(tmp_path, capsys, monkeypatch, module, argv):
    """--json onto denoise/learned_asvgf.json replaced the weights with scores,
    and every later learned-asvgf run failed: each output onto a method's
    data file (DenoisingMethod.data_files) is one line, the file untouched."""
    import importlib

    monkeypatch.chdir(ROOT)
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    target = ROOT / argv[-1]
    before = target.read_bytes()
    main = importlib.import_module(module).main
    if module.startswith("benchmarks."):  # a benchmark's main runs under core.entry.run from its __main__
        from core.entry import run

        assert run(f"python -m {module}", lambda: main(argv)) == 2
    else:
        assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"is the input file {target.name} that " in err, err
    assert target.read_bytes() == before


@pytest.mark.parametrize("module, argv, name", [
    ("export", ["scenes/sequences/dolly_lamps.json", "", "--local"], "SPEC.json... OUT"),
    ("denoise.__main__", ["{tmp}", ""], "OUT_DIR"),
    ("denoise.train", ["--work", ""], "--work"),
    ("denoise.validate", ["--json", ""], "--json"),
    ("denoise.score", ["{tmp}", "--reference", ""], "--reference"),
], ids=["export OUT", "denoise OUT_DIR", "train --work", "validate --json", "score --reference"])
def test_an_empty_path_is_refused_not_the_current_folder(tmp_path, capsys, monkeypatch, module, argv, name):
    """Path("") is the current folder: export, denoise and train wrote into the
    repository's root (an unset shell variable as OUT). Every path argument refuses it."""
    import importlib

    monkeypatch.chdir(tmp_path)
    before = sorted(tmp_path.iterdir())
    main = importlib.import_module(module).main
    assert main([a.replace("{tmp}", str(tmp_path)) for a in argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"error: {name}: an empty path, not a name (an unset shell variable?)\n" in err, err
    assert sorted(tmp_path.iterdir()) == before


@pytest.mark.parametrize("target, expected", [(".", "{cwd}_reference"), ("a/b/..", "{cwd}/a_reference"),
                                              ("seq", "seq_reference"), ("x/seq/", "x/seq_reference")])
def test_the_ground_truth_is_named_after_the_folder_a_target_means(tmp_path, monkeypatch, target, expected):
    """'.' put the ground truth in ./_reference, inside the frames; 'a/b/..' in a/b/.._reference."""
    from export.ground_truth import reference_folder

    monkeypatch.chdir(tmp_path)
    assert reference_folder(Path(target)) == Path(expected.replace("{cwd}", str(tmp_path)))


def test_out_of_memory_names_no_flag_a_command_may_lack(capsys):
    """A MemoryError said 'try a smaller size or fewer samples' in python -m denoise, which has neither."""
    from core.entry import run

    def body():
        raise MemoryError

    assert run("python -m denoise", body) == 2
    assert capsys.readouterr().err == "python -m denoise: error: out of memory: this work needs more than the memory " \
                                      "available\n"


# No output inside an export's frames or ground truth, nor onto a dataset's record, whichever
# command writes it and whether or not that export is among the command's inputs
EXPORT_PLACES = {"in the frames": "seq/{name}", "in the ground truth": "seq_reference/sub/{name}",
                 "onto a dataset's record": "set/dataset.json"}


def export_records(root: Path) -> None:
    for folder, record in (("seq", "sequence.json"), ("seq_reference", "ground_truth.json"), ("set", "dataset.json")):
        (root / folder).mkdir()
        (root / folder / record).write_text("{}")


#: (command, its output flag, the output's name): every command that writes where a user says
WRITERS = [("denoise.score", "--json", "s.json"), ("denoise.score", "--plot", "p.png"), ("denoise", "OUT_DIR", "den"),
           ("denoise.fit", "--out", "p.json"), ("denoise.train", "--out", "w.json"),
           ("denoise.validate", "--json", "v.json")]


# the record is JSON: a PNG or a folder output is refused for its name before it could land there
@pytest.mark.parametrize("command, flag, name, place",
                         [(*writer, place) for writer in WRITERS for place in EXPORT_PLACES
                          if writer[2].endswith(".json") or place != "onto a dataset's record"])
def test_no_command_writes_into_an_export(tmp_path, capsys, command, flag, name, place):
    import importlib

    from test_export import TINY

    inputs = tmp_path / "inputs"
    inputs.mkdir()
    export_records(tmp_path)
    output = tmp_path / EXPORT_PLACES[place].format(name=name)
    spec = inputs / "tiny.json"
    spec.write_text(json.dumps(dict(TINY, scene="showcase", frames=5)))  # a scene no benchmark uses
    argv = {"denoise.score": [str(inputs), "--reference", str(inputs), flag, str(output)],
            "denoise": [str(inputs), str(output)],
            "denoise.fit": [str(spec), "--work", str(inputs / "work"), flag, str(output)],
            "denoise.train": [str(spec), "--work", str(inputs / "work"), flag, str(output)],
            "denoise.validate": [str(spec), "--work", str(inputs / "work"), flag, str(output)]}[command]
    before = sorted((p, p.stat().st_mtime_ns) for p in tmp_path.rglob("*"))
    main = importlib.import_module("denoise.__main__" if command == "denoise" else command).main
    status = main(argv)
    err = capsys.readouterr().err
    assert status == 2 and err.count("\n") == 1, err
    assert f"{flag} {output}" in err and "an export's" in err and "write outputs elsewhere" in err, err
    assert sorted((p, p.stat().st_mtime_ns) for p in tmp_path.rglob("*")) == before
