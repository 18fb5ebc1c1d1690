"""Neighbour reads as shifted planes (denoise/neighbours.py) give the gathers'
result bit for bit, in every filter that uses them, and stay out of the way of
gradients."""
from __future__ import annotations

import numpy as np
import pytest
from test_denoise import buffers_fixture, tensors  # noqa: F401 (the fixture "buffers")


def both_ways(monkeypatch, run):
    """``run()`` with the shifted planes and with every neighbour read a gather."""
    import denoise.neighbours as neighbours

    shifted = run()
    monkeypatch.setattr(neighbours, "ENABLED", False)
    gathered = run()
    monkeypatch.setattr(neighbours, "ENABLED", True)
    return shifted, gathered


def moved(c, n, x, seed):
    """The next frame: the same G-buffers, another noisy colour, the back projection the identity."""
    import mitsuba as mi

    rng = np.random.default_rng(seed)
    colour = c * rng.uniform(0.5, 1.5, c.shape)
    pixels = c.shape[0] * c.shape[1]
    return colour, mi.UInt32(np.arange(pixels, dtype=np.uint32)), mi.Bool(np.ones(pixels, bool))


@pytest.mark.parametrize("levels", [1, 3, 5])  # 5: holes of 16, taps 32 rows away on a 28-row image
def test_atrous_is_the_same_with_shifted_planes(variant_vectorised_rgb, buffers, monkeypatch, levels):
    from denoise.filters import EdgeWeights, FrameArrays
    from denoise.methods.atrous import atrous

    c, n, x, _ = buffers
    p = EdgeWeights(sigma_color=0.6, sigma_normal=0.3, sigma_plane=0.3)
    shifted, gathered = both_ways(monkeypatch, lambda: np.array(atrous(FrameArrays(*tensors(c, n, x)), p, levels)))
    assert np.isfinite(shifted).all() and np.array_equal(shifted, gathered)


@pytest.mark.parametrize("levels", [2, 5])
def test_svgf_is_the_same_with_shifted_planes(variant_vectorised_rgb, buffers, monkeypatch, levels):
    """Two frames (the second with a history): colour, variance and history alike."""
    from denoise.filters import FrameArrays
    from denoise.methods.svgf import svgf
    from denoise.svgf_common import SVGFParams

    c, n, x, _ = buffers
    c2, index, valid = moved(c, n, x, 3)
    p = SVGFParams(levels=levels, sigma_plane=0.3)

    def run():
        first, history, _ = svgf(FrameArrays(*tensors(c, n, x)), p)
        second, history, variance = svgf(FrameArrays(*tensors(c2, n, x)), p, history, index, valid)
        return [np.array(a) for a in (first, second, variance, history.color, history.moments)]

    shifted, gathered = both_ways(monkeypatch, run)
    assert all(np.isfinite(a).all() and np.array_equal(a, b) for a, b in zip(shifted, gathered))


def test_asvgf_is_the_same_with_shifted_planes(variant_vectorised_rgb, buffers, monkeypatch):
    """asvgf's levels and its wide levels chain the planes from level to level."""
    from denoise.filters import FrameArrays
    from denoise.methods.asvgf import asvgf, hand_set

    c, n, x, _ = buffers
    c2, index, valid = moved(c, n, x, 4)
    p = hand_set(levels=3, wide_levels=1)

    def run():
        first, history = asvgf(FrameArrays(*tensors(c, n, x)), p)
        second, _ = asvgf(FrameArrays(*tensors(c2, n, x)), p, history, index, valid)
        return [np.array(first), np.array(second)]

    shifted, gathered = both_ways(monkeypatch, run)
    assert all(np.isfinite(a).all() and np.array_equal(a, b) for a, b in zip(shifted, gathered))


def test_planes_read_shifted_values_and_refuse_offsets_past_their_margin(variant_vectorised_rgb):
    import drjit as dr
    import mitsuba as mi

    from denoise.neighbours import ShiftedPlanes, usable

    values = mi.Float(np.arange(10, dtype=np.float32) + 1)
    planes = ShiftedPlanes([values, 2 * values], margin=3)
    assert np.array_equal(np.array(planes.at(0, 2)), [3, 4, 5, 6, 7, 8, 9, 10, 0, 0])
    assert np.array_equal(np.array(planes.at(1, -3)), [0, 0, 0, 2, 4, 6, 8, 10, 12, 14])
    with pytest.raises(ValueError, match="beyond the planes' margin 3"):
        planes.at(0, 4)
    tracked = mi.Float(values)
    dr.enable_grad(tracked)
    assert usable(values) and not usable(values, tracked)  # a gradient needs the gathers
    with pytest.raises(ValueError, match="gradient tracked"):
        ShiftedPlanes([tracked], margin=1)


def test_a_level_reads_its_own_inputs_not_the_planes_offered_before(variant_vectorised_rgb, buffers, monkeypatch):
    """A level whose inputs are not the level before's output (as a caller may
    chain them) makes its own planes instead of reading the ones offered."""
    import drjit as dr
    import mitsuba as mi

    from denoise.filters import FrameArrays
    from denoise.svgf_common import SVGFParams, atrous_level

    c, n, x, _ = buffers
    variance = mi.Float(np.random.default_rng(5).uniform(0.01, 0.5, c.shape[0] * c.shape[1]).astype(np.float32))
    p = SVGFParams(sigma_plane=0.3)

    def run():
        frame = FrameArrays(*tensors(c, n, x))
        dr.eval(atrous_level(frame, frame.color, variance, 1, p))  # offers its output's planes
        return [np.array(a) for a in atrous_level(frame, frame.color, variance, 2, p)]

    shifted, gathered = both_ways(monkeypatch, run)
    assert all(np.array_equal(a, b) for a, b in zip(shifted, gathered))


@pytest.mark.parametrize("radius", [1, 3])
def test_clamp_box_is_the_same_with_shifted_planes(variant_vectorised_rgb, buffers, monkeypatch, radius):
    """The temporal clamp's box statistics: both passes read shifted planes."""
    from denoise.filters import clamp_box

    c, _, _, _ = buffers
    shifted, gathered = both_ways(monkeypatch, lambda: [np.array(a) for a in clamp_box(tensors(c)[0], radius)])
    assert all(np.isfinite(a).all() and np.array_equal(a, b) for a, b in zip(shifted, gathered))


@pytest.mark.parametrize("size", [(6, 7), (1, 5), (4, 1)])
def test_the_variance_blur_reads_planes_as_the_gathers_at_every_edge(variant_vectorised_rgb, size):
    """SVGF's 3x3 Gaussian of the variance reads the level's planes (no gather; past the image
    its row's or column's centre): the same values at every edge and corner as the gathers'
    clamped taps, and as NumPy's blur of the edge-padded image. (The showcase buffers of the
    tests above have sky along their top row, where no weight depends on the variance.)"""
    import drjit as dr

    from denoise.filters import FrameArrays
    from denoise.svgf_common import GAUSS3, blurred_variance

    height, width = size
    rng = np.random.default_rng(5)
    c = rng.uniform(0.1, 2.0, (height, width, 3))
    frame = FrameArrays(*tensors(c, np.dstack([np.zeros((height, width, 2)), np.ones((height, width))]), c))
    variance = frame.color.x * 1.0
    dr.eval(variance)
    planes = frame.planes_of((frame.color.x, frame.color.y, frame.color.z, variance), 2)
    from_planes = np.array(blurred_variance(frame, variance, planes))
    gathered = np.array(blurred_variance(frame, variance))
    padded = np.pad(c[..., 0].astype(np.float32), 1, mode="edge")
    g = np.array(GAUSS3)
    expected = sum(g[i] * g[j] * padded[j:j + height, i:i + width] for i in range(3) for j in range(3))
    assert np.array_equal(from_planes, gathered)
    np.testing.assert_allclose(from_planes.reshape(height, width), expected, rtol=1e-6)


@pytest.mark.parametrize("radius", [1, 3])
def test_box_mean_is_the_mean_over_the_box_inside_the_image(variant_vectorised_rgb, buffers, monkeypatch, radius):
    """One channel's box mean (A-SVGF's lambda): shifted planes and gathers alike, both
    the mean of each pixel's (2r+1)^2 box cut to the image, as NumPy computes it."""
    import mitsuba as mi

    from denoise.filters import box_mean

    c, _, _, _ = buffers
    values = c[..., 1].astype(np.float32)
    height, width = values.shape
    shifted, gathered = both_ways(monkeypatch, lambda: np.array(box_mean(mi.Float(values.ravel()), width, height,
                                                                           radius)))
    assert np.array_equal(shifted, gathered)
    expected = np.array([[values[max(0, y - radius):y + radius + 1, max(0, x - radius):x + radius + 1].mean()
                          for x in range(width)] for y in range(height)])
    assert np.allclose(shifted.reshape(height, width), expected, rtol=1e-5, atol=1e-6 * np.abs(values).max())


def test_a_steady_frame_maps_no_new_memory(variant_vectorised_rgb, buffers, monkeypatch):
    """From the second frame of a size on, every plane comes from the pool
    (no NumPy view made, no wait for the queue), and the output stays the gathers'."""
    import denoise.neighbours as neighbours
    from denoise.filters import FrameArrays
    from denoise.methods.svgf import svgf
    from denoise.svgf_common import SVGFParams

    c, n, x, _ = buffers
    made = []
    original = neighbours.Plane.__init__

    def counted(self, length):
        made.append(length)
        original(self, length)

    monkeypatch.setattr(neighbours.Plane, "__init__", counted)
    p = SVGFParams(levels=3, sigma_plane=0.3)
    outputs = []
    for _ in range(3):
        before = len(made)
        outputs.append(np.array(svgf(FrameArrays(*tensors(c, n, x)), p)[0]))
        new = len(made) - before
    assert new == 0 and made  # the third frame took every plane from the pool
    monkeypatch.setattr(neighbours, "ENABLED", False)
    assert np.array_equal(outputs[-1], np.array(svgf(FrameArrays(*tensors(c, n, x)), p)[0]))


def test_a_level_differentiated_in_its_sigma_alone_uses_the_gathers(variant_llvm_ad_rgb, buffers, monkeypatch):
    """A per-pixel σ with a gradient and a colour without one (learned-asvgf's
    first level on a first frame, in training): the level's gradient in σ is
    finite and the gathers' (the shifted planes take no part in a gradient)."""
    import drjit as dr
    import mitsuba as mi

    from denoise.filters import FrameArrays, luminance
    from denoise.svgf_common import atrous_level

    c, n, x, _ = buffers
    pixels = c.shape[0] * c.shape[1]

    def gradient():
        frame = FrameArrays(*tensors(c, n, x))
        sigma = mi.Float(np.full(pixels, 1.5, np.float32))
        dr.enable_grad(sigma)
        values = type("Values", (), {"sigma_luminance": sigma, "normal_exponent": 33.9, "sigma_plane": 0.3})
        values_without_gradient = type("Values", (), {"sigma_luminance": 1.5, "normal_exponent": 33.9,
                                                      "sigma_plane": 0.3})
        colour = frame.color
        variance = dr.square(luminance(colour)) * 0.25
        out, _ = atrous_level(frame, colour, variance, 1, values)
        dr.eval(out)
        # another frame's level before the backward pass: it may reuse the planes' memory
        later = FrameArrays(*tensors(c * 7.0 + 1.0, n, x))
        dr.eval(atrous_level(later, later.color, luminance(later.color), 1, values_without_gradient)[0])
        dr.backward(dr.mean(luminance(out)))
        return np.array(dr.grad(sigma))

    first, gathered = both_ways(monkeypatch, gradient)
    assert np.isfinite(first).all() and np.abs(first).max() > 0
    assert np.array_equal(first, gathered)
