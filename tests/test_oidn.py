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
