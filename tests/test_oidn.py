"""OIDN as users run it: HDR mode on, one committed filter reused per size."""
from __future__ import annotations

import numpy as np
import pytest

oidn_module = pytest.importorskip("denoise.oidn")


def hdr_image(seed=0, level=20.0):
    """A bright noisy HDR image: values far above 1 (OIDN's LDR mode clips at 1)."""
    rng = np.random.default_rng(seed)
    ys, xs = np.mgrid[0:48, 0:64]
    base = level * (1.0 + 0.5 * np.sin(xs / 9.0))[..., None] * np.array([1.0, 0.8, 0.6])
    return (base * rng.uniform(0.6, 1.4, base.shape)).astype(np.float32)


def test_hdr_mode_keeps_values_above_one():
    from denoise.oidn import OIDN

    image = hdr_image()
    denoiser = OIDN()
    out = denoiser(image)
    assert denoiser.hdr  # the library reports the setting
    assert out.max() > 10.0 and abs(out.mean() / image.mean() - 1.0) < 0.05  # not clipped, energy kept
    assert out.std() < image.std()  # and it denoises


def test_the_hdr_check_fails_in_ldr_mode():
    """The same check on a filter in LDR mode (the old benchmark's setting): clipped at 1."""
    from denoise.oidn import OIDN, OIDNParams

    denoiser = OIDN(OIDNParams(hdr=False))
    out = denoiser(hdr_image())
    assert not denoiser.hdr
    assert out.max() <= 1.0 + 1e-3


def test_filter_created_once_per_size():
    from denoise.oidn import OIDN

    denoiser = OIDN()
    normal = np.tile(np.array([0, 0, 1], np.float32), (48, 64, 1))
    albedo = np.full((48, 64, 3), 0.5, np.float32)
    denoiser(hdr_image(1), albedo, normal)
    handle = denoiser.filter
    denoiser(hdr_image(2), albedo, normal)
    assert denoiser.filter == handle  # reused: only executed
    denoiser(hdr_image(3)[:32], albedo[:32], normal[:32])
    assert denoiser.key[:2] == (32, 64)  # a new size commits a new filter


def _plane_frames(count=2, h=24, w=32, seed=9):
    """Frames of a static plane whose world-to-screen matrix is the identity
    (pixel (x, y) sees the point (x + 0.5, y + 0.5, 1)): the back projection
    keeps every pixel's own history, except where the previous frame saw
    the background (id -1)."""
    from denoise.frames import FrameData

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

    from denoise.filters import reproject
    from denoise.oidn import OIDN
    from denoise.pipeline import Denoiser, parse_method
    from test_denoise import close, np_accumulate

    frames = _plane_frames()
    options = parse_method("oidn-guided")
    assert options.temporal and options.oidn_guided.clamp_radius == 1
    denoiser = Denoiser(options)
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
    p = options.oidn_guided
    for bounds, agrees in ((guide, True), (None, False)):
        accumulated = np_accumulate(f32(after.beauty).astype(np.float64), f32(before.beauty).astype(np.float64),
                                    index, valid, p.alpha, p.k, p.clamp_radius, bounds=bounds)
        reference = oidn(f32(accumulated), f32(after.albedo), f32(after.normal))
        assert (close(ours[1], reference) < 1e-4) == agrees, close(ours[1], reference)
