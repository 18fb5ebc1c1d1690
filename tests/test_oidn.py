"""OIDN 2 (pyoidn) as users run it: HDR mode on, the quality mode taking effect,
one committed filter reused per size, and bad inputs refused in one line."""
from __future__ import annotations

import time

import numpy as np
import pytest

from core.errors import FrameError, UsageError
from denoise.methods.oidn import OIDN, QUALITIES, OIDNParams


def hdr_image(seed=0, level=20.0, h=48, w=64):
    """A bright noisy HDR image: values far above 1 (OIDN's LDR mode clips at 1)."""
    rng = np.random.default_rng(seed)
    ys, xs = np.mgrid[0:h, 0:w]
    base = level * (1.0 + 0.5 * np.sin(xs / 9.0))[..., None] * np.array([1.0, 0.8, 0.6])
    return (base * rng.uniform(0.6, 1.4, base.shape)).astype(np.float32)


def guides(h=48, w=64):
    """Clean albedo and normals (a grey plane facing the camera)."""
    return np.full((h, w, 3), 0.5, np.float32), np.tile(np.array([0, 0, 1], np.float32), (h, w, 1))


def test_hdr_mode_keeps_values_above_one():
    image = hdr_image()
    denoiser = OIDN()
    out = denoiser(image)
    assert denoiser.hdr  # the library reports the setting
    assert out.max() > 10.0 and abs(out.mean() / image.mean() - 1.0) < 0.05  # not clipped, energy kept
    assert out.std() < image.std()  # and it denoises


def test_hdr_output_scales_with_the_input():
    """Radiance x100 gives an output x100 (to 1 %): an LDR filter clips the
    bright one at 1 (its ratio is about 6, see the next test)."""
    dim = hdr_image(3, level=0.2)
    denoiser = OIDN()
    ratio = denoiser(100.0 * dim).mean() / denoiser(dim).mean()
    assert abs(ratio / 100.0 - 1.0) < 0.01, ratio


def test_the_hdr_checks_fail_in_ldr_mode():
    """The same checks on a filter in LDR mode (the old benchmark's setting): clipped at 1."""
    denoiser = OIDN(OIDNParams(hdr=False))
    out = denoiser(hdr_image())
    assert not denoiser.hdr
    assert out.max() <= 1.0 + 1e-3
    dim = hdr_image(3, level=0.2)
    assert denoiser(100.0 * dim).mean() / denoiser(dim).mean() < 10.0


@pytest.mark.parametrize("quality", sorted(QUALITIES))
def test_quality_mode_is_set_on_the_filter(quality):
    denoiser = OIDN(OIDNParams(quality=quality))
    denoiser(hdr_image(), *guides())
    assert denoiser.quality == quality  # read back from the library


@pytest.mark.timed
def test_fast_and_high_are_different_networks():
    """With albedo and normals, ``high`` runs OIDN 2's large network: a different
    output from ``fast`` on the same input, and a slower execute."""
    image, (albedo, normal) = hdr_image(4, h=96, w=128), guides(96, 128)
    outputs, seconds = {}, {}
    for quality in ("fast", "high"):
        denoiser = OIDN(OIDNParams(quality=quality))
        denoiser.set_inputs(image, albedo, normal)
        denoiser.execute()  # warm-up
        start = time.perf_counter()
        denoiser.execute()
        seconds[quality] = time.perf_counter() - start
        outputs[quality] = denoiser.output()
    difference = np.abs(outputs["fast"] - outputs["high"]).mean() / outputs["high"].mean()
    assert difference > 0.01, difference
    assert seconds["high"] > seconds["fast"], seconds


def test_an_unknown_quality_is_one_line():
    with pytest.raises(UsageError, match=r"^unknown OIDN quality 'best'; choose from fast, balanced, high$"):
        OIDNParams(quality="best")


def test_filter_committed_once_per_size():
    """Frames of one size reuse the committed filter (only executed), and its output
    is the frame's own: the same as a fresh filter's on that frame."""
    denoiser = OIDN()
    albedo, normal = guides()
    denoiser(hdr_image(1), albedo, normal)
    handle = denoiser.filter
    second = denoiser(hdr_image(2), albedo, normal)
    assert denoiser.filter is handle  # reused
    assert np.array_equal(second, OIDN()(hdr_image(2), albedo, normal))
    denoiser(hdr_image(3)[:32], albedo[:32], normal[:32])
    assert denoiser.filter is not handle and denoiser.key[:2] == (32, 64)  # a new size commits a new filter


@pytest.mark.parametrize("color, albedo, message", [
    (np.zeros((0, 64, 3), np.float32), None, r"non-empty \(height, width, 3\) colour image, got shape \(0, 64, 3\)"),
    (np.zeros((48, 64), np.float32), None, r"got shape \(48, 64\)"),
    (np.zeros((48, 64, 3), np.float32), np.zeros((48, 32, 3), np.float32),
     r"the albedo image has shape \(48, 32, 3\), the colour \(48, 64, 3\)"),
])
def test_bad_inputs_are_refused_in_one_line(color, albedo, message):
    with pytest.raises(FrameError, match=message) as error:
        OIDN().set_inputs(color, albedo)
    assert "\n" not in str(error.value)


def _plane_frames(count=2, h=24, w=32, seed=9):
    """Frames of a static plane whose world-to-screen matrix is the identity
    (pixel (x, y) sees the point (x + 0.5, y + 0.5, 1)): the back projection
    keeps every pixel's own history, except where the previous frame saw
    the background (id -1)."""
    from export.frames import FrameData

    rng = np.random.default_rng(seed)
    ys, xs = np.mgrid[0:h, 0:w]
    position = np.stack([xs + 0.5, ys + 0.5, np.ones((h, w))], -1)
    normal = np.tile(np.array([0.0, 0.0, 1.0]), (h, w, 1))
    albedo = np.full((h, w, 3), 0.6)
    frames = []
    for i in range(count):
        clean = hdr_image(seed + i, level=2.0)[:h, :w].astype(np.float64)
        clean[:, : w // 3 + 4 * i] *= 0.2  # a shadow edge that moves by 4 pixels per frame
        ids = np.zeros((h, w), np.int32)
        if i == 0:
            ids[:4, :6] = -1
        frames.append(FrameData(clean * rng.uniform(0.2, 1.8, clean.shape), normal, position, np.ones((h, w)), ids,
                                [np.eye(4)], np.eye(4), np.eye(4), albedo))
    return frames


def test_oidn_guided_matches_numpy(variant_vectorised_rgb):
    """oidn-guided = OIDN(accumulate(input, history clamped to the 3x3 mean ± kσ of
    OIDN(input))), with NumPy doing the accumulation and a second OIDN filter the
    denoising; the same test with the clamp taken from the input (the guide step
    skipped) misses by far more than the tolerance."""
    import mitsuba as mi
    from test_denoise import close, np_accumulate

    from denoise.filters import reproject
    from denoise.methods import from_name

    frames = _plane_frames()
    denoiser = from_name("oidn-guided")
    assert denoiser.temporal and denoiser.temporal_params.clamp_radius == 1
    ours = [denoiser.step(f) for f in frames]
    assert denoiser.last_execute_s > 0.0  # both runs timed

    def tensor(a):
        return mi.TensorXf(np.ascontiguousarray(a, np.float32))

    before, after = frames
    index, valid = reproject(tensor(after.position), tensor(after.ids), tensor(before.ids), after.object_to_world,
                             before.object_to_world, before.world_to_screen)
    index, valid = np.array(index), np.array(valid, bool)
    assert 0.9 < valid.mean() < 1.0  # some pixels start over
    oidn = OIDN()
    f32 = lambda a: np.asarray(a, np.float32)  # noqa: E731 (what the pipeline hands OIDN)
    assert close(ours[0], oidn(f32(before.beauty), f32(before.albedo), f32(before.normal))) < 1e-4
    guide = oidn(f32(after.beauty), f32(after.albedo), f32(after.normal)).astype(np.float64)
    p = denoiser.temporal_params
    for bounds, agrees in ((guide, True), (None, False)):
        accumulated = np_accumulate(f32(after.beauty).astype(np.float64), f32(before.beauty).astype(np.float64),
                                    index, valid, p.alpha, p.k, p.clamp_radius, bounds=bounds)
        reference = oidn(f32(accumulated), f32(after.albedo), f32(after.normal))
        assert (close(ours[1], reference) < 1e-4) == agrees, close(ours[1], reference)
