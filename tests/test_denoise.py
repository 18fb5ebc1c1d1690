"""The denoiser's Dr.Jit kernels against a plain NumPy implementation of the same maths."""
from __future__ import annotations

import signal
from pathlib import Path

import numpy as np
import pytest
from helpers import render_layers

from converters.course_scene import load_scene
from converters.scene_variants import with_path_tracer

ROOT = Path(__file__).resolve().parent.parent
B3 = np.array([1, 4, 6, 4, 1]) / 16.0


# -- the NumPy reference ------------------------------------------------------------
def np_normalize(v):
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.divide(v, n, out=np.zeros_like(v), where=n > 0)


def shifted(a, dx, dy):
    """a[y + dy, x + dx] and whether it is inside the image."""
    h, w = a.shape[:2]
    out = np.zeros_like(a)
    inside = np.zeros((h, w), bool)
    ys, xs = slice(max(0, -dy), min(h, h - dy)), slice(max(0, -dx), min(w, w - dx))
    ys2, xs2 = slice(max(0, dy), min(h, h + dy)), slice(max(0, dx), min(w, w + dx))
    out[ys, xs] = a[ys2, xs2]
    inside[ys, xs] = True
    return out, inside


def np_edge(sc, sn, sp, ci, ni, xi, cj, nj, xj):
    d_color = ((ci - cj) ** 2).sum(-1)
    d_normal = np.arccos(np.clip((ni * nj).sum(-1), -1, 1)) ** 2
    d_plane = (ni * np_normalize(xj - xi)).sum(-1) ** 2
    return d_color / (2 * sc ** 2) + d_normal / (2 * sn ** 2) + d_plane / (2 * sp ** 2)


def np_bilateral(c, n, x, r, s_coord, sc, sn, sp):
    n = np_normalize(n)
    total, weights = c.copy(), np.ones(c.shape[:2])
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            if dx == 0 and dy == 0:
                continue
            cj, inside = shifted(c, dx, dy)
            nj, _ = shifted(n, dx, dy)
            xj, _ = shifted(x, dx, dy)
            w = np.exp(-((dx * dx + dy * dy) / (2 * s_coord ** 2) + np_edge(sc, sn, sp, c, n, x, cj, nj, xj)))
            w = np.where(inside, w, 0)
            total += w[..., None] * cj
            weights += w
    return total / weights[..., None]


def np_atrous(c, n, x, levels, sc, sn, sp):
    n = np_normalize(n)
    for level in range(levels):
        step = 1 << level
        total, weights = np.zeros_like(c), np.zeros(c.shape[:2])
        for j in range(5):
            for i in range(5):
                dx, dy = (i - 2) * step, (j - 2) * step
                cj, inside = shifted(c, dx, dy)
                nj, _ = shifted(n, dx, dy)
                xj, _ = shifted(x, dx, dy)
                if dx == 0 and dy == 0:
                    w = np.full(c.shape[:2], B3[i] * B3[j])
                else:
                    w = np.where(inside, B3[i] * B3[j] * np.exp(-np_edge(sc / step, sn, sp, c, n, x, cj, nj, xj)), 0)
                total += w[..., None] * cj
                weights += w
        c = total / weights[..., None]
    return c


def np_accumulate(current, previous, index, valid, alpha, k, r, bounds=None):
    h, w = current.shape[:2]
    flat = previous.reshape(-1, 3)
    history = np.where(valid.reshape(h, w, 1), flat[index].reshape(h, w, 3), 0)
    mean, count, square = np.zeros_like(current), np.zeros((h, w, 1)), np.zeros_like(current)
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            cj, inside = shifted(current if bounds is None else bounds, dx, dy)
            mean += np.where(inside[..., None], cj, 0)
            square += np.where(inside[..., None], cj * cj, 0)
            count += inside[..., None]
    mean /= count
    sigma = np.sqrt(np.maximum(square / count - mean ** 2, 0))
    history = np.clip(history, mean - k * sigma, mean + k * sigma)
    a = np.where(valid.reshape(h, w, 1), alpha, 1.0)
    return a * current + (1 - a) * history


# -- fixtures ------------------------------------------------------------------------
@pytest.fixture(scope="module", name="buffers")
def buffers_fixture():
    """Realistic buffers: G-buffers of our showcase scene and a noisy 1-spp path-traced beauty."""
    from conftest import _set

    _set("llvm_ad_rgb")
    scene = load_scene(ROOT / "scenes" / "showcase.txt")
    g = render_layers(scene, width=40, height=28, aovs=("normal", "position", "id"))
    noisy = render_layers(scene, width=40, height=28, spp=1, jitter=True, bounces=3, variants=(with_path_tracer,))[""]
    return noisy.astype(np.float64), g["normal"].astype(np.float64), g["position"].astype(np.float64), g["id"]


def tensors(*arrays):
    import mitsuba as mi

    return [mi.TensorXf(np.ascontiguousarray(a, np.float32)) for a in arrays]


def close(ours, reference):
    ours, reference = np.asarray(ours, np.float64), np.asarray(reference, np.float64)
    scale = np.maximum(np.abs(reference), 1e-2)
    return float(np.max(np.abs(ours - reference) / scale))


# -- tests ---------------------------------------------------------------------------
def test_joint_bilateral_matches_numpy(variant_llvm_ad_rgb, buffers):
    from denoise.filters import BilateralWindow, EdgeWeights, FrameArrays, joint_bilateral

    c, n, x, _ = buffers
    p = EdgeWeights(sigma_color=0.6, sigma_normal=0.3, sigma_plane=0.3)
    ours = np.array(joint_bilateral(FrameArrays(*tensors(c, n, x)), p, BilateralWindow(radius=4, sigma_coord=3.0)))
    reference = np_bilateral(c, n, x, 4, 3.0, 0.6, 0.3, 0.3)
    assert close(ours, reference) < 1e-4
    assert np.abs(np.diff(ours, axis=1)).mean() < np.abs(np.diff(c, axis=1)).mean()  # it smooths


def test_atrous_matches_numpy(variant_llvm_ad_rgb, buffers):
    from denoise.filters import EdgeWeights, FrameArrays
    from denoise.methods.atrous import atrous

    c, n, x, _ = buffers
    p = EdgeWeights(sigma_color=0.6, sigma_normal=0.3, sigma_plane=0.3)
    ours = np.array(atrous(FrameArrays(*tensors(c, n, x)), p, levels=3))
    assert close(ours, np_atrous(c, n, x, 3, 0.6, 0.3, 0.3)) < 1e-4


def test_accumulate_matches_numpy(variant_llvm_ad_rgb, buffers):
    import mitsuba as mi

    from denoise.filters import TemporalParams, accumulate

    c, _, _, _ = buffers
    rng = np.random.default_rng(5)
    previous = c * 0.8 + 0.1
    index = rng.integers(0, c.shape[0] * c.shape[1], c.shape[0] * c.shape[1])
    valid = rng.random(index.shape) > 0.3
    current, prev = tensors(c, previous)
    ours = np.array(accumulate(current, prev, mi.UInt32(index.astype(np.uint32)), mi.Bool(valid),
                               TemporalParams(alpha=0.2, k=1.0, clamp_radius=3)))
    assert close(ours, np_accumulate(c, previous, index, valid, 0.2, 1.0, 3)) < 1e-4
    # the clamp's neighbourhood taken from another image (oidn-guided's guide)
    guide = c * 0.5 + 0.05
    ours = np.array(accumulate(current, prev, mi.UInt32(index.astype(np.uint32)), mi.Bool(valid),
                               TemporalParams(alpha=0.5, k=1.0, clamp_radius=1), bounds=tensors(guide)[0]))
    assert close(ours, np_accumulate(c, previous, index, valid, 0.5, 1.0, 1, bounds=guide)) < 1e-4
    assert close(ours, np_accumulate(c, previous, index, valid, 0.5, 1.0, 1)) > 1e-2  # the bounds matter


def test_screen_matrix_and_static_reprojection(variant_llvm_ad_rgb, buffers):
    """The world-to-screen matrix sends each pixel's surface point to that pixel;
    so in a static scene every hit reprojects onto itself and the background is invalid."""
    from denoise.filters import reproject
    from export.frames import camera_matrices, depth_range

    _, _, x, ids = buffers
    h, w = ids.shape
    scene = load_scene(ROOT / "scenes" / "showcase.txt")
    hit = ids >= 0
    camera, screen = camera_matrices(scene.camera, w, h, *depth_range(scene.camera, x[hit]))
    p = np.concatenate([x[hit], np.ones((hit.sum(), 1))], 1) @ screen.T
    pixels = np.floor(p[:, :2] / p[:, 3:])
    rows, cols = np.nonzero(hit)
    assert np.mean((pixels[:, 0] == cols) & (pixels[:, 1] == rows)) > 0.999
    # the course's convention: depth into (0, 1), w = the camera's depth
    assert np.all((p[:, 2] / p[:, 3] > 0) & (p[:, 2] / p[:, 3] < 1))
    assert np.allclose(screen[3], camera[2])
    objects = [np.eye(4)] * len(scene.objects)
    index, valid = reproject(*tensors(x, ids, ids), objects, objects, screen)
    index, valid = np.array(index), np.array(valid)
    assert not valid[~hit.ravel()].any()
    own = np.arange(h * w)
    assert np.mean(valid[hit.ravel()] & (index[hit.ravel()] == own[hit.ravel()])) > 0.999

    # a previous screen beyond float32 (a camera dollied 2^200 away): no history, and no NumPy warning
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _, far = reproject(*tensors(x, ids, ids), objects, objects, screen * 1e300)
    assert not np.array(far).any()


def test_frame_folder_round_trip(tmp_path):
    from core.errors import FrameError
    from export.frames import FrameData, read_frame, write_frame

    rng = np.random.default_rng(2)
    frame = FrameData(rng.random((4, 5, 3)), rng.random((4, 5, 3)), rng.random((4, 5, 3)), rng.random((4, 5)),
                      rng.integers(-1, 2, (4, 5)), [np.eye(4), np.diag([2.0, 2, 2, 1])], np.eye(4) * 3, np.eye(4) * 4)
    write_frame(tmp_path, 0, frame)
    back = read_frame(tmp_path, 0)
    assert np.allclose(back.beauty, frame.beauty, atol=1e-6) and np.array_equal(back.ids, frame.ids)
    assert np.allclose(back.object_to_world[1], frame.object_to_world[1])
    assert np.allclose(back.world_to_screen, frame.world_to_screen)
    (tmp_path / "matrix_0.mat").write_bytes(b"\x02\x00\x00\x00")
    with pytest.raises(FrameError, match="expected 260 bytes for 2 objects"):
        read_frame(tmp_path, 0)
    for damaged in (b"garbage!", b"\xff\xff\xff\xff" + bytes(64)):  # text; a count of -1
        (tmp_path / "matrix_0.mat").write_bytes(damaged)
        with pytest.raises(FrameError, match=r"matrix_0.mat: not a matrix file \(its first 4 bytes give -?\d+ objects"):
            read_frame(tmp_path, 0)


GAMES202_BOX = ROOT.parent / "shared" / "games202" / "box"


def course_z_over_w(screen, points):
    p = np.concatenate([points, np.ones((len(points), 1))], 1) @ screen.T
    return p[:, 2] / p[:, 3]


@pytest.mark.skipif(not GAMES202_BOX.is_dir(), reason="the course's example frames are not beside the checkout")
def test_course_example_frames_read_and_reproject(variant_llvm_ad_rgb):
    """The course framework's own frames (GAMES202 box): our reader takes them,
    their world-to-screen follows the convention of export/frames.py (pixel
    centres at i + 0.5, w = camera depth, z/w in (0, 1)), and our back
    projection keeps >= 99 % of the visible pixels' history between
    consecutive frames."""
    from denoise.filters import reproject
    from export.frames import read_frame

    frames = [read_frame(GAMES202_BOX, i) for i in range(4)]
    for f in frames:
        hit = f.ids >= 0
        z = course_z_over_w(f.world_to_screen, f.position[hit])
        assert np.all((z > 0) & (z < 1))
        p = np.concatenate([f.position[hit], np.ones((hit.sum(), 1))], 1) @ f.world_to_screen.T
        rows, cols = np.nonzero(hit)
        assert np.mean((np.floor(p[:, 0] / p[:, 3]) == cols) & (np.floor(p[:, 1] / p[:, 3]) == rows)) > 0.99
        assert np.allclose(f.world_to_screen[3], f.world_to_camera[2], atol=1e-4)
        assert np.allclose((p[:, 3]), f.depth[hit], rtol=1e-3)  # w is the depth buffer's value
    for before, after in zip(frames, frames[1:]):
        index, valid = reproject(*tensors(after.position, after.ids, before.ids), after.object_to_world,
                                 before.object_to_world, before.world_to_screen)
        hit = after.ids.ravel() >= 0
        assert np.array(valid)[hit].mean() >= 0.99


def test_the_convention_check_fails_on_the_old_matrices(variant_llvm_ad_rgb, buffers):
    """The z/w check above catches the old export, whose depth row copied the w
    row (z/w = 1 everywhere, which the course's solutions reject)."""
    from export.frames import camera_matrices, depth_range

    _, _, x, ids = buffers
    scene = load_scene(ROOT / "scenes" / "showcase.txt")
    hit = ids >= 0
    camera, screen = camera_matrices(scene.camera, ids.shape[1], ids.shape[0], *depth_range(scene.camera, x[hit]))
    old = screen.copy()
    old[2] = old[3]
    z = course_z_over_w(old, x[hit])
    assert not np.all((z > 0) & (z < 1))


DIFFUSE_SCENE = """
PerspectiveCamera { center 0 2 7 direction 0 -0.25 -1 up 0 1 0 angle 40 }
Lights { numLights 1 DirectionalLight { direction -0.3 -1 -0.4 color 0.8 0.8 0.8 } }
Background { color 0.2 0.3 0.5 ambientLight 0.15 0.15 0.15 }
Materials { numMaterials 3 Material { diffuseColor 0.7 0.7 0.65 } Material { diffuseColor 0.8 0.2 0.2 }
            Material { diffuseColor 0.2 0.3 0.8 } }
Group { numObjects 3
  MaterialIndex 0 Plane { normal 0 1 0 offset 0 }
  MaterialIndex 1 Sphere { center -1 0.8 0 radius 0.8 }
  MaterialIndex 2 Transform { Translate 1.2 0.6 0.3 UniformScale 0.6 Sphere { center 0 0 0 radius 1 } } }
"""


@pytest.mark.parametrize("motion", ["camera", "object"])
def test_reprojection_of_the_ground_truth(variant_llvm_ad_rgb, tmp_path, motion):
    """The previous frame's ground truth, back-projected onto the current frame,
    matches the current ground truth: relMSE <= 1e-3 over the valid pixels.
    (Ground truth here: whitted through the pixel centres, the points the
    G-buffers describe, on a diffuse scene, so only geometry can differ.)"""

    from denoise.filters import reproject
    from export import Spec, export, reference_folder
    from export.frames import read_frame
    from imaging.image_io import read_exr
    from imaging.metrics import relmse

    (tmp_path / "diffuse.txt").write_text(DIFFUSE_SCENE)
    moves = {"camera": dict(camera={"orbit": {"center": [0, 0.5, 0], "degrees": 4}, "pan": [0.2, 0, 0]}),
             "object": dict(objects={"2": {"translate": [-0.3, 0, 0.2]}})}[motion]
    spec = Spec(scene=str(tmp_path / "diffuse.txt"), frames=2, size=(96, 64), spp=1, reference_spp=2,
                bounces=0, shadows=False, jitter=False, **moves)
    target = tmp_path / "seq"
    assert export(spec, target, whitted=True) == [0, 1]
    assert export(spec, target, whitted=True) == []  # resumes: nothing left to do
    before, after = read_frame(target, 0), read_frame(target, 1)
    truth = [np.stack([read_exr(reference_folder(target) / f"beauty_{i}.exr")[c] for c in "RGB"], -1)
             for i in (0, 1)]
    for f in (before, after):  # the course's matrix convention (see test_course_example_frames_...)
        z = course_z_over_w(f.world_to_screen, f.position[f.ids >= 0])
        assert np.all((z > 0) & (z < 1))
        assert np.allclose(f.world_to_screen[3], f.world_to_camera[2], atol=1e-4)
    # every point of the new frame that keeps its history lies in (0, 1) of the old one too
    index, valid = reproject(*tensors(after.position, after.ids, before.ids), after.object_to_world,
                             before.object_to_world, before.world_to_screen)
    index, valid = np.array(index), np.array(valid)
    assert valid.mean() > 0.5  # the rest is sky or newly visible
    moved = [np.linalg.inv(after.object_to_world[k]) for k in range(len(after.object_to_world))]
    kept = valid.reshape(after.ids.shape)
    world_before = np.stack([(before.object_to_world[k] @ moved[k] @ np.append(p, 1))[:3]
                             for p, k in zip(after.position[kept], after.ids[kept])])
    z = course_z_over_w(before.world_to_screen, world_before)
    assert np.all((z > 0) & (z < 1))
    warped = truth[0].reshape(-1, 3)[index][valid]
    assert relmse(warped, truth[1].reshape(-1, 3)[valid]) <= 1e-3
    assert relmse(truth[0].reshape(-1, 3)[valid], truth[1].reshape(-1, 3)[valid]) > 1e-3  # it did move


#: what ``python -m benchmarks.denoise`` compares (its METHODS, from the registry)
BENCHMARK_METHODS = ("raw", "bilateral", "atrous", "bilateral+temporal", "atrous+temporal",
                     "demod+outliers+atrous+temporal", "svgf", "asvgf", "learned-asvgf",
                     "learned-asvgf-no-temporal-inputs", "learned-asvgf-half-hidden", "learned-mixture",
                     "learned-mixture-no-temporal-inputs", "learned-mixture-half-channels", "oidn-fast",
                     "oidn-balanced", "oidn-high", "oidn+temporal", "oidn-guided")
#: every method but raw is timed (its TIMED: the error-against-time front)
TIMED_METHODS = tuple(m for m in BENCHMARK_METHODS if m != "raw")


def test_denoise_command_and_benchmark_quick(variant_llvm_ad_rgb, tmp_path):
    """The quick benchmark renders the hard sequence small, runs every method
    (OIDN included), times them, and writes finite numbers with the new
    figures; `python -m denoise` writes one result per frame, PNG previews and
    a video."""
    import json
    import subprocess
    import sys

    from denoise.__main__ import main as denoise_main
    from imaging.image_io import read_exr

    out = tmp_path / "dn.json"
    command = [sys.executable, "-m", "benchmarks.denoise", "--quick", "--json", str(out), "--work",
               str(tmp_path / "work"), "--sequences", "glossy_shadow"]
    finished = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=1800)
    assert finished.returncode == 0, finished.stderr[-3000:]
    results = json.loads(out.read_text())
    assert {r["method"] for r in results["results"]} == set(BENCHMARK_METHODS)
    assert all(np.isfinite([r["relmse"], r["flip"], r["ms"]]).all() for r in results["results"])
    assert all((r["temporal"] is None) == (r["frame"] == 0) for r in results["results"])
    sequence = results["sequences"][0]
    assert np.isfinite(sequence["reference_noise"]) and sequence["reference_noise"] > 0
    assert set(sequence["stability"]) == set(BENCHMARK_METHODS)
    assert set(results["timing"]["ms"]) == set(results["timing"]["cpu_ms"]) == set(TIMED_METHODS)
    assert all(v > 0 for v in results["timing"]["cpu_ms"].values())
    last = {r["method"]: r["relmse"] for r in results["results"] if r["frame"] == 3}
    assert last["atrous+temporal"] < last["raw"] / 2  # it denoises
    assert results["timing"]["ratio_to_oidn"]["oidn-high"] == 1.0
    # --methods without the baseline (oidn-high): its speed bars are printed, no ratio to the
    # baseline is written (that run once ended in a KeyError traceback)
    finished = subprocess.run(command + ["--methods", "oidn-fast", "atrous+temporal"], cwd=ROOT,
                              capture_output=True, text=True, timeout=1800)
    assert finished.returncode == 0, finished.stderr[-3000:]
    timing = json.loads(out.read_text())["timing"]
    assert set(timing["ms"]) == {"oidn-fast", "atrous+temporal"} and "ratio_to_oidn" not in timing
    speed = [line for line in finished.stdout.splitlines() if line.startswith("speed at 160x90 (")]
    assert len(speed) == 1 and "atrous+temporal / oidn-fast = " in speed[0], finished.stdout
    # a bar whose base did not run is said to be unchecked, not passed over
    finished = subprocess.run(command + ["--methods", "oidn-high", "svgf"], cwd=ROOT, capture_output=True,
                              text=True, timeout=1800)
    assert "svgf / oidn-fast (no oidn-fast in this run): not checked" in finished.stdout, finished.stdout
    front = subprocess.run([sys.executable, "-m", "benchmarks.denoise_front", "--json", str(out), "--out",
                            str(tmp_path / "front.png")], cwd=ROOT, capture_output=True, text=True, timeout=300)
    # four frames a sequence: no mean over frames >= 4, so no front (one line; the front's own test draws one)
    assert front.returncode == 2 and "no front to draw" in front.stderr and front.stderr.count("\n") == 1
    # the per-kernel profile, on the speed run's frames just rendered: À-Trous has its
    # 5 levels, each reading 24 taps' colour (3 planes) and guides (6 planes) as shifted loads
    # (denoise.neighbours), no gathers (the centre's own values loaded)
    profile = tmp_path / "profile.json"
    finished = subprocess.run([sys.executable, "-m", "benchmarks.denoise_profile", "--quick", "--work",
                               str(tmp_path / "work"), "--json", str(profile)], cwd=ROOT, capture_output=True,
                              text=True, timeout=600)
    assert finished.returncode == 0, finished.stderr[-3000:]
    atrous = json.loads(profile.read_text())["methods"][0]
    levels = [k for k in atrous["kernels"] if k["level"]]
    assert atrous["method"] == "atrous+temporal" and len(levels) == 5
    assert all(not k["packet_gathers"] and k["shifted_loads"] >= 9 * 24 for k in levels)
    assert 0 < atrous["levels_ms"] <= atrous["kernels_ms"]
    folder = tmp_path / "work" / "glossy_shadow_96x54_16spp_quick"
    video = tmp_path / "den.mp4"
    assert denoise_main([str(folder), str(tmp_path / "results"), "--method", "svgf", "--png", "--video", str(video),
                         "--reference", str(folder.parent / "glossy_shadow_96x54_16spp_quick_reference")]) == 0
    results = sorted((tmp_path / "results").glob("result_*.exr"))
    assert len(results) == 4 and len(list((tmp_path / "results").glob("result_*.png"))) == 4
    assert all(np.isfinite(np.stack(list(read_exr(p).values()))).all() for p in results)
    import imageio.v2 as imageio

    frames = imageio.mimread(video)
    assert len(frames) == 4 and frames[0].shape[1] == 3 * 96  # input | output | reference
    # our OIDN-guided accumulation is a method of the command too
    assert denoise_main([str(folder), str(tmp_path / "guided"), "--method", "oidn-guided"]) == 0
    assert len(list((tmp_path / "guided").glob("result_*.exr"))) == 4


def test_the_front_is_the_methods_no_other_beats_in_error_and_time(tmp_path):
    """benchmarks.denoise_front on made-up results: a method slower and worse than
    another is off the front; the mean over sequences is geometric; no speed run is one line."""
    import json
    import subprocess
    import sys

    points = {"a": (10, 0.1), "b": (20, 0.05), "c": (30, 0.2), "d": (40, 0.01)}
    rows = [{"sequence": s, "method": m, "frame": f, "relmse": e * scale}
            for s, scale in (("one", 1.0), ("two", 4.0)) for m, (_, e) in points.items() for f in range(6)]
    results = {"sequences": [{"name": "one"}, {"name": "two"}], "results": rows,
               "timing": {"size": [1280, 720], "ms": {m: t for m, (t, _) in points.items()}}}
    path = tmp_path / "r.json"
    path.write_text(json.dumps(results))
    command = [sys.executable, "-m", "benchmarks.denoise_front", "--json", str(path), "--out", str(tmp_path / "f.png")]
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().endswith("fastest first: a, b, d")
    del results["timing"]
    path.write_text(json.dumps(results))
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and "no speed run" in done.stderr


@pytest.mark.parametrize("argv, message", [
    (["--quick", "--sequences", "nosuch"], "--sequences: no sequence 'nosuch'; choose from"),
    (["--reference-spp", "3"], "--reference-spp must be an even number >= 2"),
    (["--reference-spp", "0"], "--reference-spp must be an even number >= 2"),
    (["--quick", "--work", "README.md"], "--work README.md: a file, not a folder"),
    (["--quick", "--json", "docs"], "--json docs: a folder"),
    (["--quick", "--json", "/proc/x/a.json"], "/proc/x: No such file or directory"),
])
@pytest.mark.parametrize("module", ["benchmarks.denoise", "benchmarks.denoise_profile"])
def test_denoise_benchmarks_refuse_bad_arguments_first(module, argv, message):
    """Bad arguments of the two denoising benchmarks: one line, exit 2, before
    anything is rendered or timed (the profile has no --sequences/--reference-spp)."""
    import subprocess
    import sys

    if module.endswith("profile") and ("--sequences" in argv or "--reference-spp" in argv):
        message = "unrecognized arguments"
    finished = subprocess.run([sys.executable, "-m", module, *argv], cwd=ROOT, capture_output=True, text=True,
                              timeout=120)
    assert finished.returncode == 2 and "Traceback" not in finished.stderr, finished.stderr[-2000:]
    assert finished.stderr.count("\n") == 1 and message in finished.stderr, finished.stderr


@pytest.mark.parametrize("flags, message", [
    (["--levels", "31"], "--levels must be a whole number from 1 to 12"),
    (["--method", "bilateral", "--radius", "-5"], "bilateral: --radius must be a whole number from 0 to 64"),
    # an option the method does not take: that first, whatever its value (not the value checked as another's)
    (["--radius", "-5"], "--radius is an option of bilateral, not of atrous"),
    (["--method", "svgf", "--sigma-normal", "-1"], "--sigma-normal is an option of bilateral, atrous, not of svgf"),
    (["--alpha", "2"], "--alpha must be a number in (0, 1]"),
    (["--alpha", "0"], "--alpha"),
    (["--k", "-1"], "--k must be a finite number >= 0"),
    (["--sigma-color", "0"], "--sigma-color must be a finite number > 0"),
    (["--sigma-plane", "-1"], "--sigma-plane"),
    (["--sigma-coord", "inf"], "--sigma-coord"),
    (["--outliers", "-1"], "atrous: --outliers must be a finite number > 0"),
    (["--method", "svgf", "--sigma-luminance", "nan"], "svgf: --sigma-luminance must be"),
    (["--method", "svgf", "--normal-exponent", "-3"], "svgf: --normal-exponent must be"),
    (["--video", "out.gif"], "name it .mp4"),
    (["--fps", "8"], "--fps is used by --video only"),
    (["--reference", "ref"], "--reference is used by --video only"),
    (["--video", "v.mp4", "--fps", "0"], "--fps must be from 1 to 240"),
])
def test_denoise_rejects_bad_parameters(tmp_path, capsys, flags, message):
    """Each out-of-range parameter: one line, exit 2, before any frame is read."""
    from denoise.__main__ import main

    assert main([str(tmp_path / "none"), str(tmp_path / "out")] + flags) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("python -m denoise: error: ") and message in err
    assert err.strip().isprintable()  # a control character in a message is shown escaped


def _small_folder(folder, count=2, size=(5, 4), objects=1):
    from export.frames import FrameData, write_frame

    rng = np.random.default_rng(4)
    h, w = size[1], size[0]
    for i in range(count):
        write_frame(folder, i, FrameData(rng.random((h, w, 3)), rng.random((h, w, 3)), rng.random((h, w, 3)),
                                         rng.random((h, w)), np.zeros((h, w), np.int32), [np.eye(4)] * objects,
                                         np.eye(4), np.eye(4)))


@pytest.mark.parametrize("damage, message", [
    (lambda f: (f / "normal_1.exr").write_bytes(b"not an exr"), "normal_1.exr: not a readable EXR"),
    (lambda f: (f / "beauty_1.exr").write_bytes((f / "beauty_1.exr").read_bytes()[:300]), "beauty_1.exr"),
    (lambda f: _small_folder_one(f, 1, size=(6, 4)), "beauty_1.exr: 6x4 pixels, but frame 0 has 5x4"),
    (lambda f: _write_ids(f, 1, 3), "ID_1.exr: object id 3, but matrix_1.mat has matrices for 1 objects"),
    (lambda f: _write_ids(f, 0, 0.5), "ID_0.exr: object ids must be whole numbers"),
    (lambda f: (f / "position_0.exr").unlink(), "frame 0 lacks position_0.exr"),
    (lambda f: (f / "matrix_1.mat").write_bytes(b"\x01\x00"), "matrix_1.mat: expected an int32 object count"),
])
def test_denoise_rejects_bad_frames(variant_llvm_ad_rgb, tmp_path, capsys, damage, message):
    """Damaged or inconsistent frame folders: one line naming the file, exit 2."""
    from denoise.__main__ import main

    folder = tmp_path / "frames"
    _small_folder(folder)
    damage(folder)
    assert main([str(folder), str(tmp_path / "out"), "--method", "bilateral", "--radius", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err, err


@pytest.mark.parametrize("spare", [-1, 0], ids=["one byte short", "just enough"])
def test_frames_too_large_for_the_memory_are_one_line_before_any_frame(variant_llvm_ad_rgb, tmp_path, capsys,
                                                                       monkeypatch, spare):
    """The first frame's header gives the size; frames that would take more
    memory than is available are refused before the first is read (an 8192x8192
    folder was killed for memory), with the memory here made just short."""
    import denoise.pipeline as pipeline
    import renderer.checks as checks
    from denoise.__main__ import main
    from imaging.image_io import exr_size

    folder = tmp_path / "frames"
    _small_folder(folder)
    assert exr_size(folder / "beauty_0.exr") == (5, 4) and exr_size(folder / "nothing.exr") is None
    monkeypatch.setattr(checks, "available_memory", lambda: pipeline.BASE_BYTES + pipeline.BYTES_PER_PIXEL * 20
                        + spare)
    code = main([str(folder), str(tmp_path / "out"), "--method", "bilateral", "--radius", "1"])
    err = capsys.readouterr().err
    if spare < 0:
        assert code == 2 and err.count("\n") == 1, err
        assert f"{folder / 'beauty_0.exr'}: denoising 5x4 frames needs about 0.5 GiB of memory" in err, err
        assert not (tmp_path / "out").exists()
    else:
        assert code == 0 and err == "", err


@pytest.mark.parametrize("asked", [["--method", "atrous", "--demodulate"], ["--method", "demod+atrous"]],
                         ids=["--demodulate", "demod+"])
def test_demodulation_without_albedo_is_refused_however_asked(variant_llvm_ad_rgb, tmp_path, capsys, asked):
    """demod+atrous on frames without albedo ran as plain atrous (the same bytes), in silence."""
    from denoise.__main__ import main

    folder = tmp_path / "frames"
    _small_folder(folder)
    assert main([str(folder), str(tmp_path / "out"), *asked, "--levels", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "demodulation (--demodulate, or demod+ in the method's name) needs albedo_i.exr" \
        in err, err
    assert not (tmp_path / "out").exists()


def test_an_unfinished_export_is_refused_not_taken_for_the_sequence(variant_llvm_ad_rgb, tmp_path, capsys):
    """Frames 0-2 of an export whose record names 4 (still running, or stopped):
    5 of 8 frames were denoised and scored, exit 0, without a word."""
    import json

    from denoise.__main__ import main

    folder = tmp_path / "frames"
    _small_folder(folder, count=3)
    (folder / "sequence.json").write_text(json.dumps({"format": 2, "spec": {"frames": 4}}))
    assert main([str(folder), str(tmp_path / "out"), "--method", "bilateral", "--radius", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{folder}: 1 of the 4 frames its export names are missing (frame 3 first)" \
        in err, err
    (folder / "sequence.json").write_text(json.dumps({"format": 2, "spec": {"frames": 3}}))
    assert main([str(folder), str(tmp_path / "out"), "--method", "bilateral", "--radius", "1"]) == 0


def _small_folder_one(folder, index, size):
    from export.frames import FrameData, write_frame

    h, w = size[1], size[0]
    write_frame(folder, index, FrameData(np.ones((h, w, 3)), np.ones((h, w, 3)), np.ones((h, w, 3)), np.ones((h, w)),
                                         np.zeros((h, w), np.int32), [np.eye(4)], np.eye(4), np.eye(4)))


def _write_ids(folder, index, value):
    from imaging.image_io import write_exr

    write_exr(folder / f"ID_{index}.exr", {"": np.full((4, 5), value, np.float32)})


def test_denoise_shows_progress_only_on_a_terminal(variant_llvm_ad_rgb, tmp_path, capsys, monkeypatch):
    """With stderr redirected, a successful run leaves it empty: in process with
    the bar's delay at 0 (a bar would show at once), and as a command."""
    import subprocess
    import sys

    import denoise.pipeline as pipeline
    from denoise.__main__ import main

    folder = tmp_path / "frames"
    _small_folder(folder, count=3)
    monkeypatch.setattr(pipeline, "PROGRESS_DELAY_S", 0.0)
    assert main([str(folder), str(tmp_path / "out"), "--method", "bilateral", "--radius", "1"]) == 0
    captured = capsys.readouterr()
    assert captured.err == "" and "3 frames ->" in captured.out
    finished = subprocess.run([sys.executable, "-m", "denoise", str(folder), str(tmp_path / "command"),
                               "--method", "bilateral", "--radius", "1"], cwd=ROOT, capture_output=True, text=True,
                              timeout=300)
    assert finished.returncode == 0 and finished.stderr == "", finished.stderr


@pytest.mark.parametrize("flags, message", [
    (["--method", "atrous", "--oidn-quality", "fast"], "--oidn-quality is an option of oidn, oidn-guided, not "
     "of atrous"),
    (["--radius", "3"], "--radius is an option of bilateral, not of atrous"),
])
def test_an_option_the_method_does_not_read_is_refused(tmp_path, capsys, flags, message):
    """It would change nothing: a user who asked for OIDN's fast mode with atrous got atrous, silently."""
    from denoise.__main__ import main

    assert main([str(tmp_path / "none"), str(tmp_path / "out")] + flags) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("python -m denoise: error: ") and message in err, err


@pytest.mark.parametrize("second", ["fewer frames", "stops early"])
def test_results_of_an_earlier_run_are_not_left_beside_this_runs(variant_llvm_ad_rgb, tmp_path, capsys, second):
    """python -m denoise into an OUT_DIR holding the last run's results: those it does
    not replace are removed (one note), so that a run over fewer frames, or one that
    stops at a damaged frame, leaves its own results alone. Only files the last run
    recorded as its own go: a user's files, even named like results, stay."""
    import json

    from denoise.__main__ import main as denoise
    from export import Spec, export

    sequence = ROOT / "scenes" / "sequences" / "glossy_shadow.json"
    export(Spec.load(sequence, size=(16, 9), frames=4, reference_spp=2), tmp_path / "four")
    out = tmp_path / "out"
    out.mkdir()
    mine = {"notes.txt", "result_07.exr", "result_9.png", "result_\u0663.exr", "result_8.EXR"}
    for name in mine:  # made before any run: not results of one, whatever their names
        (out / name).write_text("mine")
    assert denoise([str(tmp_path / "four"), str(out), "--png"]) == 0
    assert capsys.readouterr().err == ""  # no run was recorded there: nothing removed
    record = json.loads((out / "denoise_results.json").read_text())
    assert sorted(record["files"]) == sorted(f"result_{i}.{e}" for i in range(4) for e in ("exr", "png"))
    (out / "result_3.png").write_text("mine now")  # a result the user replaced is theirs
    if second == "fewer frames":
        export(Spec.load(sequence, size=(16, 9), frames=2, reference_spp=2), tmp_path / "two")
        assert denoise([str(tmp_path / "two"), str(out)]) == 0
    else:
        (tmp_path / "four" / "beauty_2.exr").write_bytes(b"not an EXR")
        assert denoise([str(tmp_path / "four"), str(out)]) == 2
    err = capsys.readouterr().err
    assert {p.name for p in out.iterdir()} == {"result_0.exr", "result_1.exr", "result_3.png",
                                               "denoise_results.json"} | mine
    assert sorted(json.loads((out / "denoise_results.json").read_text())["files"]) == ["result_0.exr", "result_1.exr"]
    if second == "fewer frames":
        assert err == ("python -m denoise: note: 5 result files of the last run into "
                       f"{out}, which this run did not replace, removed\n"), err


def test_a_stop_signal_just_after_a_results_rename_records_it(variant_llvm_ad_rgb, exported, tmp_path, monkeypatch):
    """A stop signal's exception can come between a result's rename into place and
    ``write_exr``'s return: the run still records that result as its own (the next
    run removes it as the last run's), as it does a result written before the signal."""
    import json

    from core.entry import Interrupted
    from denoise import pipeline
    from denoise.methods import make

    real = pipeline.write_exr

    def renamed_then_stopped(path, layers):
        real(path, layers)
        raise Interrupted(signal.SIGTERM)

    monkeypatch.setattr(pipeline, "write_exr", renamed_then_stopped)
    out = tmp_path / "out"
    with pytest.raises(Interrupted):
        pipeline.denoise_folder(exported, out, make("bilateral"))
    assert sorted(p.name for p in out.iterdir()) == ["denoise_results.json", "result_0.exr"]
    assert list(json.loads((out / "denoise_results.json").read_text())["files"]) == ["result_0.exr"]


def test_the_record_is_kept_frame_by_frame(variant_llvm_ad_rgb, exported, tmp_path):
    """After each frame the record lists this run's results so far and the last run's
    that it has not replaced: a run that the watchdog ends after a stop signal (no
    clean-up: the process exits from another thread) leaves the next run all of them."""
    import json

    from denoise import pipeline
    from denoise.methods import make

    out = tmp_path / "out"
    pipeline.denoise_folder(exported, out, make("bilateral"))
    first = json.loads((out / pipeline.RESULTS_RECORD).read_text())["files"]
    seen = []
    pipeline.denoise_folder(exported, out, make("bilateral"), on_frame=lambda index, frame, result: seen.append(
        json.loads((out / pipeline.RESULTS_RECORD).read_text())["files"]))
    assert seen[0] == first  # frame 0's result written, not yet recorded
    assert sorted(seen[1]) == ["result_0.exr", "result_1.exr"]  # frame 0's, then the last run's frame 1
    assert seen[1]["result_0.exr"] != first["result_0.exr"] and seen[1]["result_1.exr"] == first["result_1.exr"]


def test_a_second_run_into_a_busy_out_dir_is_refused(variant_llvm_ad_rgb, exported, tmp_path, capsys):
    """Two runs of python -m denoise into one OUT_DIR at once: the second is refused in
    one line (each would take the other's results for a last run's)."""
    from denoise.__main__ import main as denoise
    from export.files import locked

    out = tmp_path / "out"
    with locked([out], doing="denoise"):  # as a run in progress holds it
        assert denoise([str(exported), str(out)]) == 2
    assert capsys.readouterr().err == (f"python -m denoise: error: {out}: another denoise is writing into this "
                                       "folder; wait for it to finish, or denoise into another folder\n")
    assert not list(out.glob("result_*"))


@pytest.mark.parametrize("place", ["folder as the last frame's EXR", "folder as the last frame's PNG",
                                   "read-only last EXR"])
def test_a_result_that_cannot_be_written_is_found_before_the_first_frame(variant_llvm_ad_rgb, exported,
                                                                         tmp_path, capsys, place):
    """A folder (or a read-only file) where the last frame's result goes is one line
    before any frame is denoised, not an error after all the frames before it."""
    from denoise.__main__ import main as denoise
    from export.frames import frame_indices

    out, last = tmp_path / "out", frame_indices(exported)[-1]
    out.mkdir()
    blocked = out / f"result_{last}.{'png' if 'PNG' in place else 'exr'}"
    if place.startswith("folder"):
        blocked.mkdir()
    else:
        blocked.write_text("mine")
        blocked.chmod(0o444)
    assert denoise([str(exported), str(out), "--png"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"OUT_DIR {blocked}: " in err, err
    assert not [p for p in out.iterdir() if p != blocked]


def test_a_run_stopped_before_its_first_result_leaves_no_out_dir(variant_llvm_ad_rgb, exported, tmp_path, capsys):
    """An OUT_DIR the run made goes again when the run ends before its first result
    (here the first frame turns out damaged); one that was there stays."""
    from denoise.__main__ import main as denoise

    (exported / "beauty_0.exr").write_bytes(b"not an EXR")
    out = tmp_path / "new" / "out"
    assert denoise([str(exported), str(out)]) == 2
    assert capsys.readouterr().err.count("\n") == 1
    assert not out.exists() and not out.parent.exists()  # nor the parent the run made for it
    out.mkdir(parents=True)
    assert denoise([str(exported), str(out)]) == 2
    assert out.is_dir() and not list(out.iterdir())
