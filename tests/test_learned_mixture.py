"""learned-mixture: the committed networks against a NumPy reference, its
images against asvgf's, the trainer's gradient, bad weights files, and the
training command's stops and resumption for this method."""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
WEIGHTS = {"learned-mixture": ROOT / "denoise" / "learned_mixture.json",
           "no-temporal-inputs": ROOT / "denoise" / "learned_mixture_no_temporal.json",
           "half-channels": ROOT / "denoise" / "learned_mixture_half_channels.json"}
#: a training sequence that exports in seconds (a scene no benchmark sequence uses)
TINY = {"scene": "showcase", "frames": 3, "size": [32, 18], "spp": 1, "reference_spp": 2, "bounces": 1,
        "camera": {"dolly": 0.5}}


def reference_blend(data: dict, x: np.ndarray, images: np.ndarray) -> np.ndarray:
    """The weights file's network written out in NumPy, float64: two 3×3
    convolutions with ReLU (the border pixel repeated), a 1×1 layer of
    logits, the softmax blend of ``images`` (image, y, x, rgb), then the blend
    filtered by the 3×3 kernel of a second 1×1 layer's softmax."""
    def conv(a, w, b):
        padded = np.pad(a, ((0, 0), (1, 1), (1, 1)), mode="edge")
        h, width = a.shape[1:]
        out = np.zeros((w.shape[0], h, width)) + b[:, None, None]
        for ky in range(3):
            for kx in range(3):
                out += np.einsum("oc,chw->ohw", w[:, :, ky, kx], padded[:, ky:ky + h, kx:kx + width])
        return np.maximum(out, 0.0)

    def softmax(w, b, hidden):
        logits = np.einsum("kc,chw->khw", w, hidden) + b[:, None, None]
        weights = np.exp(logits - logits.max(0))
        return weights / weights.sum(0)

    w = {k: np.array(data[k], np.float64) for k in ("w1", "b1", "w2", "b2", "w3", "b3", "w4", "b4")}
    hidden = conv(conv(x, w["w1"], w["b1"]), w["w2"], w["b2"])
    blend = np.einsum("khw,khwc->hwc", softmax(w["w3"], w["b3"], hidden), images)
    kernel = softmax(w["w4"], w["b4"], hidden)
    padded = np.pad(blend, ((1, 1), (1, 1), (0, 0)), mode="edge")
    h, width = blend.shape[:2]
    return sum(kernel[3 * ky + kx][..., None] * padded[ky:ky + h, kx:kx + width] for ky in range(3) for kx in range(3))


def random_inputs(features: int, height: int, width: int, seed: int = 7):
    rng = np.random.default_rng(seed)
    x = rng.uniform(-3.0, 3.0, (features, height, width)).astype(np.float32)
    images = rng.exponential(1.0, (14, height, width, 3)).astype(np.float32)
    return x, images


@pytest.mark.parametrize("reads", ["shifted planes", "gathers"])
@pytest.mark.parametrize("name", list(WEIGHTS))
def test_the_committed_network_matches_numpy(name, reads, variant_llvm_ad_rgb, monkeypatch):
    """Dr.Jit inference (two convolution kernels, weights as constants; the taps read
    as shifted planes on the CPU, as gathers elsewhere) equals the NumPy network
    within 1e-4 on inputs spread over and beyond their usual ranges."""
    import mitsuba as mi

    from denoise import neighbours
    from denoise.methods.learned_mixture import CANDIDATES, FEATURES, load_network, mixture

    monkeypatch.setattr(neighbours, "ENABLED", reads == "shifted planes")

    data = json.loads(WEIGHTS[name].read_text())
    network = load_network(WEIGHTS[name])
    assert network.features == tuple(data["features"]) and set(network.features) <= set(FEATURES)
    height, width = 23, 37
    x, images = random_inputs(len(FEATURES), height, width)
    inputs = {f: mi.Float(np.ascontiguousarray(x[i]).ravel()) for i, f in enumerate(FEATURES)}
    dr_images = [mi.Vector3f(*(mi.Float(np.ascontiguousarray(im[..., c]).ravel()) for c in range(3)))
                 for im in images]
    got = mixture(network, inputs, dr_images, width, height)
    got = np.stack([np.array(got[c]) for c in range(3)], axis=-1).reshape(height, width, 3)
    used = [FEATURES.index(f) for f in network.features]
    expected = reference_blend(data, x[used].astype(np.float64), images.astype(np.float64))
    assert np.max(np.abs(got - expected) / (1.0 + np.abs(expected))) < 1e-4
    asvgf = images[CANDIDATES.index("asvgf")]
    assert np.mean(np.abs(expected - asvgf)) > 1e-2  # a network that learned to blend, not asvgf's output alone


def test_the_committed_networks_are_what_the_benchmark_runs():
    from denoise.methods import benchmark_names, from_name

    for name in ("learned-mixture", "learned-mixture-no-temporal-inputs", "learned-mixture-half-channels"):
        assert name in benchmark_names()
    plain, half = from_name("learned-mixture"), from_name("learned-mixture-half-channels")
    assert half.network.channels * 2 == plain.network.channels
    ablation = from_name("learned-mixture-no-temporal-inputs")
    assert ablation.temporal and "gradient" not in ablation.network.features
    assert "noise" in ablation.network.features and "ratio_asvgf" in ablation.network.features


def test_its_images_are_asvgfs(exported, variant_llvm_ad_rgb):
    """Over an exported sequence, the method's 'asvgf' image is asvgf's output, its
    'slow' and 'wide_one' asvgf's own, frame after frame (the history it carries is asvgf's)."""
    from dataclasses import replace

    from denoise.methods.asvgf import asvgf, fitted
    from denoise.methods.learned_mixture import CANDIDATES, candidate_images
    from denoise.training import augmented, load_sequence

    frames = augmented(load_sequence(exported), None, 0, 0, False, False, 1.0)
    params = replace(fitted(), levels=frames[0].levels)
    ours = theirs = None
    for f in frames:
        images, inputs, ours = candidate_images(f.buffers, params, ours if f.index is not None else None, f.index,
                                                f.valid)
        expected = []
        result, theirs = asvgf(f.buffers, params, theirs if f.index is not None else None, f.index, f.valid,
                               images=expected)
        got = {name: np.array(f.buffers.tensor(image)) for name, image in zip(CANDIDATES, images)}
        np.testing.assert_allclose(got["asvgf"], np.array(result), rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(got["slow"], np.array(expected[0]), rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(got["wide_one"], np.array(expected[-1]), rtol=1e-5, atol=1e-6)
        assert all(np.isfinite(np.array(v)).all() for v in inputs.values())


@pytest.mark.parametrize("name", ["learned-mixture", "no-temporal-inputs"])
def test_the_method_runs_the_network_the_training_trains(name, exported, variant_llvm_ad_rgb):
    """Frame after frame of an exported sequence with albedo, the method (as the
    denoiser and the benchmark run it) gives what the trainer's forward pass gives
    on the inputs it stores for that folder, within 1e-4: what is trained is what
    runs, demodulation included (the kernel filters the blend times the albedo)."""
    from denoise.methods import from_name
    from denoise.mixture_training import compute_inputs, forward, selected
    from export.frames import frame_indices, read_frame

    method = from_name("learned-mixture", network=str(WEIGHTS[name]))
    data = selected(compute_inputs(exported), method.network.features)
    frames = [read_frame(exported, i) for i in frame_indices(exported)]
    albedo = np.stack([f.albedo for f in frames])
    assert np.ptp(albedo) > 0.1  # edges between surfaces of different albedo: where the spaces differ
    for f, frame in enumerate(frames):
        got = method.step(frame)
        expected = forward(method.network, data["x"][f].astype(np.float64), data["images"][f].astype(np.float64))[0]
        assert np.max(np.abs(got - expected) / (1.0 + np.abs(expected))) < 1e-4, f


def test_the_trainers_gradient_is_the_losss():
    """The NumPy chain rule of the training against central differences of its own forward pass."""
    from denoise.methods.learned_mixture import FEATURES, KERNEL_TAPS, network_of
    from denoise.mixture_training import backward, forward, initial

    x, images = random_inputs(len(FEATURES), 9, 11, seed=3)
    target = np.full((9, 11, 3), 0.7)
    theta = initial(FEATURES, 3, seed=1) + np.random.default_rng(2).normal(0, 0.1, initial(FEATURES, 3, 1).shape)

    def loss(t):
        out, kept = forward(network_of(t, FEATURES, 3), x.astype(np.float64), images.astype(np.float64))
        return float(np.sum((out - target) ** 2)), out, kept

    value, out, kept = loss(theta)
    net = network_of(theta, FEATURES, 3)
    gradient = backward(net, 2.0 * (out - target), kept)
    kernel = KERNEL_TAPS * 3 + KERNEL_TAPS  # the kernel layer (3 channels), the last in the vector: every one checked
    rng = np.random.default_rng(4)
    for k in [*rng.choice(theta.size - kernel, 25, replace=False), *range(theta.size - kernel, theta.size)]:
        step = np.zeros_like(theta)
        step[k] = 1e-3
        numeric = (loss(theta + step)[0] - loss(theta - step)[0]) / 2e-3
        assert numeric == pytest.approx(gradient[k], rel=2e-2, abs=2e-3), k


def damaged(tmp_path: Path, case: str) -> Path:
    """A copy of the committed weights file, damaged as ``case`` says."""
    path = tmp_path / "mixture.json"
    text = WEIGHTS["learned-mixture"].read_text()
    data = json.loads(text)
    if case == "truncated":
        path.write_text(text[:len(text) // 2])
        return path
    if case == "other shape":
        data["w2"] = data["w2"][:-1]
    elif case == "other channels":
        data["channels"] += 1
    elif case == "other features":
        data["features"] = data["features"][::-1]
    elif case == "other candidates":
        data["candidates"] = data["candidates"][:-1]
    elif case == "not finite":
        data["b3"][0] = 1e300
    elif case == "a string":
        data["w1"][0][0][0][0] = "0.5"
    elif case == "another method's":
        data["format"] = "learned-asvgf-mlp"
    path.write_text(json.dumps(data))
    return path


@pytest.mark.parametrize("case, words", [
    ("truncated", "not a weights file"), ("other shape", "w2 must have shape"),
    ("other channels", "w1 must have shape"), ("other features", "its features must be some of"),
    ("other candidates", "its candidates must be slow"),
    ("not finite", "b3 has a value that is not finite or beyond 1e+06"),
    ("a string", "w1[0][0][0][0] is \"0.5\", not a number"), ("another method's", "not a learned-mixture-cnn"),
])
def test_a_bad_weights_file_is_one_line_naming_it(case, words, tmp_path):
    from core.errors import UsageError
    from denoise.methods import make

    path = damaged(tmp_path, case)
    with pytest.raises(UsageError) as error:
        make("learned-mixture", network=str(path))
    message = str(error.value)
    assert "\n" not in message and message.startswith(f"{path}: ") and words in message, message
    assert message.endswith("make it with python -m denoise.train --method learned-mixture")


def test_a_bad_weights_file_stops_the_denoiser_with_exit_2(exported, tmp_path, capsys):
    from denoise.__main__ import main

    path = damaged(tmp_path, "truncated")
    assert main([str(exported), str(tmp_path / "out"), "--method", "learned-mixture", "--network", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(path) in err and "--method learned-mixture" in err
    assert main([str(exported), str(tmp_path / "out"), "--method", "learned-mixture"]) == 0


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """A tiny training sequence, exported once."""
    from export import Spec, export
    from renderer.variants import set_variant

    folder = tmp_path_factory.mktemp("tiny_mixture")
    spec = folder / "tiny_showcase.json"
    spec.write_text(json.dumps(TINY))
    set_variant("llvm_ad_rgb", jit=True)
    export(Spec.load(spec), folder / "work" / "tiny_showcase")
    return spec, folder / "work"


def test_a_training_writes_a_network_the_method_loads(tiny, tmp_path):
    """Two steps: the weights file loads, its record names the method, its inputs are
    kept in --work and reused (the second run reads them, the same training)."""
    from denoise.methods import make
    from denoise.train import main

    spec, work = tiny
    out = tmp_path / "mix.json"
    common = [str(spec), "--method", "learned-mixture", "--work", str(work), "--out", str(out), "--plot",
              str(tmp_path / "mix.png"), "--hidden", "4", "--quiet", "--local"]
    assert main([*common, "--steps", "2"]) == 0
    stored = work / "mixture-inputs" / "tiny_showcase.npz"
    assert stored.is_file()
    when = stored.stat().st_mtime_ns
    assert main([*common, "--steps", "3"]) == 0
    assert stored.stat().st_mtime_ns == when
    data = json.loads(out.read_text())
    assert data["record"]["method"] == "learned-mixture" and data["record"]["steps"] == 3
    assert make("learned-mixture", network=str(out)).network.channels == 4
    (work / "mix.checkpoint.npz").unlink()


def test_a_loss_that_is_not_finite_stops_the_step():
    """A step whose loss is not finite is one line (a UsageError), the weights as they were."""
    from core.errors import UsageError
    from denoise.methods.learned_mixture import FEATURES
    from denoise.mixture_training import initial, train_step
    from denoise.training_state import Adam, Settings

    x, images = random_inputs(len(FEATURES), 16, 16)
    data = {"x": np.stack([x, x]), "images": np.stack([images, images]), "target": np.ones((2, 16, 16, 3))}
    theta = initial(FEATURES, 4, seed=0)
    theta[-1] = np.nan
    adam = Adam(theta, 0.01)
    with pytest.raises(UsageError, match="the training loss is nan at step 0"):
        train_step(adam, Settings(FEATURES, 4, 0, 0.01, 1, "learned-mixture"), [data], 0)
    assert adam.t == 0 and np.isnan(adam.theta[-1])


def test_the_loss_is_relative_to_asvgf():
    """A network that gives asvgf's output all the weight, and its kernel's centre
    all of the kernel's, scores 1 (training and held out)."""
    from denoise.methods.learned_mixture import CANDIDATES, FEATURES, KERNEL_TAPS, flatten, network_of
    from denoise.mixture_training import held_out_loss, initial, train_step
    from denoise.training_state import Adam, Settings

    x, images = random_inputs(len(FEATURES), 16, 16)
    data = {"x": np.stack([x, x]), "images": np.stack([images, images]), "target": np.ones((2, 16, 16, 3))}
    network = network_of(initial(FEATURES, 4, seed=0), FEATURES, 4)
    network.b3[CANDIDATES.index("asvgf")] = 60.0
    network.b4[KERNEL_TAPS // 2] = 60.0
    theta = flatten(network).astype(np.float64)
    settings = Settings(FEATURES, 4, 0, 0.01, 1, "learned-mixture")
    assert held_out_loss(theta, settings, [data]) == pytest.approx(1.0, abs=1e-6)
    assert train_step(Adam(theta, 0.01), settings, [data], 0) == pytest.approx(1.0, abs=1e-6)


@pytest.mark.timed
def test_ctrl_c_keeps_the_checkpoint_and_a_rerun_resumes(tiny, tmp_path):
    """Ctrl-C during the steps: exit 130 within 2 s, the last step's checkpoint
    kept; the rerun trains the remaining steps only and writes the weights."""
    spec, work = tiny
    out, plot = tmp_path / "m.json", tmp_path / "m.png"
    command = [sys.executable, "-m", "denoise.train", str(spec), "--method", "learned-mixture", "--work", str(work),
               "--out", str(out), "--plot", str(plot), "--hidden", "4", "--steps", "100000"]
    process = subprocess.Popen(command, cwd=ROOT, stderr=subprocess.PIPE, text=True, env={**os.environ})
    line = process.stderr.readline()
    while line.startswith("loaded "):
        line = process.stderr.readline()
    assert line.startswith("step 1/100000: loss "), line
    process.send_signal(signal.SIGINT)
    start = time.monotonic()
    process.wait(timeout=10)
    assert time.monotonic() - start < 2.0 and process.returncode == 130
    assert (work / "m.checkpoint.npz").is_file() and not out.exists()
    steps = int(np.load(work / "m.checkpoint.npz")["t"])
    resumed = subprocess.run(command[:-1] + [str(steps + 1)], cwd=ROOT, capture_output=True, text=True)
    assert resumed.returncode == 0, resumed.stderr
    assert f"step {steps + 1}/{steps + 1}: " in resumed.stderr and "step 1/" not in resumed.stderr
    assert json.loads(out.read_text())["record"]["steps"] == steps + 1
    (work / "m.checkpoint.npz").unlink()


@pytest.mark.parametrize("damage", ["truncated", "garbage", "fewer frames", "a NaN", "a stop's partial write"])
def test_a_damaged_inputs_file_is_made_anew(tiny, tmp_path, damage):
    """A kept inputs file that is cut, foreign, of other shapes or not finite is computed
    again (the training runs as with none); a partial write a stop left is removed."""
    from denoise.train import main

    spec, work = tiny
    out = tmp_path / "d.json"
    common = [str(spec), "--method", "learned-mixture", "--work", str(work), "--out", str(out), "--plot",
              str(tmp_path / "d.png"), "--hidden", "2", "--steps", "1", "--quiet", "--local", "--restart"]
    assert main(common) == 0
    stored = work / "mixture-inputs" / "tiny_showcase.npz"
    good = dict(np.load(stored))
    partial = stored.parent / ".tiny_showcase.npz.0badc0de.npz"
    if damage == "truncated":
        stored.write_bytes(stored.read_bytes()[:stored.stat().st_size // 2])
    elif damage == "garbage":
        stored.write_bytes(b"\x00" * 1000)
    elif damage == "fewer frames":
        np.savez(stored, **{**good, "x": good["x"][:-1], "images": good["images"][:-1], "target": good["target"][:-1]})
    elif damage == "a NaN":
        good["target"][1, 0, 0, 0] = np.nan
        np.savez(stored, **good)
    else:
        stored.unlink()
        partial.write_bytes(b"PK\x03\x04 cut short")
    assert main(common) == 0
    again = np.load(stored)
    assert again["x"].shape == good["x"].shape and np.isfinite(again["target"]).all()
    assert not partial.exists()
    (work / "d.checkpoint.npz").unlink()


def test_a_folder_where_the_inputs_go_is_one_line(tiny, tmp_path, capsys):
    from denoise.train import main

    spec, work = tiny
    store = tmp_path / "work"
    shutil.copytree(work, store, ignore=shutil.ignore_patterns("*.checkpoint.npz", "mixture-inputs"))
    (store / "mixture-inputs" / "tiny_showcase.npz").mkdir(parents=True)
    assert main([str(spec), "--method", "learned-mixture", "--work", str(store), "--out", str(tmp_path / "f.json"),
                 "--plot", str(tmp_path / "f.png"), "--hidden", "2", "--steps", "1", "--local"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[-1].endswith("tiny_showcase.npz: not a file, where the training keeps tiny_showcase's inputs; "
                            "remove it"), err


def test_another_trainings_checkpoint_is_not_resumed(tiny, tmp_path, capsys):
    """Two --out files of one name in two folders share the checkpoint's name in --work: the
    second training is refused in one line naming the first's file, not resumed from its steps."""
    from denoise.train import main

    spec, work = tiny
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    common = [str(spec), "--method", "learned-mixture", "--work", str(work), "--hidden", "2", "--local", "--quiet"]
    assert main([*common, "--out", str(tmp_path / "a" / "x.json"), "--plot", str(tmp_path / "a.png"),
                 "--steps", "2"]) == 0
    capsys.readouterr()
    assert main([*common, "--out", str(tmp_path / "b" / "x.json"), "--plot", str(tmp_path / "b.png"),
                 "--steps", "3"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"the checkpoint of another training, into {tmp_path / 'a' / 'x.json'}" in err
    assert not (tmp_path / "b" / "x.json").exists()
    (work / "x.checkpoint.npz").unlink()


@pytest.mark.parametrize("method, other", [("learned-mixture", "learned_asvgf.json"),
                                           ("learned-asvgf", "learned_mixture_half_channels.json")])
def test_one_methods_network_never_replaces_the_others(method, other, tmp_path, capsys):
    from denoise.train import main

    target = ROOT / "denoise" / other
    before = target.read_bytes()
    assert main([str(tmp_path / "none.json"), "--method", method, "--out", str(target),
                 "--work", str(tmp_path / "w")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "committed weights file, not " + method in err
    assert target.read_bytes() == before and not (tmp_path / "w").exists()


@pytest.mark.parametrize("content, words", [
    ('{"format": "something-else"}', 'not a weights file of learned-asvgf ("format": "learned-asvgf-mlp") or '
                                     'learned-mixture ("learned-mixture-cnn")'),
    ('{"format": ["learned-mixture-cnn"]}', "not a weights file of learned-asvgf"),
    ('{"format": "learned-mixture-c', "not a weights file ("),
])
def test_validate_names_both_methods_for_a_file_of_neither(content, words, tmp_path):
    from core.errors import UsageError
    from denoise.validate import network_method

    path = tmp_path / "n.json"
    path.write_text(content)
    with pytest.raises(UsageError) as error:
        network_method(path)
    message = str(error.value)
    assert "\n" not in message and message.startswith(f"{path}: ") and words in message, message
    assert message.endswith("python -m denoise.train [--method learned-mixture]")
    path.write_text(WEIGHTS["learned-mixture"].read_text())
    assert network_method(path) == "learned-mixture"


def test_a_checkpoint_of_a_sequence_since_changed_is_not_resumed(tiny, tmp_path, capsys):
    """A spec of the same name that now says something else (another frame count) is
    another training: one line naming the sequence, before any rendering; --restart trains it."""
    from denoise.train import main

    spec, work = tiny
    out = tmp_path / "c.json"
    common = ["--method", "learned-mixture", "--work", str(work), "--out", str(out), "--plot", str(tmp_path / "c.png"),
              "--hidden", "2", "--local", "--quiet"]
    assert main([str(spec), *common, "--steps", "2"]) == 0
    changed = tmp_path / "other" / spec.name
    changed.parent.mkdir()
    changed.write_text(json.dumps({**TINY, "frames": 4}))
    capsys.readouterr()
    assert main([str(changed), *common, "--steps", "3"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "a checkpoint of other sequences (tiny_showcase: its spec changed since)" in err
    assert main([str(spec), *common, "--steps", "3"]) == 0  # the same spec again resumes
    assert json.loads(out.read_text())["record"]["steps"] == 3
    (work / "c.checkpoint.npz").unlink()
