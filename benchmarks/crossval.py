"""Cross-validation of the renderer against Mitsuba's own machinery.

    python -m benchmarks.crossval [--json PATH] [--quick]

1. The ``phong`` BSDF passes Mitsuba's chi-square test (``mitsuba.chi2``)
   on a grid of kd/ks/shininess and incident angles, and a white furnace
   (Monte Carlo albedo from its own sampling) never exceeds 1 where
   ``kd + ks <= 1`` and the shininess is at least 1.
2. For every course scene and each of ours, with ambient 0 and a background
   that emits nothing, ``whitted`` at bounces 0..4 agrees with Mitsuba's
   ``path`` integrator restricted to the same light paths (``phong`` with
   ``sampling="mirror"``): with the same jittered pixel sampling and spp, the
   relative MSE between them is at most twice that between two path renders
   with different seeds, at 64 and at 1024 spp.

Exits non-zero if any criterion fails. The notebook ``notebooks/crossval.ipynb``
calls the same functions.
"""
from __future__ import annotations

import argparse
import math
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from benchmarks import write_json
from benchmarks.course import DEFAULT_COURSE, ROOT

#: (kd, ks, shininess) combinations for the BSDF checks
MATERIALS = [(0.5, 0.5, 1.0), (0.8, 0.2, 20.0), (0.2, 0.8, 500.0), (0.0, 1.0, 1000.0), (1.0, 0.0, 20.0),
             (0.3, 0.6, 5.0), (0.1, 0.9, 100.0), (0.6, 0.4, 2000.0)]
#: incident angles (degrees from the normal)
ANGLES = [0.0, 45.0, 85.0]
QUICK_MATERIALS = [(0.5, 0.5, 1.0), (0.2, 0.8, 500.0), (0.1, 0.9, 100.0), (0.6, 0.4, 2000.0)]
QUICK_ANGLES = [10.0, 85.0, 60.0]


def relmse(image: np.ndarray, reference: np.ndarray, epsilon: float = 1e-2) -> float:
    """Relative mean squared error, ``mean((x - ref)^2 / (ref^2 + eps))``."""
    image, reference = np.asarray(image, np.float64), np.asarray(reference, np.float64)
    return float(np.mean((image - reference) ** 2 / (reference ** 2 + epsilon)))


def _phong(kd, ks, s, sampling="phong") -> dict:
    return {"type": "phong", "diffuse_reflectance": {"type": "rgb", "value": [kd] * 3},
            "specular_reflectance": {"type": "rgb", "value": [ks] * 3}, "exponent": s, "sampling": sampling}


def chi2_case(kd: float, ks: float, shininess: float, theta: float, sample_count: int = 1_000_000) -> dict:
    """Mitsuba's chi-square test of the phong BSDF's sampling against its pdf."""
    from mitsuba.chi2 import BSDFAdapter, ChiSquareTest, SphericalDomain

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


def furnace_albedo(kd: float, ks: float, shininess: float, theta: float, samples: int = 1 << 20) -> tuple[float, float]:
    """Monte Carlo directional albedo (mean, standard error) from the BSDF's own sampling."""
    import drjit as dr
    import mitsuba as mi

    bsdf = mi.load_dict(_phong(kd, ks, shininess))
    rng = np.random.default_rng(7)
    si = dr.zeros(mi.SurfaceInteraction3f, samples)
    si.wi = mi.Vector3f(math.sin(math.radians(theta)), 0.0, math.cos(math.radians(theta)))
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    _, weight = bsdf.sample(mi.BSDFContext(), si, mi.Float(rng.random(samples)),
                            mi.Point2f(rng.random(samples), rng.random(samples)))
    values = np.array(weight, np.float64)[0]
    return float(values.mean()), float(values.std() / math.sqrt(samples))


@dataclass
class Agreement:
    scene: str
    bounces: int
    spp: int
    relmse_whitted_path: float
    relmse_path_path: float

    @property
    def passed(self) -> bool:
        return self.relmse_whitted_path <= 2.0 * self.relmse_path_path


def scene_paths(course: Path | None = DEFAULT_COURSE, quick: bool = False) -> list[Path]:
    """The course scenes (if present) and ours."""
    course_scenes = sorted((course / "data").glob("scene0*.txt")) if course and (course / "data").is_dir() else []
    ours = sorted((ROOT / "scenes").glob("*.txt"))
    if quick:
        return course_scenes[-1:] + ours[:1] + ours[2:3]
    return course_scenes + ours


def render(path: Path, size: int, **options) -> np.ndarray:
    """Renders with the active variant; ``options`` are :class:`RenderOptions` fields."""
    import mitsuba as mi

    from converters.course_scene import load_scene
    from converters.to_mitsuba import RenderOptions, load_scene_dict, scene_dict

    description = scene_dict(load_scene(path), RenderOptions(width=size, height=size, **options))
    return np.array(mi.render(load_scene_dict(description)), np.float32)[..., :3]


def agreement(path: Path, bounces: int, spp: int, size: int) -> Agreement:
    """whitted vs path restricted to Whitted's light paths, against path vs path."""
    common = dict(bounces=bounces, shadows=True, spp=spp, jitter=True, ambient=False, background=False)
    path_only = dict(integrator="path", phong_sampling="mirror")
    # whitted's course-compatible "skip hits within epsilon" is a different
    # visibility rule from the path tracer's; compare the light transport alone
    whitted = render(path, size, seed=1, ray_epsilon=False, **common)
    path_a = render(path, size, seed=1, **common, **path_only)
    path_b = render(path, size, seed=2, **common, **path_only)
    return Agreement(path.stem, bounces, spp, relmse(whitted, path_a), relmse(path_b, path_a))


def run(course: Path | None, quick: bool) -> dict:
    from renderer.variants import set_variant

    set_variant(None, quiet=True)
    materials, angles = (QUICK_MATERIALS, QUICK_ANGLES) if quick else (MATERIALS, ANGLES)
    chi2 = [chi2_case(kd, ks, s, theta, sample_count=200_000 if quick else 1_000_000)
            for kd, ks, s in materials for theta in angles]
    furnace = []
    for kd, ks, s in materials:
        for theta in angles:
            mean, error = furnace_albedo(kd, ks, s, theta, samples=1 << (16 if quick else 20))
            furnace.append({"kd": kd, "ks": ks, "shininess": s, "theta_deg": theta, "albedo": mean,
                            "stderr": error, "passed": mean <= 1.0 + 4 * error})
    size, spps, bounce_list = (48, [16, 64], [0, 2, 4]) if quick else (128, [64, 1024], [0, 1, 2, 3, 4])
    rows = [agreement(p, b, spp, size) for p in scene_paths(course, quick) for b in bounce_list for spp in spps]
    return {"chi2": chi2, "furnace": furnace,
            "agreement": [dict(asdict(r), passed=r.passed) for r in rows],
            "settings": {"image_size": size, "spp": spps, "bounces": bounce_list, "quick": quick}}


def failures(results: dict) -> list[str]:
    lines = [f"chi2 kd={c['kd']} ks={c['ks']} s={c['shininess']} theta={c['theta_deg']}: p={c['p_value']}"
             for c in results["chi2"] if not c["passed"]]
    lines += [f"furnace kd={c['kd']} ks={c['ks']} s={c['shininess']}: albedo {c['albedo']:.4f}"
              for c in results["furnace"] if not c["passed"]]
    lines += [f"agreement {a['scene']} bounces={a['bounces']} spp={a['spp']}: "
              f"{a['relmse_whitted_path']:.3g} > 2 x {a['relmse_path_path']:.3g}"
              for a in results["agreement"] if not a["passed"]]
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.crossval", description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", type=Path, metavar="PATH", help="write the numbers as JSON")
    parser.add_argument("--quick", action="store_true", help="a small version (CI)")
    parser.add_argument("--course", type=Path, default=DEFAULT_COURSE, help="course folder (default ../shared/course)")
    args = parser.parse_args(argv)
    results = run(args.course, args.quick)
    if args.json:
        write_json(args.json, results)
    failed = failures(results)
    print(f"chi2: {sum(c['passed'] for c in results['chi2'])}/{len(results['chi2'])} passed; "
          f"furnace: {sum(c['passed'] for c in results['furnace'])}/{len(results['furnace'])}; "
          f"agreement: {sum(a['passed'] for a in results['agreement'])}/{len(results['agreement'])}")
    for line in failed:
        print("FAILED " + line, file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())


# -- presentation (used by the notebook and the README report) -----------------
def summary_table(results: dict) -> str:
    """Markdown tables of the chi-square tests, the furnace and the agreement."""
    lines = ["| kd | ks | shininess | θi | χ² p-value | albedo | passed |", "|---|---|---|---|---|---|---|"]
    for c, f in zip(results["chi2"], results["furnace"]):
        lines.append(f"| {c['kd']} | {c['ks']} | {c['shininess']:g} | {c['theta_deg']:g}° | {c['p_value']:.3f} | "
                     f"{f['albedo']:.3f} ± {f['stderr']:.3f} | {'yes' if c['passed'] and f['passed'] else 'NO'} |")
    lines += ["", "| scene | bounces | spp | relMSE(whitted, path) | relMSE(path, path') | ratio | passed |",
              "|---|---|---|---|---|---|---|"]
    for a in results["agreement"]:
        ratio = a["relmse_whitted_path"] / a["relmse_path_path"] if a["relmse_path_path"] else float("nan")
        lines.append(f"| {a['scene']} | {a['bounces']} | {a['spp']} | {a['relmse_whitted_path']:.2e} | "
                     f"{a['relmse_path_path']:.2e} | {ratio:.2f} | {'yes' if a['passed'] else 'NO'} |")
    return "\n".join(lines)


def plot_agreement(results: dict):
    """relMSE(whitted, path) / relMSE(path, path') per scene and bounce count (pass: below 2)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = results["agreement"]
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    spps = sorted({r["spp"] for r in rows})
    fig, axes = plt.subplots(1, len(spps), figsize=(6 * len(spps), 4), squeeze=False)
    for ax, spp in zip(axes[0], spps):
        for bounces in sorted({r["bounces"] for r in rows}):
            ratios = [next((r["relmse_whitted_path"] / r["relmse_path_path"] for r in rows
                            if r["scene"] == s and r["spp"] == spp and r["bounces"] == bounces), np.nan)
                      for s in scenes]
            ax.plot(range(len(scenes)), ratios, "o", label=f"{bounces} bounces")
        ax.axhline(2.0, color="red", lw=1, label="criterion")
        ax.set_xticks(range(len(scenes)), scenes, rotation=45, ha="right")
        ax.set(ylabel="relMSE(whitted, path) / relMSE(path, path')", title=f"{spp} spp", ylim=(0, 2.5))
        ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def plot_light_paths(path: Path, size: int = 160, spp: int = 64, bounces: int = 3):
    """Whitted, the path tracer on Whitted's light paths, and the full path tracer."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    common = dict(bounces=bounces, shadows=True, spp=spp, jitter=True)
    images = {
        "whitted (ambient 0, no background)": render(path, size, ambient=False, background=False, **common),
        "path, Whitted's light paths": render(path, size, ambient=False, background=False, integrator="path",
                                              phong_sampling="mirror", **common),
        "path, full Phong model + background light": render(path, size, integrator="path",
                                                            **dict(common, bounces=max(bounces, 6))),
    }
    fig, axes = plt.subplots(1, 3, figsize=(12, 4.4))
    for ax, (title, image) in zip(axes, images.items()):
        ax.imshow(np.clip(image, 0, 1))
        ax.set_title(title, fontsize=9)
        ax.axis("off")
    fig.suptitle(path.stem)
    fig.tight_layout()
    return fig
