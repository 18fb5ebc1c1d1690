"""Cross-validation of the renderer against Mitsuba's own machinery: the checks and their criteria.

1. The ``phong`` BSDF passes Mitsuba's chi-square test (``mitsuba.chi2``)
   on a grid of kd/ks/shininess and incident angles, and a two-sided white
   furnace: its Monte Carlo albedo (from its own ``sample``) agrees within
   4 standard errors with the albedo of the model's formula integrated
   independently (:func:`analytic_albedo`, a 1-D quadrature).
2. For every course scene and each of ours, with ambient 0 and a background
   that emits nothing, ``whitted`` at bounces 0..4 agrees with Mitsuba's
   ``path`` integrator restricted to the same light paths (``phong`` with
   ``sampling="mirror"``), with the same jittered pixel samples (same seed;
   in vectorised variants only: scalar_rgb shares one random stream per block
   with the path tracer's later dimensions, so there the two are independent
   and the check has less power):

   - no tile of 16x16 pixels, nor the whole image, in any channel, has a
     mean of whitted - path further from 0 than its standard error allows:
     |z| below the two-sided 1 % level, Bonferroni-corrected over all tiles
     and channels (pixels are independent, so the standard error of a tile's
     mean difference is the spread of its pixels' differences / sqrt(n));
   - and the relative MSE between them is at most twice that between two
     path renders with different seeds,

   at 64 and 1024 spp (``--quick``: 48x48 pixels, 16 and 64 spp, a single-
   light scene with mirrors among the three scenes). :func:`biased_whitted`
   scales whitted's shading (fault injection): the checks must then fail.

``python -m benchmarks.crossval`` runs them and reports (exit non-zero if any
criterion fails); the notebook ``notebooks/crossval.ipynb`` and the tests call
the same functions.
"""
from __future__ import annotations

import math
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path
from statistics import NormalDist

import drjit as dr
import mitsuba as mi
import numpy as np
from mitsuba.chi2 import BSDFAdapter, ChiSquareTest, SphericalDomain

from converters.course_scene import load_scene
from converters.description import RenderOptions, scene_dict
from converters.scene_variants import (
    apply,
    with_mirror_sampling,
    with_path_tracer,
    without_ambient,
    without_background,
    without_ray_epsilon,
)
from converters.to_mitsuba import load_scene_dict
from imaging.metrics import relmse
from renderer.variants import set_variant

ROOT = Path(__file__).resolve().parent.parent

#: (kd, ks, shininess) combinations for the BSDF checks
MATERIALS = [(0.5, 0.5, 1.0), (0.8, 0.2, 20.0), (0.2, 0.8, 500.0), (0.0, 1.0, 1000.0), (1.0, 0.0, 20.0),
             (0.3, 0.6, 5.0), (0.1, 0.9, 100.0), (0.6, 0.4, 2000.0)]
#: incident angles (degrees from the normal)
ANGLES = [0.0, 45.0, 85.0]
QUICK_MATERIALS = [(0.5, 0.5, 1.0), (0.2, 0.8, 500.0), (0.1, 0.9, 100.0), (0.6, 0.4, 2000.0)]
QUICK_ANGLES = [10.0, 85.0, 60.0]
#: chi-square sample counts (full, quick)
CHI2_SAMPLES = (1_000_000, 200_000)
#: furnace: standard errors allowed between the Monte Carlo and the integrated albedo,
#: and the relative float32 rounding that widens a standard error of ~0
FURNACE_SIGMAS = 4.0
FLOAT32 = 1e-6
#: agreement: tiles of this many pixels square, and the family-wise significance level
TILE = 16
SIGNIFICANCE = 0.01
#: relative difference below which whitted and path agree whatever the noise: the two
#: compute the same products in another order (float32 rounding, ~1e-6), and a real
#: bias (a missing factor, a wrong falloff) is percents
ROUNDING = 1e-4
#: a single-light scene with mirrors: there whitted and path compute the same samples,
#: so any bias shows; the quick set must contain it
SINGLE_LIGHT_SCENE = "mirrors"


def _phong(kd, ks, s, sampling="phong") -> dict:
    return {"type": "phong", "diffuse_reflectance": {"type": "rgb", "value": [kd] * 3},
            "specular_reflectance": {"type": "rgb", "value": [ks] * 3}, "exponent": s, "sampling": sampling}


def chi2_case(kd: float, ks: float, shininess: float, theta: float, sample_count: int = 1_000_000) -> dict:
    """Mitsuba's chi-square test of the phong BSDF's sampling against its pdf."""
    wi = [math.sin(math.radians(theta)), 0.0, math.cos(math.radians(theta))]
    sample_func, pdf_func = BSDFAdapter("phong", _phong(kd, ks, shininess), wi=wi)
    # narrow lobes need a fine histogram and pdf quadrature (with a coarse one
    # the test fails on the quadrature error, e.g. s = 1000 at normal incidence)
    test = ChiSquareTest(domain=SphericalDomain(), sample_func=sample_func, pdf_func=pdf_func,
                         sample_dim=3, sample_count=sample_count, res=201, ires=16 if shininess < 1000 else 64)
    passed = bool(test.run(significance_level=0.01, quiet=True))
    Path("chi2_data.py").unlink(missing_ok=True)  # written by a failing test; the JSON has the numbers
    return {"kd": kd, "ks": ks, "shininess": shininess, "theta_deg": theta,
            "p_value": float(test.p_value) if test.p_value is not None else None, "passed": passed}


def furnace_albedo(kd: float, ks: float, shininess: float, theta: float, samples: int = 1 << 20,
                   seed: int = 7) -> tuple[float, float]:
    """Monte Carlo directional albedo (mean, standard error) from the BSDF's own sampling."""
    bsdf = mi.load_dict(_phong(kd, ks, shininess))
    u = np.random.default_rng(seed).random((3, samples))
    wi = mi.Vector3f(math.sin(math.radians(theta)), 0.0, math.cos(math.radians(theta)))
    ctx = mi.BSDFContext()
    if dr.is_jit_v(mi.Float):
        si = dr.zeros(mi.SurfaceInteraction3f, samples)
        si.wi, si.sh_frame = wi, mi.Frame3f(mi.Vector3f(0, 0, 1))
        _, weight = bsdf.sample(ctx, si, mi.Float(u[0]), mi.Point2f(u[1], u[2]))
        values = np.array(weight, np.float64)[0]
    else:  # scalar variants: one sample at a time
        si = dr.zeros(mi.SurfaceInteraction3f)
        si.wi, si.sh_frame = wi, mi.Frame3f(mi.Vector3f(0, 0, 1))
        values = np.array([bsdf.sample(ctx, si, float(u[0, k]), mi.Point2f(u[1, k], u[2, k]))[1][0]
                           for k in range(samples)], np.float64)
    return float(values.mean()), float(values.std() / math.sqrt(samples))


def analytic_albedo(kd: float, ks: float, shininess: float, theta: float, nodes: int = 200_000) -> float:
    """Directional albedo of the course's Phong model, integrated independently of the plugin.

    With the BSDF's documented formula ``f cos = kd/pi cos(theta_o) + ks/pi max(0, R.wo)^s``
    over the upper hemisphere: the diffuse part integrates to ``kd``; the glossy part,
    in a frame around the mirror direction R (at ``theta`` from the normal), is
    ``ks/pi * int_0^1 x^s g(x) dx`` with ``x = cos(alpha)`` and ``g(x)`` the length of the
    circle of directions at angle alpha from R that lies above the horizon (closed
    form). Substituting ``t = x^(s+1)`` makes the integrand bounded; midpoint rule.
    """
    t = (np.arange(nodes) + 0.5) / nodes
    x = t ** (1.0 / (shininess + 1.0))
    sin_r, cos_r = math.sin(math.radians(theta)), math.cos(math.radians(theta))
    sin_alpha = np.sqrt(np.maximum(1.0 - x * x, 0.0))
    # a direction at angle alpha from R and azimuth phi has z = x cos_r - sin_alpha sin_r cos(phi)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.where(sin_alpha * sin_r > 0.0, x * cos_r / (sin_alpha * sin_r), np.inf)
    circle = np.where(u >= 1.0, 2 * np.pi, np.where(u <= -1.0, 0.0, 2 * np.pi - 2 * np.arccos(np.clip(u, -1, 1))))
    glossy = circle.mean() / (shininess + 1.0)  # int_0^1 x^s g(x) dx
    return kd + ks / math.pi * glossy


def furnace_case(kd: float, ks: float, shininess: float, theta: float, samples: int = 1 << 20) -> dict:
    """Two-sided furnace: Monte Carlo albedo against :func:`analytic_albedo`."""
    mean, error = furnace_albedo(kd, ks, shininess, theta, samples)
    expected = float(analytic_albedo(kd, ks, shininess, theta))
    # where every sample weighs the same (a pure lobe sampled exactly) the standard error
    # vanishes and float32 rounding (~1e-7 relative) is what is left
    allowed = math.hypot(error, FLOAT32 * expected)
    z = (mean - expected) / allowed if allowed > 0 else (0.0 if mean == expected else math.inf)
    passed = abs(z) <= FURNACE_SIGMAS and mean <= 1.0 + FURNACE_SIGMAS * error
    return {"kd": kd, "ks": ks, "shininess": shininess, "theta_deg": theta, "albedo": mean, "stderr": error,
            "expected": expected, "z": float(z), "passed": bool(passed)}


@dataclass
class Agreement:
    scene: str
    bounces: int
    spp: int
    relmse_whitted_path: float
    relmse_path_path: float
    max_abs_z: float = 0.0  # largest |z| over tiles, the whole image and channels
    z_critical: float = math.inf  # Bonferroni-corrected two-sided bound
    relative_bias: float = 0.0  # whole image: mean(whitted) / mean(path) - 1
    relative_bias_stderr: float = 0.0

    @property
    def passed(self) -> bool:
        return self.relmse_whitted_path <= 2.0 * self.relmse_path_path and self.max_abs_z <= self.z_critical


def tile_z_scores(difference: np.ndarray, reference: np.ndarray, tile: int = TILE) -> np.ndarray:
    """z-score of the mean of ``difference`` (H, W, C) per tile, for the whole image
    and per channel; the standard error of a mean over n independent pixels is their
    standard deviation / sqrt(n), widened by :data:`ROUNDING` of the reference's mean."""
    h, w, channels = difference.shape
    regions = [(slice(None), slice(None))]
    regions += [(slice(y, y + tile), slice(x, x + tile)) for y in range(0, h, tile) for x in range(0, w, tile)]
    z = []
    for rows, cols in regions:
        d = difference[rows, cols].reshape(-1, channels).astype(np.float64)
        level = np.abs(reference[rows, cols].reshape(-1, channels).astype(np.float64).mean(axis=0))
        n = d.shape[0]
        if n < 2:
            continue
        stderr = np.sqrt(d.var(axis=0, ddof=1) / n + (ROUNDING * level) ** 2)
        mean = d.mean(axis=0)
        with np.errstate(divide="ignore", invalid="ignore"):
            z.append(np.where(stderr > 0, mean / stderr, np.where(mean == 0, 0.0, np.inf)))
    return np.array(z)


def z_critical(tests: int, significance: float = SIGNIFICANCE) -> float:
    """Two-sided normal quantile with a Bonferroni correction over ``tests``."""
    return NormalDist().inv_cdf(1.0 - significance / (2.0 * tests))


def scene_paths(course: Path | None, quick: bool = False) -> list[Path]:
    """The course scenes (if present) and ours; ``quick``: the last course scene
    (two lights, mirrors, shadows), ``lamps`` (three lights) and ``mirrors`` (one)."""
    course_scenes = sorted((course / "data").glob("scene0*.txt")) if course and (course / "data").is_dir() else []
    ours = sorted((ROOT / "scenes").glob("*.txt"))
    if quick:
        return course_scenes[-1:] + [p for p in ours if p.stem in ("lamps", SINGLE_LIGHT_SCENE)]
    return course_scenes + ours


def render(path: Path, size: int, variants=(), **options) -> np.ndarray:
    """Renders with the active variant; ``options`` are :class:`RenderOptions` fields,
    ``variants`` :mod:`converters.scene_variants` functions applied in order."""
    description = apply(scene_dict(load_scene(path), RenderOptions(width=size, height=size, **options)), variants)
    return np.array(mi.render(load_scene_dict(description)), np.float32)[..., :3]


def agreement(path: Path, bounces: int, spp: int, size: int) -> Agreement:
    """whitted vs path restricted to Whitted's light paths: per-tile z-scores of their
    difference (same pixel samples) and relMSE against that of path vs path."""
    common = dict(bounces=bounces, shadows=True, spp=spp, jitter=True)
    whitted_paths = (without_ambient, without_background)
    path_only = (with_path_tracer, with_mirror_sampling)
    # whitted's course-compatible "skip hits within epsilon" is a different
    # visibility rule from the path tracer's; compare the light transport alone
    whitted = render(path, size, seed=1, variants=(*whitted_paths, without_ray_epsilon), **common)
    path_a = render(path, size, seed=1, variants=(*whitted_paths, *path_only), **common)
    path_b = render(path, size, seed=2, variants=(*whitted_paths, *path_only), **common)
    z = tile_z_scores(whitted - path_a, path_a)
    total_w, total_p = float(whitted.astype(np.float64).sum()), float(path_a.astype(np.float64).sum())
    d = (whitted.astype(np.float64) - path_a).sum(axis=-1).ravel()
    bias = total_w / total_p - 1.0 if total_p > 0 else 0.0
    bias_error = float(d.std(ddof=1) * math.sqrt(d.size) / total_p) if total_p > 0 else 0.0
    return Agreement(path.stem, bounces, spp, relmse(whitted, path_a), relmse(path_b, path_a),
                     max_abs_z=float(np.max(np.abs(z))) if z.size else 0.0,
                     z_critical=z_critical(int(z.size)), relative_bias=bias, relative_bias_stderr=bias_error)


@contextmanager
def biased_whitted(fraction: float):
    """Fault injection: whitted's local shading scaled by ``1 + fraction`` (for the
    active variant) while the context lasts. A check with power fails under it."""
    if mi.variant() is None:
        set_variant(None, quiet=True)
    cls = type(mi.load_dict({"type": "whitted"}))
    original = cls.shade

    def shade(self, *args, **kwargs):
        return original(self, *args, **kwargs) * (1.0 + fraction)

    cls.shade = shade
    try:
        yield
    finally:
        cls.shade = original


def run(course: Path | None, quick: bool, size: int | None = None, spps: list[int] | None = None,
        bounce_list: list[int] | None = None, paths: list[Path] | None = None, bsdf: bool = True,
        variant: str | None = None) -> dict:
    """All checks; ``size``/``spps``/``bounce_list``/``paths`` override the agreement's
    settings, ``bsdf=False`` skips the chi-square and furnace checks."""
    if variant is not None or mi.variant() is None:
        set_variant(variant, quiet=True)
    materials, angles = (QUICK_MATERIALS, QUICK_ANGLES) if quick else (MATERIALS, ANGLES)
    chi2 = [chi2_case(kd, ks, s, theta, sample_count=CHI2_SAMPLES[quick])
            for kd, ks, s in materials for theta in angles] if bsdf else []
    furnace = [furnace_case(kd, ks, s, theta, samples=1 << (16 if quick else 20))
               for kd, ks, s in materials for theta in angles] if bsdf else []
    default_size, default_spps, default_bounces = (48, [16, 64], [0, 2, 4]) if quick else (128, [64, 1024],
                                                                                          [0, 1, 2, 3, 4])
    size, spps, bounce_list = size or default_size, spps or default_spps, bounce_list or default_bounces
    rows = [agreement(p, b, spp, size) for p in (paths or scene_paths(course, quick))
            for b in bounce_list for spp in spps]
    return {"chi2": chi2, "furnace": furnace,
            "agreement": [dict(asdict(r), passed=r.passed) for r in rows],
            "settings": {"image_size": size, "spp": spps, "bounces": bounce_list, "quick": quick, "tile": TILE,
                         "significance": SIGNIFICANCE, "chi2_samples": CHI2_SAMPLES[quick],
                         "variant": mi.variant()}}


def failures(results: dict) -> list[str]:
    lines = [f"chi2 kd={c['kd']} ks={c['ks']} s={c['shininess']} theta={c['theta_deg']}: p={c['p_value']}"
             for c in results["chi2"] if not c["passed"]]
    lines += [f"furnace kd={c['kd']} ks={c['ks']} s={c['shininess']} theta={c['theta_deg']}: albedo "
              f"{c['albedo']:.4f} +- {c['stderr']:.4f}, integrated {c['expected']:.4f} (z = {c['z']:.1f})"
              for c in results["furnace"] if not c["passed"]]
    lines += [f"agreement {a['scene']} bounces={a['bounces']} spp={a['spp']}: max |z| {a['max_abs_z']:.1f} "
              f"(bound {a['z_critical']:.2f}), bias {round(100 * a['relative_bias'], 2) + 0.0:+.2f} % "
              f"+- {100 * a['relative_bias_stderr']:.2f} %, relMSE {a['relmse_whitted_path']:.3g} "
              f"vs 2 x {a['relmse_path_path']:.3g}"
              for a in results["agreement"] if not a["passed"]]
    return lines
