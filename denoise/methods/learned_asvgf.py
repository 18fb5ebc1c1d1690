"""asvgf with a trained per-pixel network that steers its filter: ``learned-asvgf``.

The temporal step is asvgf's (:func:`denoise.methods.asvgf.temporal_accumulation`,
unchanged, with its fitted parameters). Then, per pixel, a small multilayer
perceptron reads what that step knows (:data:`FEATURES`: the history length,
the temporal gradient λ, whether the history was lost, how far the current
frame and the fast history lie from the slow one, how much the slow history
was clipped, the relative noise) and gives three numbers
(:data:`OUTPUTS`):

- ``sigma_first``, ``sigma_coarse``: the luminance weight's σ of the first
  À-Trous level and of the coarser ones (the wide level included), as
  asvgf's fitted σ times ``exp(2 tanh(o / 2))`` (a factor from e⁻² to e²);
- ``wide_blend``: the blend between the wide level and the last regular one,
  ``sigmoid(logit(asvgf's blend) + o)``.

How much of the history to trust is asvgf's own (its λ and clips): a
fourth output that blended the fast history into the slow one, trained so,
lowered the error on the held-out training sequences and raised it frame
after frame on scenes it had not seen (``docs/learned_asvgf.md``).

With the output layer at 0 the method is asvgf with a wide blend within 1 %
of asvgf's; the trained weights (``denoise/learned_asvgf.json``, written by
``python -m denoise.train``) start there. The network costs one pass of
per-pixel arithmetic (no gathers): with 8 inputs and 12 hidden units about
150 multiply-adds per pixel, against asvgf's 24 taps per level.

The network is plain Dr.Jit arithmetic on per-pixel Floats of the active
variant, its weights Python floats (constants in the kernels). The trainer
(:mod:`denoise.training`) runs the same perceptron in NumPy instead and
makes its outputs the leaves of Dr.Jit's differentiation, the chain rule
through the perceptron NumPy's: the kernels then hold no weights and are
compiled once, not at every step. The features are detached: the gradient reaches the outputs
through the filter and, by the slow history the first level feeds back,
through the frames after.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

from ..filters import FrameArrays, luminance
from ..svgf_common import atrous_level, levels_for
from .asvgf import ASVGFHistory, ASVGFParams, FilterValues, temporal_accumulation, variance
from .trained import TrainedMethod
from .weights_file import bad_weights, check_count, check_names, open_weights, weight_arrays

#: the network's inputs, in order: a weights file names the ones it was trained on
FEATURES = ("inverse_length", "gradient", "disoccluded", "current_change", "fast_slow", "slow_clip", "noise")
#: the inputs that come from the history (the "no temporal inputs" ablation drops them)
TEMPORAL_FEATURES = ("inverse_length", "gradient", "disoccluded", "current_change", "fast_slow", "slow_clip")
#: the network's outputs, in order
OUTPUTS = ("sigma_first", "sigma_coarse", "wide_blend")
#: the file format's name, in every weights file
FORMAT = "learned-asvgf-mlp"
#: the command that writes the weights files
TRAIN_COMMAND = "python -m denoise.train"
WEIGHTS_DIR = Path(__file__).resolve().parents[1]
#: the trained network, and the two ablations the benchmark runs beside it
WEIGHTS_FILE = WEIGHTS_DIR / "learned_asvgf.json"
ABLATIONS = {"no-temporal-inputs": WEIGHTS_DIR / "learned_asvgf_no_temporal.json",
             "half-hidden": WEIGHTS_DIR / "learned_asvgf_half_hidden.json"}
#: the most hidden units a weights file may have
MAX_HIDDEN = 256
#: added to luminances in the features' ratios: dark noise is not a change
FLOOR = 1e-2
#: asvgf's wide blend is kept this far from 0 and 1 before its logit
BLEND_MARGIN = 1e-2


@dataclass(frozen=True)
class Network:
    """The perceptron's weights: ``hidden = tanh(w1 x + b1)``, ``outputs = w2 hidden + b2``,
    ``x`` the values of ``features`` (a subset of :data:`FEATURES`, in its order)."""
    features: tuple[str, ...]
    w1: np.ndarray  # (hidden, len(features))
    b1: np.ndarray  # (hidden,)
    w2: np.ndarray  # (len(OUTPUTS), hidden)
    b2: np.ndarray  # (len(OUTPUTS),)

    @property
    def hidden(self) -> int:
        return self.b1.shape[0]

    def to_json(self) -> dict:
        return {"format": FORMAT, "features": list(self.features), "outputs": list(OUTPUTS), "hidden": self.hidden,
                "w1": self.w1.tolist(), "b1": self.b1.tolist(), "w2": self.w2.tolist(), "b2": self.b2.tolist()}

    def constants(self) -> tuple[list, list, list, list]:
        """The weights as nested lists of Python floats (constants in the kernels)."""
        return (self.w1.tolist(), self.b1.tolist(), self.w2.tolist(), self.b2.tolist())


def feature_set(temporal_inputs: bool) -> tuple[str, ...]:
    """The inputs of a network trained with or without the history's statistics (the ablation)."""
    return FEATURES if temporal_inputs else tuple(f for f in FEATURES if f not in TEMPORAL_FEATURES)


def parameter_count(inputs: int, hidden: int) -> int:
    return hidden * inputs + hidden + len(OUTPUTS) * hidden + len(OUTPUTS)


def load_network(path: Path | str) -> Network:
    """The network of weights file ``path``; a missing, truncated or damaged
    file, or one of other shapes or another feature list, is one line naming
    the file and the training command."""
    data = open_weights(path, FORMAT, TRAIN_COMMAND)
    path = Path(path)
    features = check_names(path, data, "features", FEATURES, TRAIN_COMMAND)
    if data.get("outputs") != list(OUTPUTS):
        raise bad_weights(path, f"its outputs must be {', '.join(OUTPUTS)}, got {data.get('outputs')!r}",
                          TRAIN_COMMAND)
    hidden = check_count(path, data, "hidden", MAX_HIDDEN, TRAIN_COMMAND)
    shapes = {"w1": (hidden, len(features)), "b1": (hidden,), "w2": (len(OUTPUTS), hidden), "b2": (len(OUTPUTS),)}
    arrays = weight_arrays(path, data, shapes, f"{len(features)} features and {hidden} hidden units", TRAIN_COMMAND)
    return Network(features, **arrays)


def mlp(inputs: list, w1, b1, w2, b2) -> list:
    """The perceptron on per-pixel Floats ``inputs``; weights as nested lists of
    Python floats or of one-lane Dr.Jit Floats. Returns one Float per output."""
    hidden = []
    for row, bias in zip(w1, b1):
        total = bias
        for w, x in zip(row, inputs):
            total = total + w * x
        hidden.append(dr.tanh(total))
    outputs = []
    for row, bias in zip(w2, b2):
        total = bias
        for w, h in zip(row, hidden):
            total = total + w * h
        outputs.append(total)
    return outputs


def features(frame: FrameArrays, statistics: dict, fast: mi.Vector3f, slow: mi.Vector3f, length: mi.Float,
             var: mi.Float) -> dict[str, mi.Float]:
    """Every input of :data:`FEATURES` per pixel (detached), from asvgf's temporal step."""
    def ratio(a, b):
        return dr.abs(a - b) / (dr.abs(a) + dr.abs(b) + FLOOR)

    y_c, y_s, y_f = luminance(frame.color), luminance(dr.detach(slow)), luminance(fast)
    n = dr.detach(length)
    if "valid" in statistics:
        valid = statistics["valid"]
        gradient = dr.select(valid, statistics["gradient"], 1.0)
        history = luminance(statistics["slow_history"])
        clip = dr.select(valid, log1p(dr.abs(luminance(statistics["slow_clipped"]) - history)
                                         / (dr.abs(history) + FLOOR)), 0.0)
        lost = dr.select(valid, 0.0, 1.0)
    else:  # the first frame: no history anywhere
        gradient, clip, lost = dr.full(mi.Float, 1.0, dr.width(n)), dr.zeros(mi.Float, dr.width(n)), 1.0
    values = {"inverse_length": 1.0 / n, "gradient": gradient, "disoccluded": lost + dr.zeros(mi.Float, dr.width(n)),
              "current_change": ratio(y_c, y_s), "fast_slow": ratio(y_f, y_s), "slow_clip": clip,
              "noise": log1p(dr.sqrt(dr.maximum(dr.detach(var), 0.0)) / (dr.abs(y_s) + FLOOR))}
    return {k: dr.detach(v) for k, v in values.items()}


def log1p(x):
    return dr.log(1.0 + x)


def sigmoid(x):
    return 1.0 / (1.0 + dr.exp(-x))


@dataclass
class LevelValues:
    """What :func:`denoise.svgf_common.atrous_level` reads: σ per pixel, the rest as fitted."""
    sigma_luminance: object
    normal_exponent: float
    sigma_plane: float


def scale(o):
    """A σ factor from e⁻² to e², 1 at ``o = 0``."""
    return dr.exp(2.0 * dr.tanh(0.5 * o))


def constant_network(network: Network) -> Callable[[dict], list]:
    """The network as Dr.Jit arithmetic with its weights as constants: the features by name -> the outputs."""
    weights = network.constants()
    return lambda inputs: mlp([inputs[name] for name in network.features], *weights)


def learned_asvgf(frame: FrameArrays, p: ASVGFParams, network: Callable[[dict], list],
                  history: ASVGFHistory | None = None, index: mi.UInt32 | None = None,
                  valid: mi.Bool | None = None) -> tuple[mi.TensorXf, ASVGFHistory]:
    """One frame (see the module): asvgf's temporal step, the network on its
    statistics, the À-Trous levels it steers. ``network`` maps the features
    (:func:`features`, by name) to the outputs (:data:`OUTPUTS`, per-pixel
    Floats): :func:`constant_network` when denoising, the trainer's own when
    training.
    Returns (the filtered colour, the history for the next frame)."""
    v = FilterValues.of(p)
    statistics = {}
    fast, slow, moments, length = temporal_accumulation(frame, history, index, valid, p, v, statistics=statistics)
    dr.eval(fast, slow, moments, length)
    var = variance(frame, moments, length, p, v)
    dr.eval(var)
    inputs = features(frame, statistics, fast, slow, length, var)
    o = network(inputs)
    sigma_first, sigma_coarse = p.sigma_luminance * scale(o[0]), p.sigma_luminance * scale(o[1])
    base = dr.clip((dr.detach(length) - 1.0) / p.wide_frames, BLEND_MARGIN, 1.0 - BLEND_MARGIN)
    wide_blend = sigmoid(dr.log(base / (1.0 - base)) + o[2])
    color = slow
    dr.eval(sigma_first, sigma_coarse, wide_blend, color)
    feedback = color
    levels = p.levels if p.levels is not None else levels_for(frame.width)
    for level in range(levels + p.wide_levels):
        values = LevelValues(sigma_first if level == 0 else sigma_coarse, p.normal_exponent, p.sigma_plane)
        if level == levels:
            regular = color
        color, var = atrous_level(frame, color, var, 1 << level, values)
        dr.eval(color, var)
        if level == min(p.feedback_level, levels - 1):
            feedback = color
    if p.wide_levels:
        color = dr.lerp(color, regular, wide_blend)
    return frame.tensor(color), ASVGFHistory(fast, feedback, moments, length)


class LearnedASVGF(TrainedMethod):
    """asvgf's temporal step, then a per-pixel perceptron trained end to end
    through the temporal and spatial pipeline (``python -m denoise.train``)
    that sets, from asvgf's temporal statistics, the luminance weight of the
    first and of the coarser À-Trous levels and the wide level's blend. asvgf's other
    parameters are its fitted ones. The presets are the benchmark's
    ablations: ``no-temporal-inputs`` (the network trained on the noise
    input alone) and ``half-hidden`` (half the hidden units).
    Temporal by nature; it always demodulates by the albedo when the frames have one.
    """
    name = "learned-asvgf"
    description = "asvgf whose filter a trained per-pixel network steers (kernel sigmas, wide blend)"
    weights_file = WEIGHTS_FILE
    ablations = ABLATIONS
    load_network = staticmethod(load_network)

    @staticmethod
    def denoise(frame, params, network, history, index, valid):
        return learned_asvgf(frame, params, constant_network(network), history, index, valid)
