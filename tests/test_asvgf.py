"""asvgf against a NumPy implementation of the same maths, stage by stage, on small synthetic frames."""
from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from test_denoise import B3, close, np_normalize, shifted, tensors

LUM = np.array([0.2126, 0.7152, 0.0722])
TO_YCOCG = np.array([[0.25, 0.5, 0.25], [0.5, 0.0, -0.5], [-0.25, 0.5, -0.25]])
FROM_YCOCG = np.array([[1.0, 1.0, -1.0], [1.0, 0.0, 1.0], [1.0, -1.0, -1.0]])
H, W = 16, 24


# -- the NumPy reference ------------------------------------------------------------
def np_box(c, r):
    """Mean and σ per channel of each pixel's (2r+1)² box inside the image."""
    total, square, count = np.zeros_like(c), np.zeros_like(c), np.zeros(c.shape[:2] + (1,))
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            cj, inside = shifted(c, dx, dy)
            total += np.where(inside[..., None], cj, 0)
            square += np.where(inside[..., None], cj * cj, 0)
            count += inside[..., None]
    mean = total / count
    return mean, np.sqrt(np.maximum(square / count - mean ** 2, 0))


def np_clip(history, mean, sigma, width):
    y = history @ TO_YCOCG.T
    return np.clip(y, mean - width * sigma, mean + width * sigma) @ FROM_YCOCG.T


def np_temporal(c, p, history=None, index=None, valid=None):
    """(fast, slow, moments, length); ``history`` = (fast, slow, moments, length) arrays."""
    lum = c @ LUM
    moments = np.stack([lum, lum * lum], -1)
    if history is None:
        return c, c, moments, np.ones((H, W))
    v = valid.reshape(H, W)
    fast, slow, pm, pl = (a.reshape(H * W, -1)[index].reshape(H, W, -1) for a in history)
    pl = pl[..., 0]
    fast = np.where(v[..., None], fast, c)
    mean_c, sigma_c = np_box(c @ TO_YCOCG.T, p.box_radius)
    mean_f, _ = np_box(fast @ TO_YCOCG.T, p.box_radius)
    delta = np.abs(mean_c[..., 0] - mean_f[..., 0]) / (np.maximum(np.maximum(mean_c[..., 0], mean_f[..., 0]), 0)
                                                       + 1e-2)
    lam = np.clip(p.antilag_gain * (delta - p.antilag_threshold), 0, 1)
    length = np.where(v, np.minimum(1 + pl * (1 - lam), p.slow_frames), 1)
    alpha = (1 / length)[..., None]
    clipped = np_clip(fast, mean_c, sigma_c, p.fast_clip)
    fast = np.where(v[..., None], clipped + (c - clipped) * np.maximum(alpha, 1 / p.fast_frames), c)
    mean_fast, sigma_fast = np_box(fast @ TO_YCOCG.T, p.clip_radius)
    clipped = np_clip(slow, mean_fast, sigma_fast, p.clip_width)
    slow = np.where(v[..., None], clipped + (c - clipped) * alpha, c)
    moments = np.where(v[..., None], pm + (moments - pm) * alpha, moments)
    return fast, slow, moments, length


def np_plane(n, x, xj):
    return (n * np_normalize(xj - x)).sum(-1) ** 2


def np_variance(c, n, x, moments, length, p):
    """Temporal from the moments; spatial (SVGF's 7x7 on the current frame, its
    own default edge weights) where the history is short."""
    temporal = np.maximum(moments[..., 1] - moments[..., 0] ** 2, 0)
    lum = c @ LUM
    m = np.stack([lum, lum * lum], -1)
    total, weights = np.zeros((H, W, 2)), np.zeros((H, W))
    r = p.spatial_radius
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            mj, inside = shifted(m, dx, dy)
            if dx == 0 and dy == 0:
                wt = np.ones((H, W))
            else:
                nj, _ = shifted(n, dx, dy)
                xj, _ = shifted(x, dx, dy)
                wt = np.maximum((n * nj).sum(-1), 0) ** 128 * np.exp(-np_plane(n, x, xj) / (2 * 0.1 ** 2))
                wt = np.where(inside, wt, 0)
            total += wt[..., None] * mj
            weights += wt
    sm = total / weights[..., None]
    spatial = np.maximum(sm[..., 1] - sm[..., 0] ** 2, 0) * (p.variance_frames / length)
    return np.where(length < p.variance_frames, spatial, temporal)


def np_level(c, var, n, x, step, p):
    blurred = np.zeros((H, W))
    g = [0.25, 0.5, 0.25]
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            ys, xs = np.clip(np.arange(H) + dy, 0, H - 1), np.clip(np.arange(W) + dx, 0, W - 1)
            blurred += g[dx + 1] * g[dy + 1] * var[ys][:, xs]
    scale = 1 / (p.sigma_luminance * np.sqrt(np.maximum(blurred, 0)) + 1e-10)
    lp = c @ LUM
    tc, tw, tv = np.zeros_like(c), np.zeros((H, W)), np.zeros((H, W))
    for j in range(5):
        for i in range(5):
            dx, dy = (i - 2) * step, (j - 2) * step
            cj, inside = shifted(c, dx, dy)
            vj, _ = shifted(var, dx, dy)
            if dx == 0 and dy == 0:
                wt = np.full((H, W), B3[i] * B3[j])
            else:
                nj, _ = shifted(n, dx, dy)
                xj, _ = shifted(x, dx, dy)
                wt = (B3[i] * B3[j] * np.maximum((n * nj).sum(-1), 0) ** p.normal_exponent
                      * np.exp(-np.abs(lp - cj @ LUM) * scale - np_plane(n, x, xj) / (2 * p.sigma_plane ** 2)))
                wt = np.where(inside, wt, 0)
            tc += wt[..., None] * cj
            tw += wt
            tv += wt * wt * vj
    return tc / tw[..., None], tv / tw ** 2


def np_asvgf(c, n, x, p, history=None, index=None, valid=None):
    n = np_normalize(n)
    fast, slow, moments, length = np_temporal(c, p, history, index, valid)
    var = np_variance(c, n, x, moments, length, p)
    color, feedback = slow, slow
    for level in range(p.levels):
        color, var = np_level(color, var, n, x, 1 << level, p)
        if level == p.feedback_level:
            feedback = color
    wide = color
    for level in range(p.levels, p.levels + p.wide_levels):
        wide, var = np_level(wide, var, n, x, 1 << level, p)
    blend = np.clip((length - 1) / p.wide_frames, 0, 1)[..., None]
    return wide + (color - wide) * blend, (fast, feedback, moments, length[..., None])


# -- synthetic frames ---------------------------------------------------------------
def synthetic(seed: int, brightness: float = 1.0):
    """A floor and a tilted box face (two normals, positions on their planes) and
    a noisy colour whose mean differs between them."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    wall = xx > 14
    n = np.where(wall[..., None], [0.6, 0.0, 0.8], [0.0, 1.0, 0.02])
    x = np.stack([xx * 0.1, np.where(wall, yy * 0.1, 0.0), np.where(wall, 0.0, yy * 0.1)], -1)
    mean = np.where(wall[..., None], [0.9, 0.5, 0.3], [0.3, 0.35, 0.4])
    c = brightness * mean * rng.exponential(size=(H, W, 1)) * (1 + 0.2 * rng.random((H, W, 3)))
    return c, n, x


def random_history(seed: int):
    rng = np.random.default_rng(seed)
    c, _, _ = synthetic(seed + 100)
    fast = c * (1 + 0.1 * rng.random((H, W, 3)))
    slow = c * rng.choice([1.0, 4.0], size=(H, W, 1))  # some far outside the current box
    lum = slow @ LUM
    moments = np.stack([lum, lum * lum * 1.3], -1)
    length = rng.integers(1, 20, (H, W)).astype(np.float64)
    index = rng.integers(0, H * W, H * W)
    valid = rng.random(H * W) > 0.15
    return (fast, slow, moments, length), index, valid


def dr_history(history):
    import mitsuba as mi

    from denoise.methods.asvgf import ASVGFHistory

    fast, slow, moments, length = history
    return ASVGFHistory(mi.Vector3f(*[mi.Float(a) for a in fast.reshape(-1, 3).T.astype(np.float32)]),
                        mi.Vector3f(*[mi.Float(a) for a in slow.reshape(-1, 3).T.astype(np.float32)]),
                        mi.Vector2f(*[mi.Float(a) for a in moments.reshape(-1, 2).T.astype(np.float32)]),
                        mi.Float(length.reshape(-1).astype(np.float32)))


def arrays(v, channels):
    return np.array(v).T.reshape(H, W, channels) if channels > 1 else np.array(v).reshape(H, W)


def params(**changes):
    from denoise.methods.asvgf import hand_set

    return hand_set(**{"levels": 2, "box_radius": 2, "clip_radius": 1, **changes})


def frame_of(c, n, x):
    from denoise.filters import FrameArrays

    return FrameArrays(*tensors(c, n, x))


# -- tests ---------------------------------------------------------------------------
@pytest.mark.parametrize("changes", [{}, {"antilag_threshold": 0.05, "antilag_gain": 3.0, "clip_width": 0.5}])
def test_temporal_accumulation_matches_numpy(variant_vectorised_rgb, changes):
    import mitsuba as mi

    from denoise.methods.asvgf import FilterValues, temporal_accumulation

    p = params(**changes)
    c, n, x = synthetic(1)
    history, index, valid = random_history(2)
    ours = temporal_accumulation(frame_of(c, n, x), dr_history(history), mi.UInt32(index.astype(np.uint32)),
                                 mi.Bool(valid), p, FilterValues.of(p))
    reference = np_temporal(c, p, history, index, valid)
    for o, r, k in zip(ours, reference, (3, 3, 2, 1)):
        assert close(arrays(o, k), r) < 1e-5
    assert 1 < reference[3].min() or (
        reference[3] < np.where(valid, history[3].reshape(-1)[index] + 1, 1).reshape(H, W)).any()
    assert (np.abs(reference[1] - c) > 1e-3).any()  # the history is in it


def test_variance_matches_numpy(variant_vectorised_rgb):
    import mitsuba as mi

    from denoise.methods.asvgf import FilterValues, variance

    p = params()
    c, n, x = synthetic(3)
    rng = np.random.default_rng(4)
    lum = c @ LUM
    moments = np.stack([lum, lum * lum * (1 + rng.random((H, W)))], -1)
    length = rng.uniform(1, 8, (H, W))  # both sides of variance_frames
    ours = variance(frame_of(c, n, x), mi.Vector2f(*[mi.Float(a) for a in moments.reshape(-1, 2).T.astype(np.float32)]),
                    mi.Float(length.reshape(-1).astype(np.float32)), p, FilterValues.of(p))
    assert close(arrays(ours, 1), np_variance(c, np_normalize(n), x, moments, length, p)) < 1e-5


@pytest.mark.parametrize("step", [1, 2])
def test_atrous_level_matches_numpy(variant_vectorised_rgb, step):
    import mitsuba as mi

    from denoise.methods.asvgf import FilterValues
    from denoise.svgf_common import atrous_level

    p = params(normal_exponent=20.0)  # not a power of two: dr.power's path
    c, n, x = synthetic(5)
    var = np.random.default_rng(6).uniform(0.01, 0.5, (H, W))
    frame = frame_of(c, n, x)
    color, v = atrous_level(frame, frame.color, mi.Float(var.reshape(-1).astype(np.float32)), step, FilterValues.of(p))
    ref_color, ref_var = np_level(c, var, np_normalize(n), x, step, p)
    assert close(arrays(color, 3), ref_color) < 1e-5
    assert close(arrays(v, 1), ref_var) < 1e-5


def test_whole_frames_match_numpy(variant_vectorised_rgb):
    import mitsuba as mi

    from denoise.methods.asvgf import asvgf

    p = params()
    c0, n, x = synthetic(7)
    c1, _, _ = synthetic(8, brightness=0.2)  # a light dimmed in one frame
    ours0, history = asvgf(frame_of(c0, n, x), p)
    ref0, ref_history = np_asvgf(c0, n, x, p)
    # float32 through the variance's m2 - m1² and three kernels: 1.5e-5 seen; each stage alone within 1e-5
    assert close(np.array(ours0), ref0) < 5e-5
    index = np.arange(H * W)
    valid = np.random.default_rng(9).random(H * W) > 0.1
    ours1, _ = asvgf(frame_of(c1, n, x), p, history, mi.UInt32(index.astype(np.uint32)), mi.Bool(valid))
    ref1, _ = np_asvgf(c1, n, x, p, ref_history, index, valid)
    assert close(np.array(ours1), ref1) < 5e-5
    assert np.abs(np.diff(ref1, axis=1)).mean() < np.abs(np.diff(c1, axis=1)).mean()  # it smooths


def test_parameters_are_checked_and_read_from_the_file(variant_vectorised_rgb, tmp_path):
    from core.errors import UsageError
    from denoise.methods import make
    from denoise.methods.asvgf import FITTED_OPTIONS, hand_set, load_parameter_file

    for bad in ({"clip_width": -1.0}, {"slow_frames": float("nan")}, {"levels": 2.5}, {"fast_frames": True}):
        flag = "--" + next(iter(bad)).replace("_", "-")
        with pytest.raises(UsageError, match=f"asvgf: {flag} must be"):
            make("asvgf", **bad)
    with pytest.raises(UsageError, match="box_radius"):
        hand_set(box_radius=0)  # the kernel's own, which no option declares
    path = tmp_path / "p.json"
    path.write_text(json.dumps({"parameters": {"clip_width": 1.7}}))
    assert load_parameter_file(path) == {"clip_width": 1.7}
    for damaged in (json.dumps({"parameters": {"clip": 1.7}}), json.dumps({"parameters": {"clip_width": "x"}}),
                    json.dumps({"parameters": {"clip_width": 1e9}}), "{", "[" * 100000):
        path.write_text(damaged)
        with pytest.raises(UsageError, match="p.json") as error:
            load_parameter_file(path)
        assert "\n" not in str(error.value)
    assert hand_set().continuous() == {o.key: o.default for o in FITTED_OPTIONS}


def test_the_method_passes_its_options_to_the_filter(variant_vectorised_rgb):
    """``python -m denoise --method asvgf``'s options reach ASVGFParams; a bad one names the option."""
    from core.errors import UsageError
    from denoise.methods import make
    from denoise.methods.asvgf import fitted

    method = make("asvgf", clip_width=2.5, slow_frames=8.0, normal_exponent=32.0, levels=2)
    assert method.params == replace(fitted(), clip_width=2.5, slow_frames=8.0, normal_exponent=32.0, levels=2)
    assert method.temporal and method.demodulate
    with pytest.raises(UsageError, match="--clip-width"):
        make("asvgf", clip_width=-1.0)


@pytest.mark.parametrize("wide_levels", [0, 1])
def test_the_images_asked_for_are_the_ones_the_filter_makes(variant_vectorised_rgb, wide_levels):
    """``images=`` (benchmarks.asvgf_bounds' oracles pick among them) takes the slow
    history and every level's output, and changes nothing: the next history's slow
    is the feedback level's image and, without the wide blend, the output the last."""
    import mitsuba as mi

    from denoise.methods.asvgf import asvgf

    p = params(wide_levels=wide_levels, feedback_level=0)
    c, n, x = synthetic(3)
    history, index, valid = random_history(4)
    where = (dr_history(history), mi.UInt32(index.astype(np.uint32)), mi.Bool(valid))
    images = []
    out, kept = asvgf(frame_of(c, n, x), p, *where, images=images)
    plain, _ = asvgf(frame_of(c, n, x), p, *where)
    assert np.array_equal(np.array(out), np.array(plain)) and len(images) == 1 + 2 + wide_levels
    assert np.array_equal(np.array(images[1]), arrays(kept.slow, 3))
    if not wide_levels:
        assert np.array_equal(np.array(images[-1]), np.array(out))


@pytest.mark.parametrize("forget", [True, False])
def test_a_given_gradient_replaces_the_estimate(variant_vectorised_rgb, forget):
    """λ = 1 everywhere forgets the history (length 1, the slow history is the
    frame); λ = 0 keeps all of it (length grows by one wherever valid), whatever
    the frame and history look like."""
    import mitsuba as mi

    from denoise.methods.asvgf import FilterValues, temporal_accumulation

    p = params()
    c, n, x = synthetic(1)
    history, index, valid = random_history(2)
    gradient = mi.Float(np.full(H * W, 1.0 if forget else 0.0, np.float32))
    fast, slow, _, length = temporal_accumulation(frame_of(c, n, x), dr_history(history),
                                                  mi.UInt32(index.astype(np.uint32)), mi.Bool(valid), p,
                                                  FilterValues.of(p), gradient)
    length = arrays(length, 1)
    if forget:
        assert np.allclose(length, 1.0)
        assert close(arrays(slow, 3), c) < 1e-6
    else:
        previous = history[3].reshape(-1)[index].reshape(H, W)
        expected = np.where(valid.reshape(H, W), np.minimum(previous + 1, p.slow_frames), 1.0)
        assert np.allclose(length, expected, atol=1e-5)


def test_a_damaged_parameter_file_breaks_asvgf_only(monkeypatch, tmp_path, capsys):
    """The parameter file is read when asvgf is made, not at import: with it
    damaged, svgf runs, the live page lists asvgf's sliders, and asvgf is one
    line naming the file."""
    from core.errors import UsageError
    from denoise.__main__ import main
    from denoise.live.methods import sliders_of
    from denoise.methods import asvgf as method_module, make

    damaged = tmp_path / "asvgf_params.json"
    damaged.write_text("{\"parameters\": ")
    monkeypatch.setattr(method_module, "PARAMETER_FILE", damaged)
    make("svgf")
    assert sliders_of("asvgf")
    with pytest.raises(UsageError, match="asvgf_params.json: not a JSON parameter file") as error:
        make("asvgf")
    assert "\n" not in str(error.value)
    assert main([str(tmp_path), str(tmp_path / "out"), "--method", "svgf"]) == 2  # no frames: the folder's error
    assert "parameter file" not in capsys.readouterr().err
    assert main([str(tmp_path), str(tmp_path / "out"), "--method", "asvgf"]) == 2
    assert capsys.readouterr().err.startswith(f"python -m denoise: error: {damaged}: not a JSON parameter file")
