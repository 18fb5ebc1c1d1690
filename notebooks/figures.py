"""Figures and fitted numbers that the notebooks show, made from the library's
renders and results (:mod:`validation.crossval`, :mod:`validation.convergence`,
:mod:`validation.inverse_rendering`)."""
from __future__ import annotations

import math
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from converters.scene_variants import (
    with_mirror_sampling,
    with_path_tracer,
    without_ambient,
    without_background,
    without_ray_epsilon,
)
from validation import convergence, crossval, inverse_rendering


def whitted_path_difference(path: Path, size: int, spp: int, bounces: int = 3) -> dict:
    """Renders of ``path`` (``size`` x ``size``, ``spp`` jittered samples, same seed):
    ``whitted`` and Mitsuba's ``path`` on Whitted's light paths (as the agreement
    check of :mod:`validation.crossval` renders them), and the full path tracer;
    with the mean of whitted - path over the image relative to path's mean, and
    its standard error (pixels are independent)."""
    common = dict(bounces=bounces, shadows=True, spp=spp, jitter=True, seed=1)
    whitted_paths = (without_ambient, without_background)
    whitted = crossval.render(path, size, variants=(*whitted_paths, without_ray_epsilon), **common)
    restricted = crossval.render(path, size, **common,
                                 variants=(*whitted_paths, with_path_tracer, with_mirror_sampling))
    full = crossval.render(path, size, variants=(with_path_tracer,), **dict(common, bounces=max(bounces, 6)))
    difference = whitted.astype(np.float64) - restricted
    per_pixel = difference.sum(axis=-1).ravel()
    total = float(restricted.astype(np.float64).sum(axis=-1).mean())
    return {"scene": path.stem, "size": size, "spp": spp, "whitted": whitted, "path": restricted,
            "full_path": full, "difference": difference,
            "relative_mean": float(per_pixel.mean() / total),
            "relative_stderr": float(per_pixel.std(ddof=1) / math.sqrt(per_pixel.size) / total)}


def plot_whitted_path_difference(renders: dict):
    """Four panels: whitted, path on Whitted's light paths, their difference
    (blue: path brighter, red: whitted brighter; the colour bar's range is the
    99.5th percentile of the difference), and the full path tracer."""
    difference = renders["difference"].mean(axis=-1)
    scale = max(float(np.percentile(np.abs(difference), 99.5)), 1e-6)
    fig, axes = plt.subplots(1, 4, figsize=(17, 4.6))
    shown = [("whitted (ambient 0, no background)", renders["whitted"]),
             ("path, Whitted's light paths", renders["path"]), (None, None),
             ("path, full Phong model + background light", renders["full_path"])]
    for ax, (title, image) in zip(axes, shown):
        if image is not None:
            ax.imshow(np.clip(image, 0, 1))
            ax.set_title(title, fontsize=9)
    picture = axes[2].imshow(difference, cmap="RdBu_r", vmin=-scale, vmax=scale)
    axes[2].set_title(f"whitted − path (mean {100 * renders['relative_mean']:+.3f} ± "
                      f"{100 * renders['relative_stderr']:.3f} %)", fontsize=9)
    fig.colorbar(picture, ax=axes[2], fraction=0.046, pad=0.02)
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle(f"{renders['scene']}: {renders['size']}×{renders['size']} pixels, {renders['spp']} spp")
    fig.tight_layout()
    return fig


def student_t_quantile(probability: float, dof: int) -> float:
    """The ``probability`` quantile (> 0.5) of Student's t with ``dof`` degrees of
    freedom: its density integrated numerically (Simpson, fine grid) and bisected."""
    def density(t):
        c = math.gamma((dof + 1) / 2) / (math.sqrt(dof * math.pi) * math.gamma(dof / 2))
        return c * (1 + t * t / dof) ** (-(dof + 1) / 2)

    def cdf(x: float) -> float:
        t = np.linspace(0.0, x, 20001)
        f = density(t)
        return 0.5 + (t[1] - t[0]) / 3 * (f[0] + f[-1] + 4 * f[1:-1:2].sum() + 2 * f[2:-1:2].sum())

    low, high = 0.0, 1000.0
    for _ in range(60):
        middle = (low + high) / 2
        low, high = (middle, high) if cdf(middle) < probability else (low, middle)
    return (low + high) / 2


def slope_interval(points: list[dict], level: float = 0.95) -> tuple[float, float, float]:
    """The slope of log relMSE over log seconds by :mod:`validation.convergence`'s
    fitting rule, and its ``level`` confidence interval (least squares, Student's t)."""
    usable = convergence.fitted_points(points)
    x = np.log([p["seconds"] for p in usable])
    y = np.log([p["relmse"] for p in usable])
    (slope, intercept), covariance = np.polyfit(x, y, 1, cov="unscaled")
    residual = y - (slope * x + intercept)
    dof = len(usable) - 2
    stderr = math.sqrt(float(residual @ residual) / dof * covariance[0, 0]) if dof > 0 else math.inf
    half = student_t_quantile(0.5 + level / 2, dof) * stderr if dof > 0 else math.inf
    return float(slope), float(slope - half), float(slope + half)


def plot_fit(history: list[dict], truth: dict = inverse_rendering.TRUTH):
    """The loss over the steps; every fitted value over its true value (converged:
    1); and each parameter's error against the truth in the unit of its
    tolerance (below the red line: recovered)."""
    steps = [h["step"] for h in history]
    fig, (ax_loss, ax_value, ax_error) = plt.subplots(1, 3, figsize=(17, 4.4))
    ax_loss.semilogy(steps, [h["loss"] for h in history])
    ax_loss.set(xlabel="step", ylabel="mean squared pixel difference", title="loss")
    channels = {"diffuse": "RGB", "specular": "RGB", "light": "xyz"}
    styles = {"diffuse": "-", "specular": "--", "exponent": "-", "light": ":"}
    colours = {"R": "tab:red", "G": "tab:green", "B": "tab:blue", "x": "tab:purple", "y": "tab:olive",
               "z": "tab:cyan"}
    for name, value in truth.items():
        for k, channel in enumerate(channels.get(name, [""])):
            true = value[k] if isinstance(value, list) else value
            fitted = [h[name][k] if isinstance(value, list) else h[name] for h in history]
            ax_value.plot(steps, [v / true for v in fitted], styles[name], lw=1.2,
                          color=colours.get(channel, "black"), label=f"{name} {channel}".strip())
    ax_value.axhline(1.0, color="grey", lw=0.8)
    ax_value.set(xlabel="step", ylabel="fitted / true value", title="parameters: value over the truth")
    ax_value.legend(fontsize=7, ncol=2)
    errors = [inverse_rendering.parameter_errors(h, truth) for h in history]
    for name, tolerance in inverse_rendering.TOLERANCE.items():
        unit = "of the scene's size" if name == "light" else "relative"
        ax_error.semilogy(steps, [max(e[name], 1e-7) / tolerance for e in errors],
                          label=f"{name} (tolerance {100 * tolerance:g} % {unit})")
    ax_error.axhline(1.0, color="red", lw=1)
    ax_error.set(xlabel="step", ylabel="error / tolerance", title="parameters: error against the truth")
    ax_error.legend(fontsize=8)
    for ax in (ax_loss, ax_value, ax_error):
        ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    return fig


def plot_images(images: dict):
    """Images side by side, titled by their keys, clipped to [0, 1]."""
    fig, axes = plt.subplots(1, len(images), figsize=(3.6 * len(images), 3.9))
    for ax, (title, image) in zip(axes, images.items()):
        ax.imshow(np.clip(image, 0, 1))
        ax.set_title(title, fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    return fig
