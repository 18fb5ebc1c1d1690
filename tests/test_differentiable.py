"""Gradients through the plugins: ``mi.traverse`` exposes phong's ``kd``, and
``dr.grad`` of a whitted image's mean with respect to it matches a central
finite difference.

The image mean is linear in ``kd`` (direct light, ambient and what mirrors
show of the material are all proportional to it), so the finite difference is
exact up to float32 rounding (measured: 3e-7 of the gradient); :data:`RTOL` is far
above that and far below what a wrong derivative does: a gradient only 1 % too
large fails (``test_a_wrong_gradient_fails``), as does one that misses the
diffuse term's ``kd``. With 2 bounces, 17 % of the gradient comes through the
mirrors (0.0375 against 0.0312 with ray casting), so the mirror loop's
derivative is checked too.
"""
from __future__ import annotations

from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from converters.course_scene import load_scene
from converters.description import RenderOptions, scene_dict
from converters.to_mitsuba import load_scene_dict

SCENE = Path(__file__).resolve().parent.parent / "scenes" / "mirrors.txt"
#: relative tolerance of the gradient against the finite difference
RTOL = 1e-4
#: finite-difference step on kd (the mean is linear in kd: no truncation error)
STEP = 0.05


def mirror_scene():
    """``mirrors.txt`` at 24x16 with 2 mirror bounces and shadows, and the key of a
    phong ``kd`` that is seen both directly and in the mirrors."""
    scene = load_scene_dict(scene_dict(load_scene(SCENE), RenderOptions(width=24, height=16, bounces=2,
                                                                        shadows=True)))
    params = mi.traverse(scene)
    keys = [k for k in params.keys() if k.endswith("diffuse_reflectance")]
    assert keys, "phong exposes no diffuse_reflectance"
    return scene, params, keys[0]


def gradient_and_finite_difference(scene, params, key) -> tuple[np.ndarray, np.ndarray]:
    kd = mi.Color3f(params[key])
    base = np.array(kd, np.float64).reshape(-1)
    dr.enable_grad(kd)
    params[key] = kd
    params.update()
    image = mi.render(scene, params, spp=1)
    dr.backward(dr.mean(image, axis=None))
    gradient = np.array(dr.grad(params[key]), np.float64).reshape(-1)

    def mean_at(value) -> float:
        color = mi.Color3f(*map(float, value))
        dr.make_opaque(color)  # one kernel for every value
        params[key] = color
        params.update()
        return float(np.mean(np.array(mi.render(scene, spp=1), np.float64)))

    dr.disable_grad(params[key])
    finite = np.zeros(3)
    for channel in range(3):
        step = np.eye(3)[channel] * STEP
        finite[channel] = (mean_at(base + step) - mean_at(base - step)) / (2 * STEP)
    params[key] = mi.Color3f(base)
    params.update()
    return gradient, finite


def test_traverse_exposes_the_plugins_parameters(variant_vectorised_rgb):
    scene, params, key = mirror_scene()
    material = key.rsplit(".", 1)[0]
    assert not params.flags(key) & mi.ParamFlags.NonDifferentiable
    assert not params.flags(f"{material}.specular_reflectance") & mi.ParamFlags.NonDifferentiable
    assert not params.flags(f"{material}.exponent") & mi.ParamFlags.NonDifferentiable
    for name in ("origin", "direction", "up", "fov"):
        assert f"sensor.{name}" in params or any(k.endswith(f".{name}") for k in params.keys())


def test_image_gradient_wrt_phong_kd_matches_finite_difference(variant_vectorised_rgb):
    scene, params, key = mirror_scene()
    gradient, finite = gradient_and_finite_difference(scene, params, key)
    assert np.all(finite > 1e-3), finite  # the material is visible: a real check
    np.testing.assert_allclose(gradient, finite, rtol=RTOL)


@pytest.mark.parametrize("mutation", ["no_diffuse_kd_derivative", "gradient_one_percent_high"])
def test_a_wrong_gradient_fails(variant_vectorised_rgb, monkeypatch, mutation):
    """Purpose-broken phong derivatives (the image itself unchanged) fail the check."""
    cls = type(mi.load_dict({"type": "phong"}))
    original = cls.eval

    def eval_with_wrong_derivative(self, ctx, si, wo, active=True):
        kd = self.kd
        if mutation == "no_diffuse_kd_derivative":
            self.kd = dr.detach(kd)
        else:
            self.kd = kd * 1.01 - dr.detach(kd) * 0.01  # same value, derivative x 1.01
        try:
            return original(self, ctx, si, wo, active)
        finally:
            self.kd = kd

    monkeypatch.setattr(cls, "eval", eval_with_wrong_derivative)
    scene, params, key = mirror_scene()
    gradient, finite = gradient_and_finite_difference(scene, params, key)
    with pytest.raises(AssertionError):
        np.testing.assert_allclose(gradient, finite, rtol=RTOL)
