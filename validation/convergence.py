"""Convergence of the two ways of rendering whitted's light transport: relMSE
against samples per pixel and render time.

Per scene (the course's and ours), the light transport of the course's ray
tracer (``whitted``'s light paths: direct light from every point light with
shadows, plus mirror recursion; ambient 0 and a background that emits
nothing, as in :mod:`validation.crossval`), computed two ways:

- ``whitted``: our integrator, every light evaluated at every hit, with
  jittered supersampling;
- ``path``: Mitsuba's path tracer on the same light paths (``phong`` with
  ``sampling="mirror"``): one light picked at random per hit.

Both are compared with **one common reference**: ``whitted`` converged
(many jittered spp, another seed). Errors are relMSE and mean FLIP
(:mod:`imaging.metrics`).

Fitting rule (fixed before any data was taken, the same for every curve):
``slope`` is the least-squares slope of log relMSE over log seconds, and
``spp_slope`` that over log spp, both fitted over the upper half of the spp
ladder (the points whose spp is at least the median spp of the curve; the
first renders are dominated by fixed per-render costs). Monte Carlo gives
``spp_slope`` = -1; ``slope`` approaches -1 as the fixed costs vanish.
``seconds_to_relmse_1e-3`` is read off that fitted line (extrapolated where
no render reached 1e-3). ``python -m benchmarks.error_vs_time`` runs it at
full size and plots it.
"""
from __future__ import annotations

import math
import time
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

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
from imaging.metrics import flip_error, relmse

ROOT = Path(__file__).resolve().parent.parent

#: The course's flags per course scene; ours render with 3 bounces and shadows
COURSE_FLAGS = {"scene06_bunny_1k": dict(bounces=4, shadows=False), "scene07_arch": dict(bounces=4, shadows=True)}
OWN_FLAGS = dict(bounces=3, shadows=True)
TARGET_RELMSE = 1e-3


def flags_for(path: Path) -> dict:
    if path.parent == ROOT / "scenes":
        return OWN_FLAGS
    return COURSE_FLAGS.get(path.stem, dict(bounces=0, shadows=False))


def method_options(method: str, path: Path) -> dict:
    """RenderOptions fields (beyond size, spp, seed) of a method, and under
    "variants" the :mod:`converters.scene_variants` functions it applies: both
    render whitted's light paths (shadows on, so the two have the same visibility)."""
    common = dict(jitter=True, bounces=flags_for(path)["bounces"], shadows=True)
    whitted_paths = (without_ambient, without_background)
    if method == "whitted":
        # the course's "skip hits within epsilon" is not the path tracer's visibility rule
        return dict(variants=(*whitted_paths, without_ray_epsilon), **common)
    if method == "path":
        return dict(variants=(*whitted_paths, with_path_tracer, with_mirror_sampling), **common)
    raise ValueError(method)


def render_timed(path: Path, size: int, spp: int, seed: int, options: dict) -> tuple[np.ndarray, float]:
    fields = {name: value for name, value in options.items() if name != "variants"}
    scene = load_scene_dict(apply(scene_dict(load_scene(path), RenderOptions(width=size, height=size, spp=spp,
                                                                            seed=seed, **fields)),
                                  options.get("variants", ())))
    mi.render(scene, spp=1)  # kernels compiled and cached before timing
    dr.sync_thread()
    start = time.perf_counter()
    image = mi.render(scene, spp=spp)  # (an spp argument sticks to the sampler: always pass it)
    dr.eval(image)
    dr.sync_thread()
    seconds = time.perf_counter() - start
    return np.array(image, np.float32)[..., :3], seconds


def fitted_points(points: list[dict]) -> list[dict]:
    """The fitting rule (module docstring): the points whose spp is at least the median spp."""
    usable = [p for p in points if p["relmse"] > 0 and p["seconds"] > 0]
    if not usable:
        return []
    median = float(np.median([p["spp"] for p in usable]))
    return [p for p in usable if p["spp"] >= median]


def fit_slope(points: list[dict]) -> tuple[float, float | None]:
    """Slope of log relMSE over log seconds (by :func:`fitted_points`) and the
    time at which the fitted line reaches TARGET_RELMSE (None: never)."""
    usable = fitted_points(points)
    if len(usable) < 2:
        return float("nan"), None
    x = np.log([p["seconds"] for p in usable])
    y = np.log([p["relmse"] for p in usable])
    slope, intercept = np.polyfit(x, y, 1)
    log_seconds = (math.log(TARGET_RELMSE) - intercept) / slope if slope < 0 else math.inf
    return float(slope), (math.exp(log_seconds) if log_seconds < 700 else None)


def fit_spp_slope(points: list[dict]) -> float:
    """Slope of log relMSE over log spp, over the same points (Monte Carlo: -1)."""
    usable = fitted_points(points)
    if len(usable) < 2:
        return float("nan")
    return float(np.polyfit(np.log([p["spp"] for p in usable]), np.log([p["relmse"] for p in usable]), 1)[0])


def measure(paths: list[Path], size: int, spp_by_method: dict[str, list[int]], reference_spp: int,
            progress=print) -> dict:
    """Curves per scene and method against one reference per scene (whitted, ``reference_spp``)."""
    points, slopes = [], []
    for path in paths:
        reference, _ = render_timed(path, size, reference_spp, 99, method_options("whitted", path))
        for method, spps in spp_by_method.items():
            options = method_options(method, path)
            curve = []
            for spp in spps:
                image, seconds = render_timed(path, size, spp, 1, options)
                curve.append({"scene": path.stem, "method": method, "spp": spp, "seconds": seconds,
                              "relmse": relmse(image, reference), "flip": flip_error(image, reference)})
            points += curve
            slope, to_target = fit_slope(curve)
            slopes.append({"scene": path.stem, "method": method, "slope": slope, "spp_slope": fit_spp_slope(curve),
                           "seconds_to_relmse_1e-3": to_target})
            progress(f"{path.stem} {method}: slope {slope:.2f} (per spp {slopes[-1]['spp_slope']:.2f}), "
                     "relMSE 1e-3 after "
                     f"{'n/a' if to_target is None else f'{to_target:.3g} s'}")
    return {"points": points, "slopes": slopes,
            "settings": {"image_size": size, "spp": spp_by_method, "reference_spp": reference_spp}}


def refit(results: dict) -> dict:
    """``results`` with its slopes fitted again from its points."""
    slopes = []
    for s in results["slopes"]:
        curve = [p for p in results["points"] if p["scene"] == s["scene"] and p["method"] == s["method"]]
        slope, to_target = fit_slope(curve)
        slopes.append(dict(s, slope=slope, spp_slope=fit_spp_slope(curve), **{"seconds_to_relmse_1e-3": to_target}))
    return dict(results, slopes=slopes)


def settings(quick: bool) -> tuple[int, dict, int]:
    """Image size, spp per method, and the spp of the common (whitted) reference."""
    if quick:
        return 32, {"whitted": [1, 4, 16, 64], "path": [4, 16, 64, 256]}, 2048
    return 96, {"whitted": [1, 2, 4, 8, 16, 32, 64, 128, 256], "path": [1, 4, 16, 64, 256, 1024, 4096]}, 4096
