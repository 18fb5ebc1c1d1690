"""Inverse rendering through the ``whitted`` integrator: a Phong material and a
point light's position recovered from a target image by gradient descent.

The scene (:data:`SCENE`, the course's text format): a sphere of the material
being fitted on a floor of a known grey material, lit by one point light of
known colour. :data:`TRUTH` renders the target; :data:`START` is where the
fit begins. The fitted parameters (:func:`parameter_keys` finds their
``mi.traverse`` keys):

- ``diffuse`` and ``specular``: the sphere's phong ``diffuse_reflectance``
  and ``specular_reflectance`` (RGB), the course's ``kd`` and ``ks``;
- ``exponent``: its shininess ``s``;
- ``light``: the point light's ``position``.

:func:`fit_material_and_light` follows Mitsuba's inverse-rendering tutorials:
``mi.traverse`` exposes the parameters, ``mi.ad.Adam`` holds and updates
them, and each step renders with ``mi.render(scene, params)``, takes the
mean squared difference to the target and ``dr.backward`` sends its gradient
through whitted's shading and phong's ``eval`` to the parameters (visibility
is not differentiated: the floor's shadow moves with the light, its edge
gives no gradient). Pixels are sampled at their centres, so every render of
the same parameters is the same image and the loss can reach 0.

Recovered means (:func:`parameter_errors`, :data:`TOLERANCE`): each colour
channel and the exponent within 2 % of the truth, and the light within 1 %
of the scene's size (:func:`converters.description.view_scale`: how far the
camera looks).
"""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from converters.course_scene import parse_scene
from converters.description import RenderOptions, scene_dict, view_scale
from converters.to_mitsuba import load_scene_dict

#: the course scene; materials 1 (the sphere) and light 0 are fitted
SCENE = """
PerspectiveCamera {
    center 0 1.2 6.5
    direction 0 -0.2 -1
    up 0 1 0
    angle 32
}
Lights {
    numLights 1
    PointLight { position 2.5 4 3 color 1 1 1 falloff 0.04 }
}
Background { color 0 0 0 ambientLight 0 0 0 }
Materials {
    numMaterials 2
    Material { diffuseColor 0.6 0.6 0.6 }
    Material { diffuseColor 0.7 0.35 0.15 specularColor 0.5 0.45 0.4 shininess 40 }
}
Group {
    numObjects 2
    MaterialIndex 0
    Plane { normal 0 1 0 offset -1 }
    MaterialIndex 1
    Sphere { center 0 0 0 radius 1 }
}
"""
#: the fitted sphere's shape and the light, by the scene converter's names
SPHERE, LIGHT = "object_1", "light_0"
#: the phong parameter of each fitted material parameter
BSDF_PARAMETERS = {"diffuse": "diffuse_reflectance", "specular": "specular_reflectance",
                   "exponent": "exponent"}
#: the parameters of the target image (those of SCENE)
TRUTH = {"diffuse": [0.7, 0.35, 0.15], "specular": [0.5, 0.45, 0.4], "exponent": 40.0,
         "light": [2.5, 4.0, 3.0]}
#: where the fit starts: a grey material, a broad highlight, the light elsewhere
START = {"diffuse": [0.4, 0.4, 0.4], "specular": [0.2, 0.2, 0.2], "exponent": 12.0, "light": [1.0, 5.0, 1.5]}
#: recovery bounds: relative for the material, a fraction of view_scale for the light
TOLERANCE = {"diffuse": 0.02, "specular": 0.02, "exponent": 0.02, "light": 0.01}
#: Adam's learning rates, in each parameter's own unit (the light's: scene
#: units), the exponent's in that of its logarithm
LEARNING_RATES = {"diffuse": 0.01, "specular": 0.02, "exponent": 0.05, "light": 0.03}
#: the smallest colours a step may leave
LOWER = {"diffuse": 0.0, "specular": 0.0}


def scene_size() -> float:
    """The scene's size that the light's tolerance is a fraction of."""
    return view_scale(parse_scene(SCENE))


def make_scene(size: int):
    """The Mitsuba scene of :data:`SCENE` at ``size`` x ``size`` pixels, pixel
    centres, ray casting with shadows (the active variant must be a ``*_ad_*`` one)."""
    options = RenderOptions(width=size, height=size, spp=1, shadows=True, bounces=0, jitter=False)
    return load_scene_dict(scene_dict(parse_scene(SCENE), options))


def parameter_keys(scene, params) -> dict:
    """The ``params`` (``mi.traverse(scene)``) key of each fitted parameter: those
    of the BSDF that the sphere holds (materials have no name of their own in
    the scene), and the light's position."""
    bsdf = next(shape.bsdf() for shape in scene.shapes() if shape.id() == SPHERE)
    keys = {name: next(key for key in params.keys()
                       if key.rsplit(".", 1)[-1] == parameter and params.properties[key][2] is bsdf)
            for name, parameter in BSDF_PARAMETERS.items()}
    return dict(keys, light=f"{LIGHT}.position")


def read_parameters(scene, params) -> dict:
    """The fitted parameters' current values, as plain floats."""
    values = {name: [float(v) for v in np.array(params[key], np.float64).reshape(-1)]
              for name, key in parameter_keys(scene, params).items()}
    values["exponent"] = values["exponent"][0]
    return values


def write_parameters(scene, params, values: dict) -> None:
    """Sets the fitted parameters in ``params`` (``mi.traverse(scene)``) to ``values``."""
    kinds = {"diffuse": mi.Color3f, "specular": mi.Color3f, "exponent": mi.Float, "light": mi.Point3f}
    keys = parameter_keys(scene, params)
    for name, value in values.items():
        params[keys[name]] = kinds[name](value) if name != "exponent" else mi.Float(float(value))
        # kernel inputs, not constants: every value reuses the same kernels
        dr.make_opaque(params[keys[name]])
    params.update()


def render(scene, params=None, seed: int = 0) -> np.ndarray:
    """The scene's image (H, W, 3) as float32."""
    return np.array(mi.render(scene, params, spp=1, seed=seed), np.float32)[..., :3]


def parameter_errors(values: dict, truth: dict = TRUTH) -> dict:
    """Per parameter, the largest error against ``truth`` in the unit of
    :data:`TOLERANCE`: relative for colours and the exponent, the light's
    distance over :func:`scene_size`."""
    errors = {}
    for name in ("diffuse", "specular"):
        errors[name] = max(abs(v - t) / t for v, t in zip(values[name], truth[name]))
    errors["exponent"] = abs(values["exponent"] - truth["exponent"]) / truth["exponent"]
    errors["light"] = math.dist(values["light"], truth["light"]) / scene_size()
    return errors


def recovered(values: dict, truth: dict = TRUTH) -> dict:
    """Per parameter: whether it is within :data:`TOLERANCE` of ``truth``."""
    return {name: error <= TOLERANCE[name] for name, error in parameter_errors(values, truth).items()}


def fit_material_and_light(scene, target: np.ndarray, start: dict = START, iterations: int = 300,
                           learning_rates: dict = LEARNING_RATES, progress=None) -> list[dict]:
    """Fits the parameters of :func:`parameter_keys` in ``scene`` to ``target`` (H, W, 3)
    by Adam on the mean squared pixel difference, from ``start``, with
    constant learning rates (the renders have no noise: Adam's steps shrink
    by themselves near the minimum). Leaves ``scene`` at the fitted
    values and returns the history: for steps 0 (``start``) to ``iterations``
    (the fitted values) the parameter values rendered and their ``loss``.
    ``progress(step)`` is called after each step."""
    params = mi.traverse(scene)
    write_parameters(scene, params, start)
    keys = parameter_keys(scene, params)
    reference = mi.TensorXf(np.ascontiguousarray(target, np.float32))
    # the exponent through its logarithm (a latent variable): a step changes the
    # highlight's width by the same factor whether it is broad or narrow
    latent = {name: ("log_exponent" if name == "exponent" else key) for name, key in keys.items()}
    optimizer = mi.ad.Adam(lr=1.0)
    for name, key in keys.items():
        optimizer[latent[name]] = dr.log(params[key]) if name == "exponent" else params[key]
        optimizer.set_learning_rate({latent[name]: learning_rates[name]})

    def update_scene():
        for name, key in keys.items():
            if name in LOWER:  # the optimiser's own value: it can step back from the bound
                optimizer[latent[name]] = dr.maximum(optimizer[latent[name]], LOWER[name])
            value = optimizer[latent[name]]
            params[key] = dr.exp(value) if name == "exponent" else value
        params.update()

    update_scene()
    history = []
    for step in range(iterations + 1):
        values = read_parameters(scene, params)
        image = mi.render(scene, params, spp=1, seed=0)
        loss = dr.mean(dr.square(image[..., :3] - reference), axis=None)
        history.append(dict(values, step=step, loss=float(loss.array[0])))
        if step == iterations:
            break
        dr.backward(loss)
        optimizer.step()
        update_scene()
        if progress is not None:
            progress(step)
    return history
