"""Checks that can fail: each check below is run once on the code as it is (it
passes) and once on purpose-broken code (it must fail).

- the two-sided white furnace, against an ``eval`` 10 % too small;
- sampling against evaluation, by two independent estimators of the light a
  Phong surface reflects (through ``sample``, and uniform hemisphere sampling
  of ``eval``), against a glossy pdf normalised with s + 2 instead of s + 1;
- ``-filter`` against an independent 3x3 Gaussian (sigma = 1 high-res pixel)
  of a 3x render, against a box filter;
- ``-jitter``'s sample count, estimated from its noise, against 8 samples;
- the error-against-time slopes, against a renderer that ignores spp;
- whitted vs path: the quick cross-validation set fails with a bias of +-3 %,
  and every scene fails with +-1 %.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from conftest import SCALAR_FALLBACK
from helpers import render_layers

from converters.course_scene import load_scene
from imaging.image_io import read_exr
from validation import convergence, crossval

ROOT = Path(__file__).resolve().parent.parent
TRANSFORMS = ROOT / "scenes" / "transforms.txt"


def phong_class():
    import mitsuba as mi

    return type(mi.load_dict({"type": "phong"}))  # the class this variant instantiates


# -- BSDF ----------------------------------------------------------------------------
FURNACE_CASES = [(0.5, 0.5, 1.0, 60.0), (0.2, 0.8, 500.0, 85.0), (0.1, 0.9, 100.0, 10.0), (0.3, 0.6, 5.0, 45.0)]


def furnace_passes(samples: int) -> bool:
    return all(crossval.furnace_case(*case, samples=samples)["passed"] for case in FURNACE_CASES)


def test_analytic_albedo_closed_forms():
    """The quadrature against closed forms: normal incidence keeps the whole lobe
    (albedo kd + 2 ks / (s + 1)); a pure diffuse lobe is kd at any angle."""
    for s in (0.0, 1.0, 20.0, 2000.0):
        assert crossval.analytic_albedo(0.3, 0.6, s, 0.0) == pytest.approx(0.3 + 1.2 / (s + 1), rel=1e-6)
    assert crossval.analytic_albedo(0.7, 0.0, 5.0, 80.0) == pytest.approx(0.7)
    # at grazing incidence half of a narrow lobe dips below the horizon
    assert crossval.analytic_albedo(0.0, 1.0, 1e4, 90.0) == pytest.approx(0.5 * 2 / (1e4 + 1), rel=1e-2)


def test_furnace_is_two_sided(variant_rgb, monkeypatch):
    samples = 1 << (12 if SCALAR_FALLBACK else 18)
    assert furnace_passes(samples)
    cls = phong_class()
    original = cls.eval
    monkeypatch.setattr(cls, "eval", lambda self, *args, **kwargs: original(self, *args, **kwargs) * 0.9)
    assert not furnace_passes(samples)
    json.dumps(crossval.furnace_case(*FURNACE_CASES[0], samples=samples))  # a failed case still serialises


def hemisphere_light(wo: np.ndarray) -> np.ndarray:
    """A smooth incident radiance over the upper hemisphere (positive, not symmetric)."""
    return 1.0 + 0.8 * wo[..., 0] + 2.0 * wo[..., 2] ** 3


def reflected_radiance(kd: float, ks: float, s: float, theta: float, samples: int, seed: int,
                       uniform: bool) -> tuple[float, float]:
    """Light reflected towards ``theta`` under :func:`hemisphere_light`: mean and standard
    error, through the BSDF's ``sample`` or (``uniform``) uniform hemisphere sampling of ``eval``."""
    import drjit as dr
    import mitsuba as mi

    bsdf = mi.load_dict(crossval._phong(kd, ks, s))
    rng = np.random.default_rng(seed)
    u = rng.random((3, samples))
    wi = [math.sin(math.radians(theta)), 0.0, math.cos(math.radians(theta))]
    if uniform:
        z = u[0]
        r = np.sqrt(1 - z * z)
        wo = np.stack([r * np.cos(2 * np.pi * u[1]), r * np.sin(2 * np.pi * u[1]), z], axis=-1)
    values = []
    if dr.is_jit_v(mi.Float):
        si = dr.zeros(mi.SurfaceInteraction3f, samples)
        si.wi, si.sh_frame = mi.Vector3f(wi), mi.Frame3f(mi.Vector3f(0, 0, 1))
        if uniform:
            f = np.array(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(wo.T)), np.float64)[0] * 2 * np.pi
        else:
            bs, weight = bsdf.sample(mi.BSDFContext(), si, mi.Float(u[0]), mi.Point2f(u[1], u[2]))
            f, wo = np.array(weight, np.float64)[0], np.array(bs.wo, np.float64).T
    else:  # scalar variants: one direction at a time
        si = dr.zeros(mi.SurfaceInteraction3f)
        si.wi, si.sh_frame = mi.Vector3f(wi), mi.Frame3f(mi.Vector3f(0, 0, 1))
        f, directions = [], []
        for k in range(samples):
            if uniform:
                f.append(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(wo[k]))[0] * 2 * np.pi)
            else:
                bs, weight = bsdf.sample(mi.BSDFContext(), si, float(u[0, k]), mi.Point2f(u[1, k], u[2, k]))
                f.append(weight[0])
                directions.append([bs.wo[0], bs.wo[1], bs.wo[2]])
        f = np.array(f, np.float64)
        wo = wo if uniform else np.array(directions, np.float64)
    values = f * hemisphere_light(wo)
    return float(values.mean()), float(values.std() / math.sqrt(samples))


def sampling_matches_eval(samples: int) -> bool:
    """Both estimators agree within 4 combined standard errors, for a broad and a narrow lobe."""
    for kd, ks, s, theta in ((0.3, 0.7, 20.0, 40.0), (0.5, 0.5, 4.0, 70.0)):
        a, ea = reflected_radiance(kd, ks, s, theta, samples, 1, uniform=False)
        b, eb = reflected_radiance(kd, ks, s, theta, samples, 2, uniform=True)
        if abs(a - b) > 4 * math.hypot(ea, eb):
            return False
    return True


def test_sampling_matches_eval(variant_rgb, monkeypatch):
    samples = 1 << (13 if SCALAR_FALLBACK else 20)
    assert sampling_matches_eval(samples)
    # the classic slip: the glossy pdf normalised like the energy-conserving
    # lobe, (s + 2) / (2 pi), while directions are drawn from cos^s
    cls = phong_class()
    from mi_plugins.phong import clamped_power

    monkeypatch.setattr(cls, "_lobe_pdf", lambda self, c: (self.exponent + 2.0) / (2 * math.pi)
                        * clamped_power(c, self.exponent))
    assert not sampling_matches_eval(samples)


# -- -filter and -jitter --------------------------------------------------------------
def course_gaussian_3x3(high: np.ndarray) -> np.ndarray:
    """The course's filter written out: each output pixel is the weighted mean of the 3x3
    high-resolution pixels it covers, weights exp(-(dx^2 + dy^2) / 2) (sigma = 1 pixel)."""
    h, w = high.shape[0] // 3, high.shape[1] // 3
    out = np.zeros((h, w, high.shape[2]))
    total = 0.0
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            weight = math.exp(-(dx * dx + dy * dy) / 2.0)
            out += weight * high[1 + dy: 3 * h: 3, 1 + dx: 3 * w: 3]
            total += weight
    return out / total


def render_cli(tmp_path: Path, name: str, width: int, height: int, *flags: str) -> np.ndarray:
    """``render.py -input transforms.txt ... -output NAME.exr``: the linear float beauty."""
    from renderer.cli import main

    out = tmp_path / f"{name}.exr"
    assert main(["-input", str(TRANSFORMS), "-size", str(width), str(height), "-output", str(out), "--quiet",
                 *flags]) == 0
    channels = read_exr(out)
    return np.stack([channels["R"], channels["G"], channels["B"]], axis=-1).astype(np.float64)


def filter_error(tmp_path: Path) -> float:
    width, height = (20, 12) if SCALAR_FALLBACK else (60, 40)
    filtered = render_cli(tmp_path, "filtered", width, height, "-filter")
    high = render_layers(load_scene(TRANSFORMS), width=3 * width, height=3 * height)[""].astype(np.float64)
    return float(np.abs(filtered - course_gaussian_3x3(high)).max())


def test_filter_is_the_course_gaussian(variant_rgb, tmp_path, monkeypatch):
    assert filter_error(tmp_path) < 1e-4  # the same samples: only float32 rounding differs
    import renderer.job

    def box(image):
        h, w = image.shape[0] // 3, image.shape[1] // 3
        return image[: 3 * h, : 3 * w].reshape(h, 3, w, 3, *image.shape[2:]).mean(axis=(1, 3)).astype(image.dtype)

    monkeypatch.setattr(renderer.job, "downsample_3x", box)
    assert filter_error(tmp_path) > 1e-2


def jitter_sample_count(tmp_path: Path, seed: int = 0) -> float:
    """Samples per pixel of ``-jitter``, estimated from its noise: its mean squared
    error against an independent render of M spp, minus that render's share, is
    sigma^2 / N; sigma^2 (one jittered sample's variance) comes from pairs of
    independent 1-spp renders, E[(a - b)^2] = 2 sigma^2."""
    width, height, reference_spp, pairs = (48, 32, 32, 8) if SCALAR_FALLBACK else (96, 64, 256, 8)
    jittered = render_cli(tmp_path, "jittered", width, height, "-jitter")
    scene = load_scene(TRANSFORMS)
    options = dict(width=width, height=height, jitter=True)
    reference = render_layers(scene, spp=reference_spp, seed=11 + seed, **options)[""].astype(np.float64)
    singles = [render_layers(scene, spp=1, seed=100 + 2 * pairs * seed + k, **options)[""].astype(np.float64)
               for k in range(2 * pairs)]
    variance = np.mean([np.mean((a - b) ** 2) / 2 for a, b in zip(singles[::2], singles[1::2])])
    error = np.mean((jittered - reference) ** 2) - variance / reference_spp
    assert abs(jittered.mean() - reference.mean()) < 0.02 * reference.mean()  # the same image
    return float(variance / error)


def test_jitter_takes_16_samples(variant_rgb, tmp_path, monkeypatch):
    # measured (5 seeds each): 16 samples give 13.8-15.5 at 96x64 (10.1-14.4 at 48x32), 8 give
    # 6.7-7.8 (4.7-7.0): the estimate runs low, its spread is +-15 %; the bound sits between
    lowest = 8.5 if SCALAR_FALLBACK else 11.0
    assert lowest <= jitter_sample_count(tmp_path) <= 24
    import converters.render_flags

    monkeypatch.setattr(converters.render_flags, "JITTER_SPP", 8)
    assert jitter_sample_count(tmp_path) < lowest


# -- error against time ------------------------------------------------------------------
def evt_slopes(paths: list[Path]) -> list[dict]:
    size = 12 if SCALAR_FALLBACK else 32
    spps = {"whitted": [1, 4, 16], "path": [4, 16, 64]} if SCALAR_FALLBACK else \
        {"whitted": [1, 4, 16, 64], "path": [4, 16, 64, 256]}
    return convergence.measure(paths, size, spps, 256 if SCALAR_FALLBACK else 2048, progress=lambda _: None)["slopes"]


def test_error_vs_time_slopes_are_monte_carlo(variant_rgb, monkeypatch):
    """relMSE falls as 1/spp (slope -1 in log-log; -0.7 .. -1.3 allows for the
    noise of four points)."""
    paths = [ROOT / "scenes" / "mirrors.txt", ROOT / "scenes" / "lamps.txt"]
    for s in evt_slopes(paths):  # (the slope per second depends on the machine's load: reported only)
        assert -1.3 <= s["spp_slope"] <= -0.7, s
    original = convergence.render_timed
    monkeypatch.setattr(convergence, "render_timed",
                        lambda path, size, spp, seed, options: original(path, size, 1, seed, options))
    assert all(not -1.3 <= s["spp_slope"] <= -0.7 for s in evt_slopes(paths[:1]))


# -- whitted vs path ---------------------------------------------------------------------
def agreement_failures(bias: float, paths: list[Path], size: int, spp: int, bounces: int = 4) -> dict[str, bool]:
    with crossval.biased_whitted(bias):
        return {p.stem: not crossval.agreement(p, bounces, spp, size).passed for p in paths}


def test_quick_crossval_has_a_single_light_scene(course):
    names = [p.stem for p in crossval.scene_paths(course, quick=True)]
    assert crossval.SINGLE_LIGHT_SCENE in names
    assert "numLights 1" in " ".join((ROOT / "scenes" / f"{crossval.SINGLE_LIGHT_SCENE}.txt").read_text().split())


# The power of the agreement check rests on whitted and path seeing the same pixel
# samples (same seed): true of the vectorised sampler, not of scalar_rgb's, where one
# stream per block is shared with the path tracer's later dimensions. These two tests
# therefore need llvm_ad_rgb (without it they skip, visibly, as not required).
@pytest.mark.parametrize("bias", [0.03, -0.03])
def test_quick_crossval_fails_with_3_percent_bias(variant_vectorised_rgb, course, bias):
    size, spp = 48, 16  # the quick run's size and lower spp
    failed = agreement_failures(bias, crossval.scene_paths(course, quick=True), size, spp)
    assert all(failed.values()), failed


def test_every_scene_fails_with_1_percent_bias(variant_vectorised_rgb, course):
    """The full check (128x128, 64 and 1024 spp) has more samples per pixel than this
    48x48, 256 spp version, which already fails every scene with +-1 %."""
    paths = crossval.scene_paths(course)
    assert not any(agreement_failures(0.0, paths, 48, 256).values())
    for bias in (0.01, -0.01):
        failed = agreement_failures(bias, paths, 48, 256)
        assert all(failed.values()), (bias, failed)
