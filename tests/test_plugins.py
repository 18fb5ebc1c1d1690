"""The plugins one by one: phong BSDF, course camera, cube map, whitted's work."""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from benchmarks.reference_tracer import ReferenceTracer, normalize
from converters.course_scene import load_scene

ROOT = __import__("pathlib").Path(__file__).resolve().parent.parent


def phong(kd=(0.6, 0.4, 0.2), ks=(0.5, 0.5, 0.5), s=20.0):
    return mi.load_dict({"type": "phong", "diffuse_reflectance": {"type": "rgb", "value": list(kd)},
                         "specular_reflectance": {"type": "rgb", "value": list(ks)}, "exponent": s})


def interaction(wi):
    si = dr.zeros(mi.SurfaceInteraction3f)
    si.wi = mi.Vector3f(wi)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    si.n = mi.Vector3f(0, 0, 1)
    return si


def value(x):
    return np.array(x, np.float64).ravel()


@pytest.mark.parametrize("s", [0.0, 1.0, 20.0, 500.0])
def test_phong_eval_is_the_course_formula(variants_all_rgb, s):
    kd, ks = np.array([0.6, 0.4, 0.2]), np.array([0.5, 0.3, 0.9])
    bsdf = phong(kd, ks, s)
    wi = normalize(np.array([0.3, -0.2, 0.9]))
    for wo in [normalize(np.array(v, float)) for v in ([0.1, 0.5, 0.8], [-0.3, 0.2, 0.5], [0.9, 0, 0.05])]:
        got = value(bsdf.eval(mi.BSDFContext(), interaction(wi), mi.Vector3f(wo))) * np.pi
        r = np.array([-wi[0], -wi[1], wi[2]])
        spec = 1.0 if s == 0 else max(r @ wo, 0.0) ** s
        assert np.allclose(got, kd * max(wo[2], 0) + ks * spec, rtol=1e-5, atol=1e-6)


def test_phong_sample_reports_its_pdf(variant_vectorised_rgb):
    """``sample`` returns the density that ``pdf`` gives for the direction it drew, and
    finite weights. (Whether that density is the one directions are drawn from is what
    the chi-square test checks; whether weights integrate what ``eval`` integrates,
    ``tests/test_mutations.py::test_sampling_matches_eval``.)"""
    bsdf = phong(s=30.0)
    n = 4096
    rng = np.random.default_rng(1)
    si = interaction(mi.Vector3f(normalize(np.array([0.4, 0.1, 0.8]))))
    ctx = mi.BSDFContext()
    bs, weight = bsdf.sample(ctx, si, mi.Float(rng.random(n)), mi.Point2f(rng.random(n), rng.random(n)))
    pdf = bsdf.pdf(ctx, si, bs.wo)
    ok = value(bs.pdf) > 0
    assert ok.mean() > 0.95
    assert np.allclose(value(bs.pdf)[ok], value(pdf)[ok], rtol=1e-4)
    assert np.all(np.isfinite(np.array(weight)))


def test_phong_mirror_lobe(variants_all_rgb):
    bsdf = phong(ks=(0.9, 0.8, 0.7))
    ctx = mi.BSDFContext(mi.TransportMode.Radiance, +mi.BSDFFlags.DeltaReflection)
    bs, weight = bsdf.sample(ctx, interaction(mi.Vector3f(0.6, 0, 0.8)), 0.5, mi.Point2f(0.5, 0.5))
    assert np.allclose(value(bs.wo), [-0.6, 0, 0.8], atol=1e-6)
    assert np.allclose(value(weight), [0.9, 0.8, 0.7], atol=1e-6)
    assert mi.has_flag(bsdf.flags(), mi.BSDFFlags.DeltaReflection)
    assert not mi.has_flag(phong(ks=(0, 0, 0)).flags(), mi.BSDFFlags.DeltaReflection)
    params = mi.traverse(bsdf)
    assert "diffuse_reflectance" in params and "specular_reflectance" in params


def test_course_camera_rays(variants_all_rgb):
    scene = load_scene(ROOT / "scenes" / "transforms.txt")
    reference_o, reference_d = ReferenceTracer(scene).camera_rays(7, 4)
    cam = scene.camera
    sensor = mi.load_dict({"type": "course_camera", "origin": list(cam.center), "direction": list(cam.direction),
                           "up": list(cam.up), "fov": cam.angle,
                           "film": {"type": "hdrfilm", "width": 7, "height": 4}})
    for k, d in enumerate(reference_d):
        i, j = k % 7, k // 7
        # any position inside the pixel gives the pixel centre's ray
        ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f((i + 0.9) / 7, (j + 0.2) / 4), mi.Point2f(0.5))
        assert np.allclose(value(ray.d), d, atol=1e-6)
        assert np.allclose(value(ray.o), reference_o[k], atol=1e-6)


def test_cube_map_lookup_matches_reference(variants_all_rgb):
    folder = ROOT / "scenes" / "tex" / "sky"
    emitter = mi.load_dict({"type": "course_cubemap", "folder": str(folder)})
    scene = load_scene(ROOT / "scenes" / "mirrors.txt")
    reference = ReferenceTracer(scene)
    rng = np.random.default_rng(3)
    dirs = normalize(rng.normal(size=(64, 3)))
    dirs[:6] = [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]]
    expected = reference.cube_lookup(dirs)
    for d, e in zip(dirs, expected):
        assert np.allclose(value(emitter.lookup(mi.Vector3f(d))), e, atol=1e-5)
