"""The plugins one by one: phong BSDF, course camera, cube map, whitted's work."""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from converters.course_scene import load_scene
from validation.reference_tracer import ReferenceTracer, normalize

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


def test_cube_map_samples_directions_in_every_variant(variants_all_rgb):
    """The path tracer (the export's noisy beauty) samples the sky: a direction,
    its density and the radiance over it, in scalar variants too."""
    emitter = mi.load_dict({"type": "course_cubemap", "folder": str(ROOT / "scenes" / "tex" / "sky")})
    scene = mi.load_dict({"type": "scene", "sky": emitter})
    sky = scene.emitters()[0]
    it = dr.zeros(mi.Interaction3f)
    ds, weight = sky.sample_direction(it, mi.Point2f(0.3, 0.7))
    assert np.isclose(value(ds.pdf), 1 / (4 * np.pi), rtol=1e-5)
    assert np.allclose(value(weight), value(sky.lookup(ds.d)) * 4 * np.pi, rtol=1e-4)
    assert np.isclose(value(sky.pdf_direction(it, ds)), 1 / (4 * np.pi), rtol=1e-5)


# -- registration, scene analysis, fixtures -------------------------------------------
def test_plugin_classes_follow_the_variant(variant_vectorised_rgb):
    """Each variant has its own classes, built once: a class obtained earlier is
    never replaced under its holder, and the factory always builds the active
    variant's (the old registration reloaded the modules on a switch)."""
    from conftest import _set

    import mi_plugins

    vectorised = type(mi.load_dict({"type": "phong"}))
    _set("scalar_rgb")
    scalar = type(mi.load_dict({"type": "phong"}))
    assert scalar is not vectorised and scalar is mi_plugins.plugin_class("phong")
    assert issubclass(scalar, mi.BSDF) and not issubclass(vectorised, mi.BSDF)
    _set("llvm_ad_rgb")
    assert type(mi.load_dict({"type": "phong"})) is vectorised is mi_plugins.plugin_class("phong")
    assert issubclass(vectorised, mi.BSDF)
    for name in mi_plugins.PLUGINS:
        assert mi_plugins.plugin_class(name).__module__ == f"mi_plugins.{mi_plugins.PLUGINS[name][0]}"


def test_whitted_refuses_max_depth(variant_vectorised_rgb):
    with pytest.raises(Exception, match="bounces"):
        mi.load_dict({"type": "whitted", "max_depth": 2})
    assert mi.load_dict({"type": "whitted", "bounces": 2}).bounces == 2


def _mirror_scene(ks: float) -> mi.Scene:
    """A sphere before a red wall, lit from the camera: with ks > 0 it mirrors the wall."""
    return mi.load_dict({
        "type": "scene", "integrator": {"type": "whitted", "bounces": 1},
        "sensor": {"type": "course_camera", "origin": [0, 0, 4], "fov": 40,
                   "film": {"type": "hdrfilm", "width": 12, "height": 12, "rfilter": {"type": "box"}}},
        "ball": {"type": "sphere", "bsdf": {"type": "phong", "specular_reflectance": {"type": "rgb", "value": ks}}},
        "wall": {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0, 0, 6]).scale(10),
                 "flip_normals": True,
                 "bsdf": {"type": "phong", "diffuse_reflectance": {"type": "rgb", "value": [1, 0, 0]}}},
        "light": {"type": "point", "position": [0, 0, 4], "intensity": {"type": "rgb", "value": 20}},
    })


def _renews_its_analysis() -> bool:
    """Whether a ks changed through ``mi.traverse`` after a render switches whitted's
    mirror recursion on (the image then equals a scene loaded with that ks)."""
    scene = _mirror_scene(0.0)
    before = np.array(mi.render(scene))
    params = mi.traverse(scene)
    key = next(k for k in params.keys() if k.endswith("specular_reflectance") and "ball" in k)
    params[key] = mi.Color3f(0.8)
    params.update()
    after = np.array(mi.render(scene))
    expected = np.array(mi.render(_mirror_scene(0.8)))
    assert not np.allclose(expected, before)  # the mirror shows in the image
    return bool(np.allclose(after, expected, atol=1e-6))


def test_whitted_analysis_follows_parameter_updates(variant_vectorised_rgb, monkeypatch):
    assert _renews_its_analysis()
    # purpose-broken: an analysis kept across renders misses the new mirror lobe
    cls = type(mi.load_dict({"type": "whitted"}))
    monkeypatch.setattr(cls, "render", lambda self, scene, *args, **kwargs:
                        mi.SamplingIntegrator.render(self, scene, *args, **kwargs))
    assert not _renews_its_analysis()


def _own_lights_every_time() -> bool:
    import gc

    integrator = mi.load_dict({"type": "whitted"})
    own = True
    for lights in (1, 3, 2):
        scene = mi.load_dict({"type": "scene", "ball": {"type": "sphere"},
                              **{f"light_{k}": {"type": "point", "position": [k, 2, 3]} for k in range(lights)}})
        own &= integrator.delta_lights(scene) == scene.emitters()
        del scene
        gc.collect()
    return own


def test_whitted_analysis_is_never_another_scenes(variant_vectorised_rgb, monkeypatch):
    """An analysis holds its scene's shapes and emitters, so a scene built after
    another was freed (perhaps at its address) gets its own lights."""
    import mi_plugins

    assert _own_lights_every_time()
    # purpose-broken: an analysis that takes any scene for its own (as one keyed on a reused id would)
    monkeypatch.setattr(mi_plugins.plugin_module("whitted").SceneAnalysis, "belongs_to", lambda self, scene: True)
    assert not _own_lights_every_time()


def _teardown_works(monkeypatch, broken: bool) -> bool:
    import conftest
    import drjit as dr

    if broken:
        monkeypatch.setattr(conftest, "_clean_up", lambda previous: None)
    fixture = conftest._variant_fixture("scalar_rgb")
    assert next(fixture) == "scalar_rgb" == mi.variant()
    dr.set_flag(dr.JitFlag.SymbolicLoops, False)  # what a test might leave behind
    next(fixture, None)
    restored = mi.variant() == "llvm_ad_rgb" and dr.flag(dr.JitFlag.SymbolicLoops)
    dr.set_flag(dr.JitFlag.SymbolicLoops, True)
    conftest._set("llvm_ad_rgb")
    return restored


def test_variant_fixtures_restore_the_variant_and_flags(variant_vectorised_rgb, monkeypatch):
    assert _teardown_works(monkeypatch, broken=False)
    assert not _teardown_works(monkeypatch, broken=True)  # the check can fail


def _camera_follows_its_parameters(monkeypatch, broken: bool) -> bool:
    sensor = mi.load_dict({"type": "course_camera", "film": {"type": "hdrfilm", "width": 5, "height": 5}})
    if broken:  # purpose-broken: a camera that ignores parameter updates
        monkeypatch.setattr(type(sensor), "parameters_changed", lambda self, keys=[]: None)
    params = mi.traverse(sensor)
    params["origin"] = mi.Point3f(1, 2, 3)
    params["direction"] = mi.Vector3f(1, 0, 0)
    params["fov"] = mi.Float(90.0)
    params.update()
    ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(0.99, 0.5), mi.Point2f(0.5))  # right edge, middle row
    # x = +1 at the right edge: direction normalize(D / tan(45 deg) + H) with H = D x up = (0, 0, 1)
    return (np.allclose(value(ray.o), [1, 2, 3], atol=1e-6)
            and np.allclose(value(ray.d), np.array([1, 0, 1]) / np.sqrt(2), atol=1e-6))


def test_camera_parameters_are_exposed_and_followed(variant_vectorised_rgb, monkeypatch):
    """(Vectorised variants: in scalar ones the float ``fov`` of a Python plugin is
    a Python float, which ``mi.traverse`` cannot write.)"""
    assert _camera_follows_its_parameters(monkeypatch, broken=False)
    assert not _camera_follows_its_parameters(monkeypatch, broken=True)
