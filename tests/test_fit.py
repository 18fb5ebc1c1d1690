"""denoise.fit: dr.grad of the sequence loss against central finite differences, and the command's contract."""
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
from test_asvgf import H, W, synthetic
from test_denoise import tensors

ROOT = Path(__file__).resolve().parent.parent
#: a sequence that exports in seconds
TINY = {"scene": "lamps", "frames": 3, "size": [32, 18], "spp": 1, "reference_spp": 8, "bounces": 1,
        "camera": {"dolly": 0.5}}
#: the parameters checked, each where its gradient is not 0 on these frames (fast_frames below the
#: history length of frame 2, so its cap is active; the anti-lag's λ = gain·δ inside (0, 1), away
#: from its clip's kinks, which a finite difference straddles; wide_frames above the longest history,
#: so the wide levels are blended in everywhere). AD and differences agree within 0.2 %.
BASE = {"sigma_luminance": 4.0, "sigma_plane": 0.3, "fast_frames": 1.5, "clip_width": 0.8, "fast_clip": 1.5,
        "antilag_gain": 0.8, "antilag_threshold": 0.0, "wide_frames": 4.0}


def sequence():
    """Three frames of a static view, the light dimmed to 20 % from frame 2 on."""
    import mitsuba as mi

    from denoise.filters import FrameArrays
    from denoise.fit import PreparedFrame

    frames = []
    for t in range(3):
        scale = 0.2 if t >= 2 else 1.0
        c, n, x = synthetic(20 + t, brightness=scale)
        truth, _, _ = synthetic(99, brightness=scale)
        index = mi.UInt32(np.arange(H * W, dtype=np.uint32)) if t else None
        valid = mi.Bool(np.random.default_rng(t).random(H * W) > 0.1) if t else None
        frames.append(PreparedFrame(FrameArrays(*tensors(c, n, x)), index, valid, None,
                                    tensors(np.full_like(truth, 1.0) * truth.mean((0, 1)))[0]))
    return frames


def loss_of(frames, values: dict, grad: bool = False):
    import drjit as dr
    import mitsuba as mi

    from denoise.fit import sequence_loss
    from denoise.methods.asvgf import FilterValues, hand_set

    p = hand_set(levels=2, box_radius=2)
    floats = {**p.continuous(), **values}
    wrapped = {k: dr.opaque(mi.Float, v) for k, v in floats.items()}  # opaque: one kernel for every value
    if grad:
        for v in wrapped.values():
            dr.enable_grad(v)
    loss = sequence_loss([frames], p, FilterValues(**wrapped))
    if not grad:
        return float(loss[0])
    dr.backward(loss)
    return float(loss[0]), {k: float(dr.grad(wrapped[k])[0]) for k in values}


def test_gradient_matches_central_differences(variant_vectorised_rgb):
    frames = sequence()
    _, grads = loss_of(frames, BASE, grad=True)
    for name, value in BASE.items():
        h = 3e-3 * max(value, 1.0)
        up, down = dict(BASE), dict(BASE)
        up[name], down[name] = value + h, value - h
        fd = (loss_of(frames, up) - loss_of(frames, down)) / (2 * h)
        assert abs(fd) > 1e-6, name  # a parameter that does something here
        assert abs(grads[name] - fd) <= 0.01 * abs(fd), (name, grads[name], fd)


def test_fit_refuses_bad_arguments(tmp_path, capsys):
    from denoise.fit import main

    for argv, message in ((["--steps", "0"], "--steps"), (["--rate", "-1"], "--rate"),
                          ([str(tmp_path / "none.json")], "none.json"),
                          (["--evaluate", str(tmp_path)], "not an exported frame folder"),
                          (["--switch-frame", "99"], "--switch-frame must be from 1 to 7"),
                          (["--switch-frame", "0"], "--switch-frame must be from 1 to 7")):
        fitting = [] if "--evaluate" in argv else ["--work", str(tmp_path), "--out", str(tmp_path / "p.json")]
        assert main(argv + fitting) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("python -m denoise.fit: error:") and message in err
    assert not (tmp_path / "p.json").exists()
    (tmp_path / "seq").mkdir()
    (tmp_path / "seq" / "beauty_0.exr").write_bytes(b"")  # only looked for: refused before it is read
    for argv, message in ((["--out", str(tmp_path / "p.txt")], "ending in .json"),
                          (["--evaluate", str(tmp_path / "seq")], "no ground truth for frame 0"),
                          (["--out", str(tmp_path / "seq" / "beauty_0.exr" / "p.json")], "--out"),
                          (["--evaluate", str(tmp_path / "seq"), "--steps", "3"], "--steps does not apply")):
        assert main(argv + ([] if "--evaluate" in argv else ["--work", str(tmp_path)])) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, err
    assert not (tmp_path / "p.txt").exists()


def test_frames_too_many_to_hold_are_refused_before_any_render(tmp_path, capsys):
    """A fit holds every frame with its derivatives (8 frames at 1920x1080: about
    20 GiB): a set beyond the memory is one line before anything is rendered."""
    from denoise.fit import main

    spec = tmp_path / "big.json"
    spec.write_text(json.dumps(dict(TINY, size=[16384, 16384], frames=8, reference_spp=4)))
    assert main([str(spec), "--work", str(tmp_path / "work"), "--out", str(tmp_path / "p.json")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"python -m denoise.fit: error: fitting on 8 frames held at once "
                                                   f"(the largest 16384x16384, {spec}) needs about "), err
    assert "GiB is available; fit on smaller frames or fewer of them" in err, err
    assert not (tmp_path / "work").exists() and not (tmp_path / "p.json").exists()


def test_evaluate_on_a_ground_truth_names_its_frames(tmp_path, capsys):
    """--evaluate SEQ_reference looked for SEQ_reference_reference/beauty_0.exr."""
    from denoise.fit import main

    (tmp_path / "seq").mkdir()
    truth = tmp_path / "seq_reference"
    truth.mkdir()
    (truth / "ground_truth.json").write_text("{}")
    (truth / "beauty_0.exr").write_bytes(b"")
    assert main(["--evaluate", str(truth)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"--evaluate {truth}: an export's ground truth (ground_truth.json), not its " \
        f"frames; give {tmp_path / 'seq'}" in err, err


def test_diverging_step_is_refused(variant_vectorised_rgb):
    from core.errors import UsageError
    from denoise.fit import Fit
    from denoise.methods.asvgf import hand_set

    frames = sequence()
    frames[1].reference = tensors(np.full((H, W, 3), np.nan))[0]
    with pytest.raises(UsageError, match="diverging"):
        Fit(hand_set(levels=2), 0.05).step([frames])


def test_parameter_file_round_trip(variant_vectorised_rgb, tmp_path):
    from denoise.fit import write_parameters
    from denoise.methods.asvgf import load_parameter_file

    path = tmp_path / "p.json"
    write_parameters(path, {"clip_width": 1.25, "sigma_plane": 0.2}, 0.1, 0.2, ["a.json"])
    assert load_parameter_file(path) == {"clip_width": 1.25, "sigma_plane": 0.2}
    assert json.loads(path.read_text())["hand_set_loss"] == 0.2


@pytest.mark.timed
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_signal_during_the_fit_stops_it_within_two_seconds(tmp_path, signum):
    """A gradient step is one native call of up to minutes (its first one
    compiles the kernels): the steps run in a worker process, which the
    command ends on Ctrl-C or SIGTERM; one line, no parameter file, no process left."""
    psutil = pytest.importorskip("psutil")
    spec = tmp_path / "seq.json"
    spec.write_text(json.dumps(TINY))
    out = tmp_path / "p.json"
    # its own session: the SIGINT to the group is what a terminal's Ctrl-C sends
    fit = subprocess.Popen([sys.executable, "-m", "denoise.fit", str(spec), "--work", str(tmp_path / "fit"),
                            "--steps", "1000", "--switch-frame", "1", "--out", str(out)], cwd=ROOT,
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 300
        while not any("denoise" in " ".join(c.cmdline()) or "multiprocessing" in " ".join(c.cmdline())
                      for c in psutil.Process(fit.pid).children()):
            assert fit.poll() is None and time.monotonic() < deadline, fit.communicate()
            time.sleep(0.05)
        time.sleep(4.0)  # the worker imports, prepares the frames and compiles its first step
        children = psutil.Process(fit.pid).children(recursive=True)
        start = time.monotonic()
        os.killpg(fit.pid, signum)
        _, err = fit.communicate(timeout=120)
        elapsed = time.monotonic() - start
    finally:
        if fit.poll() is None:
            os.killpg(fit.pid, signal.SIGKILL)
    assert fit.returncode == 128 + signum, err
    assert elapsed < 2.0, elapsed
    assert err.count("\n") == 1 and err.startswith("python -m denoise.fit: interrupted"), err
    assert not out.exists()
    _, alive = psutil.wait_procs(children, timeout=10)
    assert not alive, alive


@pytest.mark.parametrize("smaller", ["truth", "next frame"])
def test_sizes_that_disagree_are_one_line_naming_both_files(variant_vectorised_rgb, tmp_path, smaller):
    """prepare checks each frame against its ground truth and the frame before, before any arithmetic."""
    import dataclasses

    from test_denoise_score import CROPPED, plane_frames

    from core.errors import FrameError
    from denoise.fit import prepare
    from export.frames import write_frame
    from imaging.image_io import write_exr

    folder = tmp_path / "seq"
    for i, frame in enumerate(plane_frames(2)):
        if i == 1 and smaller == "next frame":
            fields = {f.name: getattr(frame, f.name) for f in dataclasses.fields(frame)}
            frame = type(frame)(**{k: v[:, :8] if k in CROPPED else v for k, v in fields.items()})
        write_frame(folder, i, frame)
        truth = frame.beauty[:, :8] if i == 1 and smaller == "truth" else frame.beauty
        write_exr(tmp_path / "seq_reference" / f"beauty_{i}.exr", {"": truth})
    other = "seq_reference/beauty_1.exr" if smaller == "truth" else "seq/beauty_0.exr"
    mine = "16x12" if smaller == "truth" else "8x12"
    with pytest.raises(FrameError, match=f"seq/beauty_1.exr: {mine} pixels, but .*{other} has "):
        prepare(folder)
