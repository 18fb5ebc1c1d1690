"""python -m denoise.score: a denoiser's per-frame results against a ground truth.

The figures are checked against ``python -m benchmarks.denoise`` on the same
exported sequence (run as its command), and the temporal figure against
NumPy on frames whose back projection is known."""
from __future__ import annotations

import dataclasses
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from denoise.score import main
from export.frames import FrameData, write_frame
from imaging.image_io import read_exr_rgb, write_exr
from imaging.metrics import relmse

ROOT = Path(__file__).resolve().parent.parent
#: the benchmark's figures and ours agree to this (they are the same computation)
AGREEMENT = 1e-6


def score(capsys, *arguments) -> tuple[int, str, str]:
    status = main([str(a) for a in arguments])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def test_matches_the_benchmark_on_an_exported_sequence(variant_vectorised_rgb, tmp_path, capsys):
    """Export a small sequence and score it with ``benchmarks.denoise --quick``; denoise it
    with ``python -m denoise --method svgf``; ``denoise.score`` on those results, and on
    ``--compare svgf oidn-high raw``, gives the benchmark's relMSE, FLIP, temporal relMSE and
    stability of those methods, frame by frame."""
    from denoise.__main__ import main as denoise_main

    work, benchmark = tmp_path / "work", tmp_path / "benchmark.json"
    finished = subprocess.run([sys.executable, "-m", "benchmarks.denoise", "--quick", "--no-timing", "--sequences",
                               "dolly_lamps", "--work", str(work), "--json", str(benchmark)],
                              cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert finished.returncode == 0, finished.stderr[-3000:]
    # its 4 frames have none >= 4, where the asvgf bar's mean is taken: said so, not NaN
    assert "nan" not in finished.stdout and "dolly_lamps: asvgf mean relMSE: no frames >= 4;" in finished.stdout
    frames = work / "dolly_lamps_96x54_16spp_quick"
    assert denoise_main([str(frames), str(tmp_path / "svgf_results"), "--method", "svgf"]) == 0
    ours = tmp_path / "score.json"
    status, out, err = score(capsys, tmp_path / "svgf_results", "--reference", f"{frames}_reference", "--frames",
                             frames, "--compare", "svgf", "oidn-high", "raw", "--json", ours,
                             "--plot", tmp_path / "p.png")
    assert status == 0 and err == "", err
    expected = json.loads(benchmark.read_text())
    rows = {(r["method"], r["frame"]): r for r in expected["results"]}
    stability = expected["sequences"][0]["stability"]
    methods = json.loads(ours.read_text())["methods"]
    assert [m["name"] for m in methods] == ["svgf_results", "svgf", "oidn-high", "raw"]
    for m in methods:
        method = "svgf" if m["name"] == "svgf_results" else m["name"]
        for key in ("relmse", "flip", "temporal"):
            benchmark_values = [rows[(method, k)][key] for k in range(4)]
            assert benchmark_values[0] is None or key != "temporal"
            assert m[key][0] is None or key != "temporal"
            got, want = np.array(m[key][key == "temporal":]), np.array(benchmark_values[key == "temporal":])
            assert np.abs(got - want).max() <= AGREEMENT, (m["name"], key, got, want)
        assert abs(m["stability"] - stability[method]) <= AGREEMENT * stability[method]
    assert "| svgf_results | 0.0" in out and (tmp_path / "p.png").stat().st_size > 10_000


# -- frames whose back projection is known ---------------------------------------------
H, W = 12, 16
#: a frame's per-pixel buffers
CROPPED = ("beauty", "normal", "position", "depth", "ids")


def plane_frames(count=3):
    """A static plane seen through the identity world-to-screen matrix: pixel (x, y) sees
    (x + 0.5, y + 0.5, 1) and keeps its own history, except where the previous frame
    saw the background (id -1: a corner of frame 0)."""
    ys, xs = np.mgrid[0:H, 0:W]
    position = np.stack([xs + 0.5, ys + 0.5, np.ones((H, W))], -1).astype(np.float32)
    frames = []
    for i in range(count):
        ids = np.zeros((H, W), np.int32)
        if i == 0:
            ids[:3, :5] = -1
        frames.append(FrameData(np.full((H, W, 3), 0.5, np.float32), np.tile(np.float32([0, 0, 1]), (H, W, 1)),
                                position, np.ones((H, W), np.float32), ids, [np.eye(4)], np.eye(4), np.eye(4)))
    return frames


@pytest.fixture
def sequence(tmp_path):
    """(frames folder, reference folder, results folder, results, truth) of 3 frames."""
    rng = np.random.default_rng(7)
    folders = [tmp_path / name for name in ("frames", "reference", "results")]
    results, truth = [], []
    for i, frame in enumerate(plane_frames()):
        write_frame(folders[0], i, frame)
        truth.append(rng.uniform(0.5, 1.5, (H, W, 3)).astype(np.float32))
        results.append((truth[-1] * rng.uniform(0.8, 1.2, (H, W, 3))).astype(np.float32))
        write_exr(folders[1] / f"beauty_{i}.exr", {"": truth[-1]})
        write_exr(folders[2] / f"result_{i}.exr", {"": results[-1]})
    return (*folders, results, truth)


def numpy_temporal(images):
    """relMSE between consecutive images where the back projection keeps history (the identity
    mapping, minus frame 0's background corner for frame 1)."""
    values = []
    for t in range(1, len(images)):
        keep = np.ones((H, W), bool)
        if t == 1:
            keep[:3, :5] = False
        values.append(relmse(images[t][keep], images[t - 1][keep]))
    return values


def test_temporal_figures_match_numpy(variant_vectorised_rgb, sequence, tmp_path, capsys):
    frames, reference, results, images, truth = sequence
    status, out, _ = score(capsys, results, "--reference", reference, "--frames", frames, "--json", tmp_path / "s.json")
    assert status == 0
    (ours,) = json.loads((tmp_path / "s.json").read_text())["methods"]
    expected = numpy_temporal(images)
    assert ours["temporal"][0] is None and np.allclose(ours["temporal"][1:], expected, rtol=1e-6)
    assert np.isclose(ours["stability"], np.mean(expected) / np.mean(numpy_temporal(truth)), rtol=1e-6)
    assert np.allclose(ours["relmse"], [relmse(a, b) for a, b in zip(images, truth)], rtol=1e-9)
    assert f"| results | 2 | {ours['relmse'][2]:.5f} |" in out


def test_one_frame_has_no_temporal_figure_and_says_why(variant_vectorised_rgb, sequence, tmp_path, capsys):
    """One frame given with --frames: no pair to compare, said as such (not "no --frames")."""
    frames, reference, results, _, _ = sequence
    for folder, name in ((frames, "*_[12].*"), (reference, "beauty_[12].exr"), (results, "result_[12].exr")):
        for path in folder.glob(name):
            path.unlink()
    status, out, _ = score(capsys, results, "--reference", reference, "--frames", frames)
    assert status == 0 and "n/a (one frame: no pair to compare)" in out and "no --frames" not in out, out


def test_without_frames_there_is_no_temporal_figure(sequence, tmp_path, capsys):
    _, reference, results, _, _ = sequence
    status, out, _ = score(capsys, results, "--reference", reference, "--json", tmp_path / "s.json")
    assert status == 0 and "| results | " in out and "n/a (no --frames)" in out
    (ours,) = json.loads((tmp_path / "s.json").read_text())["methods"]
    assert ours["temporal"] is None and ours["stability"] is None and len(ours["flip"]) == 3


def test_a_pattern_names_the_results(sequence, capsys):
    _, reference, results, images, truth = sequence
    for i in range(len(images)):
        (results / f"result_{i}.exr").rename(results / f"frame_{i:04d}.exr")
    status, out, _ = score(capsys, results, "--reference", reference, "--pattern", "frame_{i:04d}.exr")
    assert status == 0 and f"| results | 1 | {relmse(images[1], truth[1]):.5f} |" in out


@pytest.mark.parametrize("case, message", [
    ("no results", r"nowhere: not a folder"),
    ("no reference", r"--reference .*nowhere: not a folder"),
    ("empty reference", r"--reference .*frames: no beauty_<i>\.exr frames"),
    ("missing result", r"results/result_1\.exr: missing$"),
    ("smaller result", r"results/result_2\.exr: 8x12 pixels, but .*reference/beauty_2\.exr has 16x12"),
    ("smaller reference frame", r"reference/beauty_1\.exr: 8x12 pixels, but .*reference/beauty_0\.exr has 16x12"),
    ("smaller frame", r"frames/beauty_2\.exr: 8x12 pixels, but .*reference/beauty_2\.exr has 16x12"),
    ("damaged result", r"results/result_0\.exr: not a readable EXR \("),
    ("no channels", r"results/result_0\.exr: no R channel \(expected R, G, B\)"),
    ("pattern", r"--pattern 'result\.exr': a file name with exactly one \{i\}"),
    ("compare without frames", r"--compare runs our methods on the frames: give --frames FRAME_DIR"),
    ("unknown method", r"--compare: unknown method 'best'; known: bilateral, atrous, svgf, .*, or raw \("),
    ("method twice", r"--compare: svgf named twice"),
    ("NaN in a result", r"results/result_1\.exr: 2 pixels NaN and 0 infinite of 192 \("),
    ("inf in the truth", r"reference/beauty_2\.exr: 0 pixels NaN and 1 infinite of 192 \("),
    ("a gap in the frame numbers", r"--reference .*reference: frames 0\.\.2 without beauty_1\.exr; the temporal"),
    ("plot", r"--plot writes PNG: name it \.png, got .*p\.jpg"),
])
def test_bad_inputs_are_one_line_and_exit_2(sequence, tmp_path, capsys, case, message):
    frames, reference, results, images, _ = sequence
    arguments = [results, "--reference", reference]
    if case == "no results":
        arguments[0] = tmp_path / "nowhere"
    elif case == "no reference":
        arguments[2] = tmp_path / "nowhere"
    elif case == "empty reference":
        (tmp_path / "frames").mkdir(exist_ok=True)
        arguments[2] = tmp_path / "results" / ".." / "frames"
        for path in frames.glob("beauty_*.exr"):
            path.rename(path.with_name(path.name.replace("beauty", "moved")))
    elif case == "missing result":
        (results / "result_1.exr").unlink()
    elif case == "smaller result":
        write_exr(results / "result_2.exr", {"": images[2][:, :8]})
    elif case == "smaller reference frame":
        write_exr(reference / "beauty_1.exr", {"": images[1][:, :8]})
        write_exr(results / "result_1.exr", {"": images[1][:, :8]})
    elif case == "smaller frame":
        frame = plane_frames()[2]
        fields = {f.name: getattr(frame, f.name) for f in dataclasses.fields(FrameData)}
        write_frame(frames, 2, FrameData(**{k: v[:, :8] if k in CROPPED else v for k, v in fields.items()}))
        arguments += ["--frames", frames]
    elif case == "damaged result":
        path = results / "result_0.exr"
        path.write_bytes(path.read_bytes()[:300])
    elif case == "no channels":
        write_exr(results / "result_0.exr", {"depth": images[0][..., 0]})
    elif case == "pattern":
        arguments += ["--pattern", "result.exr"]
    elif case == "compare without frames":
        arguments += ["--compare", "svgf"]
    elif case == "unknown method":
        arguments += ["--frames", frames, "--compare", "best"]
    elif case == "method twice":
        arguments += ["--frames", frames, "--compare", "svgf", "raw", "svgf"]
    elif case == "NaN in a result":
        image = images[1].copy()
        image[0, :2, 1] = np.nan
        write_exr(results / "result_1.exr", {"": image})
    elif case == "inf in the truth":
        image = read_exr_rgb(reference / "beauty_2.exr")
        image[3, 4] = np.inf
        write_exr(reference / "beauty_2.exr", {"": image})
    elif case == "a gap in the frame numbers":  # frame 2 would be scored against frame 0 as its previous
        (reference / "beauty_1.exr").unlink()
        arguments += ["--frames", frames]
    elif case == "plot":
        arguments += ["--plot", tmp_path / "p.jpg"]
    status, out, err = score(capsys, *arguments)
    assert status == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith("python -m denoise.score: error: "), err
    assert re.search(message, err.strip()), err


@pytest.mark.parametrize("pattern", ["result_{i:q}.exr", "result_{i:s}.exr"])
def test_a_pattern_that_cannot_be_formatted_is_one_line(capsys, tmp_path, pattern):
    status, _, err = score(capsys, tmp_path, "--reference", tmp_path, "--pattern", pattern)
    assert status == 2 and err.count("\n") == 1 and f"--pattern {pattern!r}" in err, err


def test_json_must_be_named_json(capsys, tmp_path):
    """``--json`` onto a reference frame would have replaced the ground truth."""
    frame = tmp_path / "beauty_0.exr"
    frame.write_bytes(b"exr")
    status, _, err = score(capsys, tmp_path, "--reference", tmp_path, "--json", frame)
    assert status == 2 and "--json writes JSON: name it .json" in err and frame.read_bytes() == b"exr"


@pytest.mark.parametrize("pattern, message", [
    ("{i:>99999999999}.exr", "a width beyond what a file name holds (255 bytes)"),  # was 'out of memory'
    ("{i:=^300}.exr", "names frame 15 =====")])
def test_a_pattern_beyond_a_file_name_is_one_line(capsys, tmp_path, pattern, message):
    for i in (15, 25):
        write_exr(tmp_path / f"beauty_{i}.exr", {"": np.ones((2, 2, 3), np.float32)})
    status, _, err = score(capsys, tmp_path, "--reference", tmp_path, "--pattern", pattern)
    assert status == 2 and err.count("\n") == 1 and message in err, err


def test_two_frames_read_from_one_file_are_refused(capsys, tmp_path):
    """``{i:.0e}`` names frames 15 and 25 both ``2e+01.exr``: one result would be scored twice."""
    for i in (15, 25):
        write_exr(tmp_path / f"beauty_{i}.exr", {"": np.ones((2, 2, 3), np.float32)})
        write_exr(tmp_path / f"{i:.0e}.exr", {"": np.ones((2, 2, 3), np.float32)})
    status, _, err = score(capsys, tmp_path, "--reference", tmp_path, "--pattern", "{i:.0e}.exr")
    assert status == 2 and err.count("\n") == 1, err
    assert "frames 15 and 25 would both be read from 2e+01.exr" in err, err


def test_a_reference_that_is_not_a_ground_truth_is_refused(exported, tmp_path, capsys):
    """The noisy frames, any frame folder, or a truth with no more samples than the frames,
    given as --reference: one line, exit 2, in denoise.score and in python -m denoise."""
    import shutil

    from denoise.__main__ import main as denoise_main
    from export.ground_truth import GROUND_TRUTH_RECORD, SEQUENCE_RECORD, reference_folder

    truth = reference_folder(exported)
    record = json.loads((truth / GROUND_TRUTH_RECORD).read_text())
    assert (record["holds"], record["spp"], record["frames_spp"]) == ("ground truth", 2, 1)
    results = tmp_path / "results"
    results.mkdir()
    for i in (0, 1):
        shutil.copy(exported / f"beauty_{i}.exr", results / f"result_{i}.exr")
    assert score(capsys, results, "--reference", truth, "--frames", exported)[0] == 0
    status, out, err = score(capsys, results, "--reference", exported)
    assert (status, out) == (2, "")
    assert err == (f"python -m denoise.score: error: --reference {exported}: holds an export's noisy frames "
                   f"({SEQUENCE_RECORD}), not a ground truth; its ground truth is {truth}\n")
    course_layout = tmp_path / "frames_by_hand"  # the course's layout, no record
    shutil.copytree(exported, course_layout)
    (course_layout / SEQUENCE_RECORD).unlink()
    status, _, err = score(capsys, results, "--reference", course_layout)
    assert status == 2 and err.count("\n") == 1 and "holds frames with G-buffers" in err, err
    thin = tmp_path / "thin_reference"  # a truth of as many samples as the frames it would judge
    shutil.copytree(truth, thin)
    (thin / GROUND_TRUTH_RECORD).write_text(json.dumps(dict(record, spp=1)))
    for frames in ([], ["--frames", exported]):
        status, _, err = score(capsys, results, "--reference", thin, *frames)
        assert status == 2 and err.count("\n") == 1, err
        assert "a ground truth of 1 samples per pixel cannot judge" in err and "rendered at 1" in err, err
    assert denoise_main([str(exported), str(tmp_path / "out"), "--video", str(tmp_path / "v.mp4"),
                         "--reference", str(exported)]) == 2
    assert "holds an export's noisy frames" in capsys.readouterr().err
