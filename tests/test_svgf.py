"""SVGF, outlier removal and albedo demodulation against NumPy implementations of the same maths."""
from __future__ import annotations

import numpy as np
import pytest
from test_denoise import B3, buffers_fixture, close, np_normalize, shifted, tensors  # noqa: F401 (the fixture "buffers")

LUM = np.array([0.2126, 0.7152, 0.0722])


# -- the NumPy reference ------------------------------------------------------------
def np_outliers(c, k, r):
    lum = c @ LUM
    total, square, count = np.zeros(lum.shape), np.zeros(lum.shape), np.zeros(lum.shape)
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            lj, inside = shifted(lum, dx, dy)
            total += np.where(inside, lj, 0)
            square += np.where(inside, lj * lj, 0)
            count += inside
    mean = total / count
    sigma = np.sqrt(np.maximum(square / count - mean ** 2, 0))
    clamped = np.clip(lum, mean - k * sigma, mean + k * sigma)
    scale = np.where(lum > 0, clamped / np.where(lum > 0, lum, 1), 1)
    return c * scale[..., None]


def np_plane(n, x, xj, k_plane):
    return ((n * np_normalize(xj - x)).sum(-1) ** 2) * k_plane


def np_svgf(c, n, x, p, history=None, index=None, valid=None):
    """One SVGF frame; ``history`` = (colour, moments, length) arrays of the previous frame."""
    h, w = c.shape[:2]
    n = np_normalize(n)
    k_plane = 1 / (2 * p.sigma_plane ** 2)
    lum = c @ LUM
    moments = np.stack([lum, lum * lum], -1)
    length = np.ones((h, w))
    if history is not None:
        v = valid.reshape(h, w)
        pc = history[0].reshape(-1, 3)[index].reshape(h, w, 3)
        pm = history[1].reshape(-1, 2)[index].reshape(h, w, 2)
        pl = history[2].reshape(-1)[index].reshape(h, w)
        length = np.where(v, pl + 1, 1)
        ac = np.where(v, np.maximum(p.alpha_color, 1 / length), 1)[..., None]
        am = np.where(v, np.maximum(p.alpha_moments, 1 / length), 1)[..., None]
        c = np.where(v[..., None], pc + (c - pc) * ac, c)
        moments = np.where(v[..., None], pm + (moments - pm) * am, moments)
    # variance
    temporal = np.maximum(moments[..., 1] - moments[..., 0] ** 2, 0)
    total, weights = np.zeros((h, w, 2)), np.zeros((h, w))
    r = p.spatial_radius
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            mj, inside = shifted(moments, dx, dy)
            if dx == 0 and dy == 0:
                wt = np.ones((h, w))
            else:
                nj, _ = shifted(n, dx, dy)
                xj, _ = shifted(x, dx, dy)
                wt = np.maximum((n * nj).sum(-1), 0) ** p.normal_exponent * np.exp(-np_plane(n, x, xj, k_plane))
                wt = np.where(inside, wt, 0)
            total += wt[..., None] * mj
            weights += wt
    sm = total / weights[..., None]
    spatial = np.maximum(sm[..., 1] - sm[..., 0] ** 2, 0) * (p.variance_frames / length)
    var = np.where(length < p.variance_frames, spatial, temporal)
    feedback = c
    for level in range(p.levels):
        step = 1 << level
        blurred = np.zeros((h, w))
        g = [0.25, 0.5, 0.25]
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                ys = np.clip(np.arange(h) + dy, 0, h - 1)
                xs = np.clip(np.arange(w) + dx, 0, w - 1)
                blurred += g[dx + 1] * g[dy + 1] * var[ys][:, xs]
        scale = 1 / (p.sigma_luminance * np.sqrt(np.maximum(blurred, 0)) + 1e-10)
        lp = c @ LUM
        tc, tw, tv = np.zeros_like(c), np.zeros((h, w)), np.zeros((h, w))
        for j in range(5):
            for i in range(5):
                dx, dy = (i - 2) * step, (j - 2) * step
                cj, inside = shifted(c, dx, dy)
                vj, _ = shifted(var, dx, dy)
                if dx == 0 and dy == 0:
                    wt = np.full((h, w), B3[i] * B3[j])
                else:
                    nj, _ = shifted(n, dx, dy)
                    xj, _ = shifted(x, dx, dy)
                    wt = (B3[i] * B3[j] * np.maximum((n * nj).sum(-1), 0) ** p.normal_exponent
                          * np.exp(-np.abs(lp - cj @ LUM) * scale - np_plane(n, x, xj, k_plane)))
                    wt = np.where(inside, wt, 0)
                tc += wt[..., None] * cj
                tw += wt
                tv += wt * wt * vj
        c, var = tc / tw[..., None], tv / tw ** 2
        if level == p.feedback_level:
            feedback = c
    return c, (feedback, moments, length), var


def svgf_ours(c, n, x, p, history=None, index=None, valid=None):
    import mitsuba as mi

    from denoise.filters import FrameArrays
    from denoise.methods.svgf import svgf

    frame = FrameArrays(*tensors(c, n, x))
    if index is not None:
        index, valid = mi.UInt32(index.astype(np.uint32)), mi.Bool(valid)
    result, state, var = svgf(frame, p, history, index, valid)
    return np.array(result), state, np.array(var).reshape(c.shape[:2])


# -- tests ---------------------------------------------------------------------------
def test_outlier_removal_matches_numpy(variant_llvm_ad_rgb, buffers):
    from denoise.filters import OutlierParams, remove_outliers

    c = buffers[0]
    ours = np.array(remove_outliers(tensors(c)[0], OutlierParams(k=1.5, radius=3)))
    reference = np_outliers(c, 1.5, 3)
    assert close(ours, reference) < 1e-4
    # it removes fireflies: the brightest pixel comes down, most pixels barely move
    assert ours.max() < c.max()
    lum, clean = c @ LUM, reference @ LUM
    assert np.median(np.abs(clean - lum) / np.maximum(lum, 1e-2)) < 0.2


def test_outlier_k_matters(variant_llvm_ad_rgb, buffers):
    """A wrong k (the check fails on it): k = 1.5 and k = 3 give different images."""
    from denoise.filters import OutlierParams, remove_outliers

    c = buffers[0]
    a = np.array(remove_outliers(tensors(c)[0], OutlierParams(k=3.0, radius=3)))
    assert close(a, np_outliers(c, 1.5, 3)) > 1e-2


def test_demodulation_round_trip_and_guard(variant_llvm_ad_rgb):
    from denoise.filters import ALBEDO_EPSILON, demodulate, remodulate

    rng = np.random.default_rng(3)
    color = rng.random((6, 7, 3)) * 4
    albedo = rng.random((6, 7, 3))
    albedo[0, 0] = 0.0  # background: no albedo
    albedo[1, 1, 2] = ALBEDO_EPSILON / 2
    c, a = tensors(color, albedo)
    flat = np.array(demodulate(c, a))
    expected = color / np.where(albedo > ALBEDO_EPSILON, albedo, 1)
    assert close(flat, expected) < 1e-5 and np.isfinite(flat).all()
    assert np.allclose(flat[0, 0], color[0, 0], rtol=1e-6)
    assert close(np.array(remodulate(demodulate(c, a), a)), color) < 1e-5


@pytest.mark.parametrize("levels", [1, 3])
def test_svgf_first_frame_matches_numpy(variant_llvm_ad_rgb, buffers, levels):
    from denoise.svgf_common import SVGFParams

    c, n, x, _ = buffers
    p = SVGFParams(levels=levels, sigma_plane=0.3)
    ours, _, ours_var = svgf_ours(c, n, x, p)
    reference, _, var = np_svgf(c, n, x, p)
    assert close(ours, reference) < 1e-4
    assert close(ours_var, var) < 1e-3 * max(1.0, var.max())  # variances square the weights: looser scale


def test_svgf_with_history_matches_numpy(variant_llvm_ad_rgb, buffers):
    """Three frames with a random back projection: accumulation, history length,
    the switch from spatial to temporal variance (at 4 frames here, made 2 for the test)."""
    from denoise.svgf_common import SVGFParams

    c, n, x, _ = buffers
    p = SVGFParams(levels=2, sigma_plane=0.3, variance_frames=2)
    rng = np.random.default_rng(7)
    ours_state = reference_state = None
    for frame in range(3):
        noisy = c * rng.uniform(0.5, 1.5, c.shape)
        if frame == 0:
            index = valid = None
        else:
            index = rng.integers(0, c.shape[0] * c.shape[1], c.shape[0] * c.shape[1])
            valid = rng.random(index.shape) > 0.3
        ours, ours_state, _ = svgf_ours(noisy, n, x, p, ours_state, index, valid)
        reference, reference_state, _ = np_svgf(noisy, n, x, p, reference_state, index, valid)
        assert close(ours, reference) < 1e-4, frame
        assert np.allclose(np.array(ours_state.length).reshape(-1), reference_state[2].reshape(-1))
    assert reference_state[2].max() == 3  # some pixels kept history twice


def test_svgf_check_fails_on_a_skipped_step(variant_llvm_ad_rgb, buffers, monkeypatch):
    """The comparison catches a real bug: variance not filtered along the colour
    (the NumPy reference keeps it) changes the result by far more than 1e-4."""
    import drjit as dr

    import denoise.methods.svgf as svgf_module
    from denoise.svgf_common import SVGFParams

    c, n, x, _ = buffers
    p = SVGFParams(levels=3, sigma_plane=0.3)
    original = svgf_module.atrous_level

    def keeps_variance(frame, color, variance, step, params):
        filtered, _ = original(frame, color, variance, step, params)
        return filtered, variance

    monkeypatch.setattr(svgf_module, "atrous_level", keeps_variance)
    ours, _, _ = svgf_ours(c, n, x, p)
    assert close(ours, np_svgf(c, n, x, p)[0]) > 1e-3
    del dr


def test_svgf_denoises(variant_llvm_ad_rgb, buffers):
    from denoise.svgf_common import SVGFParams

    c, n, x, _ = buffers
    ours, _, _ = svgf_ours(c, n, x, SVGFParams())
    assert np.abs(np.diff(ours, axis=1)).mean() < 0.5 * np.abs(np.diff(c, axis=1)).mean()


def test_svgf_levels_follow_the_width(variant_llvm_ad_rgb, buffers):
    """By default the footprint is the paper's fraction of the image: 5 levels at
    1280 pixels wide, 3 at 320, at least 1; the default run is the run with
    those levels, and a fixed 5 gives another image."""
    from denoise.svgf_common import SVGFParams, levels_for

    assert [levels_for(w) for w in (1280, 1920, 640, 320, 160, 40, 8)] == [5, 6, 4, 3, 2, 1, 1]
    c, n, x, _ = buffers
    default, _, _ = svgf_ours(c, n, x, SVGFParams(sigma_plane=0.3))
    explicit, _, _ = svgf_ours(c, n, x, SVGFParams(levels=levels_for(c.shape[1]), sigma_plane=0.3))
    assert np.array_equal(default, explicit)
    assert close(default, np_svgf(c, n, x, SVGFParams(levels=levels_for(c.shape[1]), sigma_plane=0.3))[0]) < 1e-4
    assert close(default, svgf_ours(c, n, x, SVGFParams(levels=5, sigma_plane=0.3))[0]) > 1e-3
