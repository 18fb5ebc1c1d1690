"""learned-asvgf: the committed networks against a NumPy reference, the
training data kept apart from the benchmark, bad weights files and the
training command's refusals, stops and resumption."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
WEIGHTS = {"learned-asvgf": ROOT / "denoise" / "learned_asvgf.json",
           "no-temporal-inputs": ROOT / "denoise" / "learned_asvgf_no_temporal.json",
           "half-hidden": ROOT / "denoise" / "learned_asvgf_half_hidden.json"}
#: a training sequence that exports in seconds (a scene no benchmark sequence uses)
TINY = {"scene": "showcase", "frames": 3, "size": [32, 18], "spp": 1, "reference_spp": 2, "bounces": 1,
        "camera": {"dolly": 0.5}}


def reference_mlp(data: dict, x: np.ndarray) -> np.ndarray:
    """The weights file's perceptron written out in NumPy, float64: tanh hidden layer, linear outputs."""
    w1, b1, w2, b2 = (np.array(data[k], np.float64) for k in ("w1", "b1", "w2", "b2"))
    return np.tanh(x @ w1.T + b1) @ w2.T + b2


@pytest.mark.parametrize("name", list(WEIGHTS))
def test_the_committed_network_matches_numpy(name, variant_llvm_ad_rgb):
    """Dr.Jit inference (weights as constants) equals the NumPy network within
    1e-4 on features spread over and beyond their usual ranges."""
    import mitsuba as mi

    from denoise.methods.learned_asvgf import FEATURES, OUTPUTS, constant_network, load_network

    data = json.loads(WEIGHTS[name].read_text())
    network = load_network(WEIGHTS[name])
    assert network.features == tuple(data["features"]) and set(network.features) <= set(FEATURES)
    rng = np.random.default_rng(7)
    x = rng.uniform(-0.5, 3.0, (4096, len(FEATURES))).astype(np.float32)
    inputs = {f: mi.Float(np.ascontiguousarray(x[:, i])) for i, f in enumerate(FEATURES)}
    outputs = constant_network(network)(inputs)
    got = np.stack([np.array(o) for o in outputs], axis=1)
    used = [FEATURES.index(f) for f in network.features]
    expected = reference_mlp(data, x[:, used].astype(np.float64))
    assert got.shape == (4096, len(OUTPUTS))
    assert np.max(np.abs(got - expected)) < 1e-4
    assert np.max(np.abs(expected)) > 1e-2  # a network that learned something, not the zero start


def test_the_committed_networks_are_what_the_benchmark_runs():
    from denoise.methods import benchmark_names, from_name

    for name in ("learned-asvgf", "learned-asvgf-no-temporal-inputs", "learned-asvgf-half-hidden"):
        assert name in benchmark_names()
    plain, ablation = from_name("learned-asvgf-half-hidden"), from_name("learned-asvgf-no-temporal-inputs")
    assert plain.network.hidden * 2 == from_name("learned-asvgf").network.hidden
    assert ablation.temporal and "gradient" not in ablation.network.features


def test_no_benchmark_scene_or_sequence_is_trained_on(tmp_path):
    """The training specs, and the ones each committed network of either method records (its spec
    files and its procedural scenes, written again from the record), use no
    benchmark sequence and none of the benchmark's scenes."""
    from denoise.train import WEIGHTS_FILES, check_specs
    from denoise.training import BENCHMARK, HELD_OUT, TRAINING
    from export import Spec
    from scenes.procedural import write_sequences

    benchmark_scenes = {Spec.load(p).scene for p in BENCHMARK}
    benchmark_names = {p.stem for p in BENCHMARK}
    assert len(TRAINING) >= 12 and set(HELD_OUT) < {p.stem for p in TRAINING}
    assert check_specs(TRAINING)
    for path in TRAINING:
        assert Spec.load(path).scene not in benchmark_scenes and path.stem not in benchmark_names, path
    assert set(WEIGHTS.values()) < set(WEIGHTS_FILES)  # learned-mixture's too
    for weights in WEIGHTS_FILES:
        record = json.loads(weights.read_text())["record"]
        for spec in record["training"] + record["held_out"]:
            assert (ROOT / spec).resolve() in {p.resolve() for p in TRAINING}, spec
            assert Spec.load(ROOT / spec).scene not in benchmark_scenes
        assert not set(record["training"]) & set(record["held_out"])
        procedural = record["procedural"]
        generated = write_sequences(tmp_path / weights.stem, procedural["count"], procedural["seed"])
        assert len(check_specs(generated)) == procedural["count"] > 0
        for path in generated:
            assert Spec.load(path).scene not in benchmark_scenes
            assert path.stem not in benchmark_names and path.stem not in HELD_OUT


def damaged(tmp_path: Path, case: str) -> Path:
    """A copy of the committed weights file, damaged as ``case`` says."""
    path = tmp_path / "weights.json"
    text = WEIGHTS["learned-asvgf"].read_text()
    data = json.loads(text)
    if case == "missing":
        return tmp_path / "nowhere.json"
    if case == "truncated":
        path.write_text(text[:len(text) // 2])
    elif case == "corrupted":
        path.write_bytes(b"\x00\xff" + text.encode()[2:])
    elif case == "not an object":
        path.write_text("[1, 2, 3]\n")
    elif case == "other shape":
        data["w1"] = data["w1"][:-1]
        path.write_text(json.dumps(data))
    elif case == "other hidden":
        data["hidden"] += 1
        path.write_text(json.dumps(data))
    elif case == "other features":
        data["features"] = data["features"][::-1]
        path.write_text(json.dumps(data))
    elif case == "unknown feature":
        data["features"][0] = "depth"
        path.write_text(json.dumps(data))
    elif case == "other outputs":
        data["outputs"] = data["outputs"][:-1]
        path.write_text(json.dumps(data))
    elif case in ("a string", "true", "null"):
        data["w1"][0][0] = {"a string": "0.5", "true": True, "null": None}[case]
        path.write_text(json.dumps(data))
    elif case == "a folder":
        return tmp_path
    elif case == "a pipe":
        os.mkfifo(path)
    elif case == "a link to nothing":
        path.symlink_to(path)  # a loop
    elif case == "an empty path":
        return Path("")
    elif case == "not finite":
        path.write_text(text.replace(str(data["b2"][0]), "NaN", 1) if str(data["b2"][0]) in text else "x")
    return path


BAD = ("missing", "truncated", "corrupted", "not an object", "other shape", "other hidden", "other features",
       "unknown feature", "other outputs", "not finite", "a string", "true", "null", "a folder", "a pipe",
       "a link to nothing", "an empty path")
#: the reason each of these cases' line gives (where one is worth stating)
REASONS = {"a folder": "a folder, not a weights file", "a pipe": "not a regular file",
           "a link to nothing": "a symbolic link that leads to no file", "an empty path": "an empty path",
           "missing": "no such weights file"}


@pytest.mark.parametrize("case", BAD)
def test_a_bad_weights_file_is_one_line_naming_it(case, tmp_path):
    from core.errors import UsageError
    from denoise.methods import make

    path = damaged(tmp_path, case)
    given = "" if case == "an empty path" else str(path)
    with pytest.raises(UsageError) as error:
        make("learned-asvgf", network=given)
    message = str(error.value)
    assert "\n" not in message and message.startswith(f"{given or repr(given)}: ")
    assert "python -m denoise.train" in message
    if case in ("a string", "true", "null"):  # NumPy had read "0.5" and true as numbers
        assert "w1[0][0] is " in message and "not a number" in message, message
    if case in REASONS:  # a pipe, a loop and "" were each "no such weights file" or ".: a folder"
        assert REASONS[case] in message, message


def test_a_bad_weights_file_stops_the_denoiser_with_exit_2(exported, tmp_path, capsys):
    from denoise.__main__ import main

    path = damaged(tmp_path, "truncated")
    assert main([str(exported), str(tmp_path / "out"), "--method", "learned-asvgf", "--network", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(path) in err and "python -m denoise.train" in err
    assert main([str(exported), str(tmp_path / "out"), "--method", "learned-asvgf"]) == 0


def write_spec(folder: Path, name: str, **changes) -> Path:
    path = folder / f"{name}.json"
    path.write_text(json.dumps({**TINY, **changes}))
    return path


@pytest.mark.parametrize("case", ["benchmark sequence", "benchmark scene", "no ground truth", "all held out"])
def test_training_refuses_in_one_line(case, tmp_path, capsys):
    from denoise.train import main

    spec = {"benchmark sequence": lambda: ROOT / "scenes" / "sequences" / "light_switch.json",
            "benchmark scene": lambda: write_spec(tmp_path, "lamps_again", scene="lamps"),
            "no ground truth": lambda: write_spec(tmp_path, "no_truth", reference_spp=0),
            "all held out": lambda: write_spec(tmp_path, "mirrors_switch")}[case]()
    out = tmp_path / "w.json"
    assert main([str(spec), "--work", str(tmp_path / "work"), "--out", str(out), "--plot", str(tmp_path / "w.png"),
                 "--steps", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("python -m denoise.train: error: ")
    assert {"benchmark sequence": "a benchmark sequence", "benchmark scene": "scene 'lamps' is the benchmark's",
            "no ground truth": "no ground truth", "all held out": "is held out"}[case] in err
    assert not out.exists() and not (tmp_path / "work").exists()  # refused before any rendering


@pytest.mark.parametrize("flags, words", [
    (["--seed", "-1"], "--seed must be from 0 to 4294967295, got -1"),
    (["--seed", "4294967296"], "--seed must be from 0 to 4294967295"),
    (["--plot", "curves.jpg"], "--plot writes PNG: name it .png"),
])
def test_training_flags_out_of_range_are_one_line_before_any_work(tmp_path, capsys, flags, words):
    """A negative seed used to reach NumPy in the worker: its traceback, then 'stopped without a result'."""
    from denoise.train import main

    spec = write_spec(tmp_path, "tiny_showcase")
    argv = [str(spec), "--work", str(tmp_path / "work"), "--out", str(tmp_path / "w.json"), "--steps", "1"]
    assert main(argv + [str(tmp_path / f) if f.endswith(".jpg") else f for f in flags]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("python -m denoise.train: error: ") and words in err, err
    assert not (tmp_path / "work").exists()


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """A tiny training sequence, exported once."""
    from export import Spec, export
    from renderer.variants import set_variant

    folder = tmp_path_factory.mktemp("tiny")
    spec = write_spec(folder, "tiny_showcase")
    set_variant("llvm_ad_rgb", jit=True)
    export(Spec.load(spec), folder / "work" / "tiny_showcase")
    return spec, folder / "work"


def test_the_specs_order_does_not_change_the_training(tiny, tmp_path):
    """The same sequences in another order on the command line are the same training:
    a rerun resumes from the checkpoint instead of refusing it as another one's."""
    from denoise.train import main

    spec, work = tiny
    other = tmp_path / "tiny_again.json"
    other.write_text(spec.read_text())
    out = tmp_path / "order.json"
    common = ["--work", str(work), "--out", str(out), "--plot", str(tmp_path / "o.png"), "--hidden", "4", "--quiet",
              "--local"]
    assert main([str(spec), str(other), "--steps", "1", *common]) == 0
    assert main([str(other), str(spec), "--steps", "2", *common]) == 0
    assert json.loads(out.read_text())["record"]["steps"] == 2
    (work / "order.checkpoint.npz").unlink(missing_ok=True)


def test_a_checkpoint_with_nan_weights_is_refused_and_writes_nothing(tiny, tmp_path, capsys):
    """A NaN in a checkpoint's weights (which made the loss NaN after a step's
    work) is refused before the worker starts: one line, exit 2, the weights
    file as it was."""
    from denoise.train import main
    from denoise.training import initial
    from denoise.training_state import Adam, Settings, feature_set, save_checkpoint

    spec, work = tiny
    out = tmp_path / "w.json"
    out.write_text("before\n")
    settings = Settings(feature_set(True), 4, 0, 0.01, 1)
    theta = initial(settings.features, 4, 0)
    theta[-1] = np.nan
    save_checkpoint(work / "w.checkpoint.npz", settings, ["tiny_showcase"], Adam(theta, 0.01), [], 0.0)
    code = main([str(spec), "--work", str(work), "--out", str(out), "--plot", str(tmp_path / "w.png"),
                 "--hidden", "4", "--steps", "2", "--rate", "0.01"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "w.checkpoint.npz: theta holds values that are not finite" in err
    assert out.read_text() == "before\n" and not (tmp_path / "w.png").exists()
    (work / "w.checkpoint.npz").unlink()


def test_a_loss_that_is_not_finite_stops_the_step(variant_llvm_ad_rgb):
    """A step whose loss is not finite is one line (a UsageError), the weights as they were."""
    from core.errors import UsageError
    from denoise.methods.learned_asvgf import FEATURES
    from denoise.training import Adam, Settings, initial, train_step

    theta = initial(FEATURES, 4, seed=0)
    theta[-1] = np.nan
    adam = Adam(theta, 0.01)
    with pytest.raises(UsageError, match="the training loss is nan at step 0"):
        train_step(adam, Settings(FEATURES, 4, 0, 0.01, 1), [synthetic_frames(3, 8, 16)], 0)
    assert adam.t == 0 and np.isnan(adam.theta[-1])


@pytest.mark.timed
def test_ctrl_c_keeps_the_checkpoint_and_a_rerun_resumes(tiny, tmp_path):
    """Ctrl-C during a step: exit 130 within 2 s, the last step's checkpoint
    kept; the rerun trains the remaining steps only and writes the weights."""
    spec, work = tiny
    out, plot = tmp_path / "w.json", tmp_path / "w.png"
    command = [sys.executable, "-m", "denoise.train", str(spec), "--work", str(work), "--out", str(out),
               "--plot", str(plot), "--hidden", "4", "--steps", "1000"]
    process = subprocess.Popen(command, cwd=ROOT, stderr=subprocess.PIPE, text=True, env={**os.environ})
    first = process.stderr.readline()
    assert first == "loaded 1/1: tiny_showcase\n", first  # the sequences' loading, then the steps
    first = process.stderr.readline()
    assert first.startswith("step 1/1000: loss "), first
    process.send_signal(signal.SIGINT)
    start = time.monotonic()
    process.wait(timeout=10)
    assert time.monotonic() - start < 2.0 and process.returncode == 130
    assert (work / "w.checkpoint.npz").is_file() and not out.exists()
    steps = int(np.load(work / "w.checkpoint.npz")["t"])
    resumed = subprocess.run(command[:-1] + [str(steps + 1)], cwd=ROOT, capture_output=True, text=True)
    assert resumed.returncode == 0, resumed.stderr
    assert resumed.stderr.startswith(f"loaded 1/1: tiny_showcase\nstep {steps + 1}/{steps + 1}: ")
    data = json.loads(out.read_text())
    assert data["record"]["steps"] == steps + 1 and len(data["record"]["curve"]) == steps + 1
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    (work / "w.checkpoint.npz").unlink()


def test_quiet_training_prints_nothing(tiny, tmp_path):
    """--quiet: stderr empty on success (its step lines were printed all the same); without it the
    steps go to stderr and the final line to stdout."""
    spec, work = tiny
    out = tmp_path / "q.json"
    done = subprocess.run([sys.executable, "-m", "denoise.train", str(spec), "--work", str(work), "--out", str(out),
                           "--plot", str(tmp_path / "q.png"), "--hidden", "4", "--steps", "1", "--restart",
                           "--quiet"], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0 and done.stderr == "", done.stderr
    assert json.loads(out.read_text())["record"]["steps"] == 1
    # without it: the steps (progress) on stderr, the result's line on stdout, as every command's
    done = subprocess.run([sys.executable, "-m", "denoise.train", str(spec), "--work", str(work), "--out", str(out),
                           "--plot", str(tmp_path / "q.png"), "--hidden", "4", "--steps", "1", "--restart"],
                          cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0 and done.stderr.startswith("loaded 1/1: tiny_showcase\nstep 1/1: loss "), done.stderr
    assert done.stdout.startswith("final loss ") and f"weights written to {out}" in done.stdout, done.stdout
    (work / "q.checkpoint.npz").unlink(missing_ok=True)


def synthetic_frames(count: int, height: int, width: int) -> list:
    """Frames of smooth random colour on a plane facing the camera, each pixel's history the same pixel."""
    from denoise.training import Frame

    rng = np.random.default_rng(3)
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float32)
    position = np.stack([xs / width, ys / width, np.zeros_like(xs)], axis=-1)
    normal = np.broadcast_to(np.array([0, 0, 1], np.float32), position.shape).copy()
    frames = []
    for i in range(count):
        target = np.full((height, width, 3), 0.5, np.float32)
        color = (target * rng.exponential(1.0, target.shape)).astype(np.float32)
        previous = None if i == 0 else np.arange(height * width).reshape(height, width)
        frames.append(Frame(color, normal, position, None, target, previous))
    return frames


def test_a_crop_is_filtered_with_the_whole_frames_levels(variant_llvm_ad_rgb):
    """A 32-pixel crop of a 320-pixel frame gets the 320-pixel frame's À-Trous
    levels (3), as the method filters that frame; the crop's own width would give 1."""
    from denoise.svgf_common import levels_for
    from denoise.training import augmented

    frames = synthetic_frames(2, 6, 320)
    prepared = augmented(frames, (32, 6), 100, 0, True, False, 1.0)
    assert levels_for(320) == 3 and levels_for(32) == 1
    assert [p.levels for p in prepared] == [3, 3]


def test_the_loss_leaves_out_the_first_frame(variant_llvm_ad_rgb):
    """The first frame's target does not move the loss, a later frame's does."""
    from denoise.methods.learned_asvgf import FEATURES
    from denoise.training import LOSS_FROM, Recorder, augmented, initial, sequence_loss

    assert LOSS_FROM == 1
    theta = initial(FEATURES, 4, seed=0)

    def loss(change_frame=None):
        frames = synthetic_frames(3, 8, 16)
        if change_frame is not None:
            frames[change_frame].target[:] = 2.0
        prepared = augmented(frames, None, 0, 0, False, False, 1.0)
        return float(sequence_loss(prepared, Recorder(theta, FEATURES, 4, gradients=False))[0])

    assert loss(0) == loss()
    assert loss(1) > 1.5 * loss()


def test_the_loss_is_relative_to_asvgf(variant_llvm_ad_rgb):
    """The training and held-out losses are each sequence's loss over asvgf's: a network
    whose output layer is 0 (asvgf as fitted) scores 1 on both, whatever its first layer;
    moving the output layer moves them."""
    from denoise.methods.learned_asvgf import FEATURES
    from denoise.training import Adam, Settings, held_out_loss, initial, train_step

    settings = Settings(FEATURES, 4, 0, 0.01, 1)
    sequences = [synthetic_frames(3, 8, 16), synthetic_frames(3, 8, 24)]
    theta = initial(FEATURES, 4, seed=5)
    assert train_step(Adam(theta.copy(), 0.01), settings, sequences, 0) == pytest.approx(1.0, abs=1e-6)
    assert held_out_loss(theta, settings, sequences) == pytest.approx(1.0, abs=1e-6)
    theta[-3:] = 1.0  # the output biases: wider luminance σ, more of the wide level
    assert abs(held_out_loss(theta, settings, sequences) - 1.0) > 1e-3


def test_a_black_sequence_trains(variant_llvm_ad_rgb):
    """A crop that asvgf gets exactly right (black frames, black target) adds 0 to the
    loss: its denominator is floored, the step is not stopped as diverging."""
    from denoise.methods.learned_asvgf import FEATURES
    from denoise.training import Adam, Settings, initial, train_step

    black = synthetic_frames(3, 8, 16)
    for frame in black:
        frame.color[:] = 0.0
        frame.target[:] = 0.0
    adam = Adam(initial(FEATURES, 4, seed=0), 0.01)
    assert train_step(adam, Settings(FEATURES, 4, 0, 0.01, 1), [black], 0) == 0.0
    assert adam.t == 1
