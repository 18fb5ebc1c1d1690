"""The renderer's robustness: no silently wrong image, no crash after the
work, no non-finite output, Ctrl-C that stops, many lights without a compile cliff.

- Far lights and far objects: images equal the well-scaled equivalents within
  the course-image bar (secondary-ray offsets follow the hit object only).
- AOVs are the first hit of the pixel-centre ray, never averaged: ids stay
  integers under -jitter and -filter.
- Empty scenes, lights too bright for float32 and the scalar variant's
  --stats finish with finite images.
- Large renders are split into launches (same image), so Ctrl-C exits in ~1 s.
- Many lights are a symbolic loop (same image as unrolled), 1000 compile fast.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from helpers import MAX_BAD_FRACTION, bad_fraction, encode

from converters.course_scene import parse_scene
from converters.description import RenderOptions, scene_dict
from converters.render_flags import RenderJob
from converters.to_mitsuba import load_scene_dict
from renderer.job import render
from renderer.launches import pixel_order, render_in_launches
from validation.stress.scene import DEFAULTS, scaled, scene as scene_text
from validation.stress.system import wait_for_handler

ROOT = Path(__file__).resolve().parent.parent
SIZE = (96, 72)
FLAGS = dict(bounces=2, shadows=True)
NEAR_LIGHT = "PointLight { position 1 3 2 color 1 1 1 falloff 0.2 }"


def sun(distance: float) -> str:
    """A point light ``distance`` away along (1, 3, 2), as bright here as a directional light of 0.7."""
    position = np.array([1.0, 3.0, 2.0]) / np.sqrt(14.0) * distance
    falloff = 1.0 / (0.7 * float(position @ position))
    return "PointLight {{ position {:.9g} {:.9g} {:.9g} color 1 1 1 falloff {:.9g} }}".format(*position, falloff)


DIRECTIONAL_SUN = "DirectionalLight { direction -1 -3 -2 color 0.7 0.7 0.7 }"
OBJECTS = DEFAULTS["objects"]


def with_objects(extra: str, count: int = 1) -> str:
    return scene_text(num_objects=3 + count, objects=OBJECTS + " " + extra)


def beauty(scene, size=SIZE, **options) -> np.ndarray:
    import mitsuba as mi

    opts = RenderOptions(width=size[0], height=size[1], **{**FLAGS, **options})
    return encode(np.array(mi.render(load_scene_dict(scene_dict(scene, opts))), np.float32)[..., :3])


def parsed(text: str):
    return parse_scene(text, Path("scene.txt"))


# -- far lights and far objects ------------------------------------------------
#: Looking down: no horizon in view, where the floor is as far away as a near "sun"
DOWN = "0 -0.5 -1"
EQUIVALENTS = {
    # a sun-like point light: today's offset grew with it and shadows vanished
    "sun 3742 away": (scene_text(direction=DOWN, lights=f"{sun(3742.0)} {NEAR_LIGHT}"),
                      scene_text(direction=DOWN, lights=f"{DIRECTIONAL_SUN} {NEAR_LIGHT}")),
    "sun 1e6 away": (scene_text(lights=f"{sun(1e6)} {NEAR_LIGHT}"),
                     scene_text(lights=f"{DIRECTIONAL_SUN} {NEAR_LIGHT}")),
    # a small sphere far away, out of view
    "small sphere 1e4 away": (with_objects("MaterialIndex 0 Sphere { center 10000 0 0 radius 0.1 }"), scene_text()),
    # a large sphere far away under the floor (hidden by it)
    "large sphere under the floor": (with_objects("MaterialIndex 1 Sphere { center 0 -10000 0 radius 100 }"),
                                     scene_text()),
}


@pytest.mark.parametrize("name", EQUIVALENTS)
def test_far_lights_and_objects_change_nothing(variant_llvm_ad_rgb, name):
    text, equivalent = EQUIVALENTS[name]
    ours, expected = beauty(parsed(text)), beauty(parsed(equivalent))
    bad = bad_fraction(ours, expected)
    print(f"{name}: {100 * bad:.2f}% of pixels differ by > 2/255")
    assert bad <= MAX_BAD_FRACTION


def test_mixed_scales(variant_llvm_ad_rgb):
    """The scene shrunk 1000x beside a sphere of the original size 1e3 away (hidden
    under the floor): the small scene's image is that of the small scene alone."""
    small = scaled(parsed(scene_text()), 1e-3, 0.0)
    big = parsed(with_objects("MaterialIndex 1 Sphere { center 0 -1000 0 radius 1 }"))
    mixed = scaled(parsed(scene_text()), 1e-3, 0.0)
    mixed.objects.append(big.objects[-1])
    bad = bad_fraction(beauty(mixed), beauty(small))
    print(f"mixed scales: {100 * bad:.2f}% of pixels differ by > 2/255")
    assert bad <= MAX_BAD_FRACTION


def test_shadows_of_a_far_sun_show(variant_llvm_ad_rgb):
    text = scene_text(direction=DOWN, lights=sun(3742.0), num_lights=1)
    assert bad_fraction(beauty(parsed(text)), beauty(parsed(text), shadows=False)) > 0.01


def test_a_wrong_equivalent_fails(variant_llvm_ad_rgb):
    """The comparison bites: a sun from another direction is not equivalent."""
    other = scene_text(lights=f"DirectionalLight {{ direction -1 -3 2 color 0.7 0.7 0.7 }} {NEAR_LIGHT}")
    assert bad_fraction(beauty(parsed(EQUIVALENTS["sun 3742 away"][0])), beauty(parsed(other))) > MAX_BAD_FRACTION


# -- AOVs: the pixel-centre ray's, never averaged ---------------------------------
@pytest.fixture
def scene_file(tmp_path) -> Path:
    path = tmp_path / "scene.txt"
    path.write_text(scene_text())
    return path


@pytest.mark.parametrize("flags", [dict(jitter=True), dict(jitter=True, spp=5), dict(filter=True),
                                   dict(jitter=True, filter=True)], ids=["jitter", "spp5", "filter", "both"])
def test_aovs_are_never_averaged(variant_llvm_ad_rgb, scene_file, tmp_path, flags):
    job = RenderJob(scene=scene_file, width=40, height=30, exr=tmp_path / "x.exr", **FLAGS, **flags)
    layers = render(job).layers
    ids = layers["id"]
    assert set(np.unique(ids)) <= {-1.0, 0.0, 1.0, 2.0}, np.unique(ids)
    assert (ids == -1).any() and (ids >= 0).any()
    hit = ids >= 0
    assert np.allclose(np.linalg.norm(layers["normal"][hit], axis=-1), 1.0, atol=1e-5)
    # the same AOVs as without jitter: the pixel-centre rays
    plain = render(RenderJob(scene=scene_file, width=40, height=30, exr=tmp_path / "x.exr", **FLAGS,
                             filter=flags.get("filter", False))).layers
    for name in ("depth", "normal", "position", "albedo", "id"):
        np.testing.assert_array_equal(layers[name], plain[name], err_msg=name)
    # the beauty is still averaged
    assert not np.array_equal(layers[""], plain[""]) or not flags.get("jitter")


# -- finite output, no crash after the work -------------------------------------
def test_empty_scene_with_every_aov(variant_llvm_ad_rgb, tmp_path):
    path = tmp_path / "empty.txt"
    path.write_text(scene_text(num_objects=0, objects=""))
    layers = render(RenderJob(scene=path, width=16, height=12, exr=tmp_path / "x.exr", **FLAGS)).layers
    assert (layers["id"] == -1).all()
    assert all(np.isfinite(v).all() for v in layers.values())
    np.testing.assert_allclose(layers[""], np.broadcast_to([0.1, 0.2, 0.3], layers[""].shape))


@pytest.mark.parametrize("intensity", [1e39, 3e38, 1e30])
def test_lights_too_bright_for_float32_give_finite_images(variant_llvm_ad_rgb, intensity):
    import mitsuba as mi

    description = scene_dict(parsed(scene_text()), RenderOptions(width=24, height=18, aovs=("depth", "id"),
                                                                 **FLAGS))
    for key in ("light_0", "light_1"):
        light = description[key]
        field = "intensity" if "intensity" in light else "irradiance"
        light[field] = {"type": "rgb", "value": [intensity] * 3}
    scene = load_scene_dict(description)
    for image in (render_image(scene), np.array(mi.render(scene), np.float32)):
        assert np.isfinite(image).all()
        assert image[..., :3].max() > 1e20  # bright, not zeroed


# -- launches: Ctrl-C between them, the same image however split -----------------
def test_launches_give_the_same_image(variant_vectorised_rgb):
    scene = load_scene_dict(scene_dict(parsed(scene_text()), RenderOptions(width=33, height=17, aovs=("id",),
                                                                            jitter=True, **FLAGS)))
    whole = render_in_launches(scene, 4, True)
    for launch in (4 * 37, 4 * 100, 1000):
        np.testing.assert_array_equal(render_in_launches(scene, 4, True, launch_samples=launch), whole)
    assert not np.array_equal(render_in_launches(scene, 4, True, seed=1), whole)  # the jitter is live
    # parts of one pixel's samples per launch (a pixel that is more work than a launch), summed in float64
    small = load_scene_dict(scene_dict(parsed(scene_text()), RenderOptions(width=5, height=3, aovs=("id",),
                                                                            jitter=True, **FLAGS)))
    whole = render_in_launches(small, 8, True)
    for launch in (3, 5):
        np.testing.assert_allclose(render_in_launches(small, 8, True, launch_samples=launch), whole, rtol=1e-6,
                                   atol=1e-7)


def test_the_pixel_order_visits_every_pixel_once_and_interleaved():
    for pixels in (1, 31, 32, 33, 1000, 64 * 64 + 5):
        order = pixel_order(0, pixels, pixels)
        assert sorted(order.tolist()) == list(range(pixels))
        np.testing.assert_array_equal(np.concatenate([pixel_order(k, 7, pixels) for k in range(0, pixels, 7)])
                                      [:pixels], order)
    first = pixel_order(0, 4096 // 8, 4096)  # an eighth of the launches' pixels ...
    assert np.ptp(first) > 4096 * 3 // 4  # ... spread over the whole image


def test_one_sample_renders_as_mitsuba_does(variant_vectorised_rgb):
    """Pixel-centre renders equal mi.render's (except where Mitsuba's film puts a
    sample on a pixel border into the neighbour: a handful of pixels)."""
    import mitsuba as mi

    scene = load_scene_dict(scene_dict(parsed(scene_text()), RenderOptions(width=64, height=48, **FLAGS)))
    ours, theirs = render_in_launches(scene, 1, False), np.array(mi.render(scene), np.float32)
    assert np.mean(np.any(ours != theirs, axis=-1)) < 0.002


@pytest.mark.timed
def test_ctrl_c_stops_a_long_render(variant_llvm_ad_rgb, tmp_path):
    """A render that needs well over a minute gets SIGINT 8 s after its start (it is
    rendering by then): it exits with 130 within 2 s."""
    scene = ROOT / "scenes" / "mirrors.txt"
    out = tmp_path / "out"
    out.mkdir()
    command = [sys.executable, str(ROOT / "render.py"), "-input", str(scene), "-size", "1024", "1024",
               "-bounces", "4", "-shadows", "-jitter", "--spp", "256", "--variant", variant_llvm_ad_rgb,
               "-output", str(out / "long.png")]
    process = subprocess.Popen(command, env=dict(os.environ, PYTHONPATH=str(ROOT)), stderr=subprocess.PIPE)
    stderr = []
    reader = threading.Thread(target=lambda: stderr.extend(iter(lambda: os.read(process.stderr.fileno(), 4096),
                                                                  b"")), daemon=True)
    reader.start()
    started = time.perf_counter()
    try:
        # the launches have begun after start-up and the first kernel's compilation (~2-3 s
        # on a quiet machine; no progress bar to watch: stderr is not a terminal here)
        while time.perf_counter() - started < 8.0:
            assert process.poll() is None, b"".join(stderr).decode()
            time.sleep(0.05)
        process.send_signal(signal.SIGINT)
        sent = time.perf_counter()
        process.wait(timeout=60)
        seconds = time.perf_counter() - sent
    finally:
        process.kill()
    reader.join(timeout=5)
    text = b"".join(stderr).decode(errors="replace")
    print(f"SIGINT {sent - started:.1f} s after the start; exited {seconds:.2f} s later, code {process.returncode}")
    assert process.returncode == 130, text
    assert seconds <= 2.0
    assert "Traceback" not in text and "interrupted" in text.splitlines()[-1], text
    assert list(out.iterdir()) == []  # no output, no temporary file


def test_an_integrator_follows_the_scene_it_renders(variant_llvm_ad_rgb):
    """The integrator's per-scene analysis (lights, tables) is not reused for another scene."""
    import mitsuba as mi

    options = RenderOptions(width=24, height=18, **FLAGS)
    first = load_scene_dict(scene_dict(parsed(scene_text()), options))
    second = load_scene_dict(scene_dict(parsed(scene_text(lights=f"{DIRECTIONAL_SUN} {NEAR_LIGHT}")), options))
    integrator = first.integrator()
    mi.render(first, integrator=integrator)
    np.testing.assert_array_equal(np.array(mi.render(second, integrator=integrator)), np.array(mi.render(second)))


# -- many lights -----------------------------------------------------------------
def many_lights(count: int) -> str:
    rng = np.random.default_rng(1)
    lights = " ".join(
        f"PointLight {{ position {x:.3f} {3 + y:.3f} {z:.3f} color 0.3 0.3 0.3 falloff {0.5 * count:g} }}" if k % 2
        else f"DirectionalLight {{ direction {x:.3f} -1 {z:.3f} color {0.5 / count:g} {0.5 / count:g} 0.01 }}"
        for k, (x, y, z) in enumerate(rng.uniform(-2, 2, (count, 3))))
    return scene_text(num_lights=count, lights=lights)


def render_image(scene) -> np.ndarray:
    """One sample at each pixel centre: the project's launches in a JIT variant,
    ``mi.render`` in a scalar one (which renders in bands, never in launches)."""
    import drjit as dr
    import mitsuba as mi

    if dr.is_jit_v(mi.Float):
        return render_in_launches(scene, 1, False)
    return np.array(mi.render(scene), np.float32)


def render_lights(text: str, unrolled: int, size=(48, 36), stats=False):

    description = scene_dict(parsed(text), RenderOptions(width=size[0], height=size[1], stats=stats, **FLAGS))
    description["integrator"]["max_unrolled_lights"] = unrolled
    scene = load_scene_dict(description)
    image = render_image(scene)
    return image, (scene.integrator().ray_counts() if stats else None)


@pytest.mark.parametrize("count", [3, 12])
def test_light_loop_equals_unrolled_lights(variant_llvm_ad_rgb, count):
    text = many_lights(count)
    looped, looped_counts = render_lights(text, 0, stats=True)
    unrolled, unrolled_counts = render_lights(text, 100, stats=True)
    assert looped[..., :3].max() > 0.1
    np.testing.assert_allclose(looped, unrolled, rtol=1e-5, atol=1e-6)
    assert looped_counts == unrolled_counts


def test_light_loop_misses_no_light(variant_llvm_ad_rgb):
    """The comparison above bites: one light fewer is visible."""
    looped, _ = render_lights(many_lights(12), 0)
    fewer = many_lights(12).replace("numLights 12", "numLights 11")
    fewer = fewer[:fewer.rindex("PointLight")] + "}" + fewer[fewer.index("Background") - 1:]
    unrolled, _ = render_lights(fewer, 100)
    assert np.abs(looped - unrolled).max() > 1e-3


@pytest.mark.timed
def test_thousand_lights_compile_fast(variant_vectorised_rgb):
    start = time.perf_counter()
    image, _ = render_lights(many_lights(1000), 8, size=(32, 32))
    seconds = time.perf_counter() - start
    print(f"1000 lights, 32x32, bounces 2, shadows: {seconds:.2f} s (load, compile, render)")
    assert np.isfinite(image).all() and image[..., :3].max() > 0.1
    assert seconds <= 10.0


# -- the scalar variant ------------------------------------------------------------
@pytest.mark.slow
def test_scalar_stats_in_bands(variant_scalar_rgb):
    """--stats with scalar_rgb renders in worker processes and adds their counts
    (it used to raise KeyError: 'mirror_by_depth' after the whole render)."""
    from renderer import bands

    description = scene_dict(parsed(scene_text()), RenderOptions(width=16, height=12, stats=True, **FLAGS))
    image, counts = bands.render_in_bands(description, "scalar_rgb", workers=2)
    assert np.isfinite(image).all()
    assert counts["camera"] == 16 * 12 and len(counts["mirror_by_depth"]) == FLAGS["bounces"]
    assert counts["shadow"] > 0


@pytest.mark.slow
def test_scalar_ids_under_jitter(variant_scalar_rgb, scene_file, tmp_path):
    layers = render(RenderJob(scene=scene_file, width=12, height=9, exr=tmp_path / "x.exr", jitter=True, spp=2,
                              **FLAGS)).layers
    assert set(np.unique(layers["id"])) <= {-1.0, 0.0, 1.0, 2.0}


def test_depth_images_are_clamped_and_black_where_nothing_is_hit(tmp_path, monkeypatch):
    """README: (t - MIN) / (MAX - MIN), clamped, black where nothing is hit, for
    every format and also for an inverted ramp (MIN > MAX): misses used to be
    white with MIN > MAX, and an .exr held unclamped values (misses -MIN/(MAX-MIN))."""
    import renderer.cli as cli
    from imaging.image_io import read_exr, read_png

    # the sky fills the top rows: no hit there
    (tmp_path / "s.txt").write_text(scene_text(center="0 1 6", direction="0 0.3 -1"))
    monkeypatch.chdir(tmp_path)
    for near, far in [(2, 9), (9, 2), (6.5, 7), (20, 30)]:
        for name in ("d.exr", "d.png"):
            assert cli.main(["-input", "s.txt", "-size", "24", "18", "--quiet",
                             "-depth", str(near), str(far), name]) == 0
        depth = read_exr("d.exr")["R"]
        grey = read_png("d.png")[..., 0]
        assert depth.min() >= 0.0 and depth.max() <= 1.0, (near, far, depth.min(), depth.max())
        assert np.all(depth[0] == 0.0) and np.all(grey[0] == 0), (near, far)  # the sky row
        assert np.abs(np.floor(depth * 255.0) - grey).max() <= 1, (near, far)  # .png and .exr agree
    # the inverted ramp: what is near is bright, and something is hit
    assert cli.main(["-input", "s.txt", "-size", "24", "18", "--quiet", "-depth", "9", "2", "d.exr"]) == 0
    assert read_exr("d.exr")["R"].max() > 0.3


#: Delays at which the start-up test sends its signals, counted from when
#: render.py's handlers are in place (:func:`wait_for_handler`): the
#: imports, Dr.Jit's initialisation (where SIGTERM used to give a 60-line
#: ImportError / SystemError traceback and a signal inside the import of its
#: extension aborted the process), the render and the interpreter's teardown.
START_UP_DELAYS = (0.0, 0.15, 0.55, 0.85, 1.25, 1.65, 2.05)


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_signal_in_any_phase_of_start_up_keeps_the_contract(tmp_path, signum):
    """Finished first (0), or one line and 128 + signum; never a traceback, an
    abort or a temporary file left behind."""
    outcomes = []
    for delay in START_UP_DELAYS:
        out = tmp_path / f"{delay}"
        out.mkdir()
        process = subprocess.Popen([sys.executable, str(ROOT / "render.py"), "scene03", "-size", "48", "48",
                                    "--out", str(out)], cwd=out, stdout=subprocess.PIPE,
                                   stderr=subprocess.PIPE, text=True)
        wait_for_handler(process)
        time.sleep(delay)
        process.send_signal(signum)
        _, stderr = process.communicate(timeout=120)
        lines = stderr.strip().splitlines()
        outcomes.append((delay, process.returncode))
        assert process.returncode in (0, 128 + signum), (delay, process.returncode, stderr[-3000:])
        assert len(lines) <= 1, (delay, stderr[-3000:])
        if process.returncode:
            assert lines and "interrupted" in lines[0], (delay, stderr)
        assert not [p for p in out.rglob(".*")], (delay, list(out.rglob("*")))
    print(signal.Signals(signum).name, outcomes)


def test_an_interruption_that_native_code_replaced_is_an_interrupted_exit(capsys):
    """NumPy's C extension, imported while SIGINT comes, clears the handler's
    KeyboardInterrupt and raises an ImportError of its own, chaining nothing
    (a plugin constructor called from C++ does the same): the exit is still 130."""
    from core.entry import run

    def replaced():
        lost = False
        try:
            signal.raise_signal(signal.SIGINT)
        except BaseException:  # noqa: BLE001  as PyErr_Clear in C
            lost = True
        if lost:
            raise ImportError('PyCapsule_Import could not import module "datetime"')

    assert run("render.py", replaced) == 130
    assert capsys.readouterr().err.strip().splitlines() == [
        "render.py: interrupted; finished files are complete, unfinished ones were not written"]


def test_ctrl_c_in_a_plugin_constructor_during_load_dict_is_an_interrupted_exit(variant_scalar_rgb, capsys):
    """SIGINT while ``mi.load_dict`` runs a Python plugin's constructor: Mitsuba's
    factory turns the KeyboardInterrupt into a RuntimeError holding its traceback
    as text (no cause, no context); the exit is 130 with one line, not a traceback."""
    import mitsuba as mi

    from core.entry import run

    class StoppedBSDF(mi.BSDF):
        def __init__(self, props):
            super().__init__(props)
            signal.raise_signal(signal.SIGINT)  # Ctrl-C arriving while the plugin is built

    mi.register_bsdf("test_stopped_bsdf", lambda props: StoppedBSDF(props))
    scene = {"type": "scene", "ball": {"type": "sphere", "bsdf": {"type": "test_stopped_bsdf"}}}
    assert run("render.py", lambda: mi.load_dict(scene)) == 130
    assert capsys.readouterr().err.strip().splitlines() == [
        "render.py: interrupted; finished files are complete, unfinished ones were not written"]


def test_an_interruption_wrapped_by_native_code_is_an_interrupted_exit(capsys):
    """Dr.Jit's start-up turns the handler's exception into an ImportError, and
    CPython then into a SystemError: the chain still holds the interruption."""
    from core.entry import Interrupted, run

    def wrapped():
        try:
            try:
                raise Interrupted(signal.SIGTERM)
            except Interrupted as stop:
                raise ImportError("initializing the extension") from stop
        except ImportError:
            raise SystemError("<built-in function __import__> returned a result with an exception set")  # noqa: B904  as CPython: implicit context

    assert run("render.py", wrapped) == 143
    assert capsys.readouterr().err.strip().splitlines() == [
        "render.py: interrupted; finished files are complete, unfinished ones were not written"]

    def bug():
        raise ValueError("a bug keeps its traceback")

    with pytest.raises(ValueError):
        run("render.py", bug)
