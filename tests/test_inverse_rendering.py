"""Inverse rendering through whitted (``validation.inverse_rendering``): the fit
recovers the sphere's Phong material and the light's position from the target
image within the tolerances, and misses them when one parameter's derivative
is lost.

A lost derivative is what a real bug does here: an exponent read as a kernel
constant (phong's path for plain renders), or a light whose position is not
traced into the shading. The fit then leaves that parameter at its start
(exponent 12 against 40: 70 % off) or lets the others make up for it; the
tolerances (2 %, 1 % of the scene's size) are far from either, and far above
what a noise-free fit reaches (docs/notebooks.md has its errors).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from validation import inverse_rendering as ir

#: the quick size: 48x48 pixels, 250 steps
SIZE, STEPS = 48, 250
#: exponent derivative against a central finite difference of step 1 (s = 40):
#: above the difference's truncation and float32 error, far below a missing derivative
RTOL = 1e-2


def fitted(size: int = SIZE, steps: int = STEPS) -> dict:
    scene = ir.make_scene(size)
    target = ir.render(scene)
    return ir.fit_material_and_light(scene, target, iterations=steps)[-1]


def test_exponent_derivative_matches_finite_difference(variant_vectorised_rgb):
    """phong's exponent, differentiated while its gradient is enabled: d(mean image)/ds."""
    scene = ir.make_scene(24)
    params = mi.traverse(scene)
    key = ir.parameter_keys(scene, params)["exponent"]
    exponent = mi.Float(40.0)
    dr.enable_grad(exponent)
    params[key] = exponent
    params.update()
    dr.backward(dr.mean(mi.render(scene, params, spp=1), axis=None))
    gradient = float(dr.grad(params[key])[0])

    def mean_at(value: float) -> float:
        ir.write_parameters(scene, params, {"exponent": value})
        return float(np.mean(ir.render(scene)))

    finite = (mean_at(40.5) - mean_at(39.5)) / 1.0
    assert abs(finite) > 1e-6  # the highlight is in view: a real check
    assert gradient == pytest.approx(finite, rel=RTOL)


def test_plain_renders_keep_the_constant_exponent(variant_vectorised_rgb):
    """Without gradients the exponent stays a kernel constant (the course's images,
    bit for bit); an exponent being differentiated gives the same image to float32 rounding."""
    scene = ir.make_scene(24)
    params = mi.traverse(scene)
    key = ir.parameter_keys(scene, params)["exponent"]
    bsdf = params.properties[key][2]
    assert isinstance(bsdf.eval_exponent, float)
    plain = ir.render(scene)
    dr.enable_grad(params[key])
    params.update()
    assert not isinstance(bsdf.eval_exponent, float)
    np.testing.assert_allclose(ir.render(scene), plain, rtol=1e-5, atol=1e-7)


@pytest.mark.slow
def test_the_fit_recovers_material_and_light(variant_vectorised_rgb):
    values = fitted()
    assert ir.recovered(values) == {name: True for name in ir.TOLERANCE}, ir.parameter_errors(values)


@pytest.mark.slow
@pytest.mark.parametrize("lost", ["exponent", "light"])
def test_a_lost_derivative_misses_the_tolerances(variant_vectorised_rgb, monkeypatch, lost):
    """The same fit with one parameter's derivative detached (its values unchanged)."""
    if lost == "exponent":
        cls = type(mi.load_dict({"type": "phong"}))
        original = cls.eval

        def eval_detached(self, ctx, si, wo, active=True):
            exponent = self.eval_exponent
            self.eval_exponent = dr.detach(exponent) if not isinstance(exponent, float) else exponent
            try:
                return original(self, ctx, si, wo, active)
            finally:
                self.eval_exponent = exponent

        monkeypatch.setattr(cls, "eval", eval_detached)
    else:
        cls = type(mi.load_dict({"type": "whitted"}))
        original = cls.lit_by

        def lit_by_detached(self, scene, si, bsdf, hit, target, direction, distance, valid, radiance, *args,
                            **kwargs):
            return original(self, scene, si, bsdf, hit, dr.detach(target), dr.detach(direction),
                            dr.detach(distance), valid, dr.detach(radiance), *args, **kwargs)

        monkeypatch.setattr(cls, "lit_by", lit_by_detached)
    values = fitted()
    assert not ir.recovered(values)[lost], ir.parameter_errors(values)
