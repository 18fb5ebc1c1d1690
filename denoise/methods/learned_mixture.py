"""A trained per-pixel blend of asvgf's images: ``learned-mixture``.

asvgf (:func:`denoise.methods.asvgf.temporal_accumulation` and its À-Trous
levels, with its fitted parameters) makes, for every frame, the images of
:data:`CANDIDATES`: its slow history; at its fitted luminance σ times ½, 1 and
2, its last three regular À-Trous levels and its wide level; and its own
output. A small convolutional network reads, per pixel, asvgf's temporal
statistics (:data:`denoise.methods.learned_asvgf.FEATURES`) and how far each
image's luminance lies from the slow history's (:data:`RATIOS`, so it sees
what each level and σ would change), and gives one weight per image (a
softmax): the per-pixel filter is a blend of kernels of three footprints,
three edge stops and the temporal history alone. The same network then
predicts a 3×3 kernel for each pixel (:data:`KERNEL_TAPS` weights, a
softmax) that filters the blend once more: it can average what noise the
blend leaves (where every image is noisy, as where the history is short).
The kernel filters the blend as the image is shown, times the albedo where
the frames are demodulated: the training filters it so, and filtering the
demodulated blend instead trains to a worse network (docs/learned_mixture.md).

The network: two 3×3 convolutions of ``channels`` ReLU units (edges
repeat the border pixel) and 1×1 layers of one logit per image and per
kernel tap; with 8 channels (the committed network's) and 20 inputs about
2.2k multiply-adds a pixel. Inference is Dr.Jit arithmetic of the active
variant: each 3×3 layer, and the kernel, is one kernel that reads its
inputs at the 9 taps (shifted planes on the CPU, gathers elsewhere:
:class:`Taps`), the weights constants in it.

The history asvgf carries to the next frame is asvgf's own (at σ × 1): the
blend changes no later frame, so training it on each frame's images
(:mod:`denoise.mixture_training`, ``python -m denoise.train --method
learned-mixture``) is training it end to end.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

from ..filters import FrameArrays, albedo_factor, luminance
from ..neighbours import ShiftedPlanes, margin_for, usable
from ..svgf_common import atrous_level, levels_for
from .asvgf import ASVGFHistory, ASVGFParams, FilterValues, temporal_accumulation, variance, wide_blend
from .learned_asvgf import FEATURES as STATISTICS, FLOOR, TEMPORAL_FEATURES, features
from .trained import TrainedMethod
from .weights_file import bad_weights, check_count, check_names, open_weights, weight_arrays

#: the luminance σ factors of the three À-Trous chains, and their names
SIGMA_FACTORS = {"half": 0.5, "one": 1.0, "double": 2.0}
#: the images the network blends, in order
CANDIDATES = ("slow", *(f"{level}_{sigma}" for sigma in SIGMA_FACTORS for level in ("a1", "a2", "a3", "wide")),
              "asvgf")
#: the log luminance ratio of each image but the slow history to the slow history's
RATIOS = tuple(f"ratio_{name}" for name in CANDIDATES[1:])
#: the network's inputs, in order: a weights file names the ones it was trained on
FEATURES = (*STATISTICS, *RATIOS)
#: the ratios are clipped to ±this (e³: a level that changes a pixel twentyfold says no more)
RATIO_LIMIT = 3.0
FORMAT = "learned-mixture-cnn"
TRAIN_COMMAND = "python -m denoise.train --method learned-mixture"
WEIGHTS_DIR = Path(__file__).resolve().parents[1]
WEIGHTS_FILE = WEIGHTS_DIR / "learned_mixture.json"
#: the benchmark's two ablations: without the temporal inputs, with half the channels
ABLATIONS = {"no-temporal-inputs": WEIGHTS_DIR / "learned_mixture_no_temporal.json",
             "half-channels": WEIGHTS_DIR / "learned_mixture_half_channels.json"}
#: the most channels a weights file may have
MAX_CHANNELS = 64
#: the logit bias of asvgf's output at the start of a training: the blend starts near asvgf
START_LOGIT = 4.0
#: the predicted kernel's taps: 3×3, row by row (:meth:`Taps.reads`' order)
KERNEL_TAPS = 9
#: the logit bias of the kernel's centre at the start of a training: the kernel starts near the identity
KERNEL_START_LOGIT = 5.0


def feature_set(temporal_inputs: bool) -> tuple[str, ...]:
    """The inputs of a network trained with or without the history's statistics (the ablation)."""
    return FEATURES if temporal_inputs else tuple(f for f in FEATURES if f not in TEMPORAL_FEATURES)


@dataclass(frozen=True)
class MixtureNetwork:
    """``h1 = relu(conv3x3(x; w1) + b1)``, ``h2 = relu(conv3x3(h1; w2) + b2)``,
    ``logits = w3 h2 + b3``, one per :data:`CANDIDATES`, and ``kernel = w4 h2
    + b4``, one per tap of the 3×3 kernel; ``x`` the values of ``features``
    (some of :data:`FEATURES`, in its order)."""
    features: tuple[str, ...]
    w1: np.ndarray  # (channels, len(features), 3, 3)
    b1: np.ndarray  # (channels,)
    w2: np.ndarray  # (channels, channels, 3, 3)
    b2: np.ndarray  # (channels,)
    w3: np.ndarray  # (len(CANDIDATES), channels)
    b3: np.ndarray  # (len(CANDIDATES),)
    w4: np.ndarray  # (KERNEL_TAPS, channels)
    b4: np.ndarray  # (KERNEL_TAPS,)

    @property
    def channels(self) -> int:
        return self.b1.shape[0]

    def to_json(self) -> dict:
        return {"format": FORMAT, "features": list(self.features), "candidates": list(CANDIDATES),
                "channels": self.channels, **{k: getattr(self, k).tolist() for k in ARRAYS}}


#: the weights' names, in the order a training's parameter vector holds them
ARRAYS = ("w1", "b1", "w2", "b2", "w3", "b3", "w4", "b4")


def shapes(inputs: int, channels: int) -> dict[str, tuple]:
    k = len(CANDIDATES)
    return {"w1": (channels, inputs, 3, 3), "b1": (channels,), "w2": (channels, channels, 3, 3),
            "b2": (channels,), "w3": (k, channels), "b3": (k,), "w4": (KERNEL_TAPS, channels),
            "b4": (KERNEL_TAPS,)}


def parameter_count(inputs: int, channels: int) -> int:
    return sum(int(np.prod(s)) for s in shapes(inputs, channels).values())


def network_of(theta: np.ndarray, features: tuple[str, ...], channels: int) -> MixtureNetwork:
    """The network of a training's parameter vector (:data:`ARRAYS` flattened, in order)."""
    arrays, start = {}, 0
    for key, shape in shapes(len(features), channels).items():
        size = int(np.prod(shape))
        arrays[key] = np.asarray(theta[start:start + size], np.float32).reshape(shape)
        start += size
    return MixtureNetwork(tuple(features), **arrays)


def flatten(network: MixtureNetwork) -> np.ndarray:
    return np.concatenate([getattr(network, k).ravel() for k in ARRAYS]).astype(np.float32)


def load_network(path: Path | str) -> MixtureNetwork:
    """The network of weights file ``path``; a missing, truncated or damaged
    file, or one of other shapes, another feature or image list, is one line
    naming the file and the training command."""
    data = open_weights(path, FORMAT, TRAIN_COMMAND)
    path = Path(path)
    features = check_names(path, data, "features", FEATURES, TRAIN_COMMAND)
    if data.get("candidates") != list(CANDIDATES):
        raise bad_weights(path, f"its candidates must be {', '.join(CANDIDATES)}, got {data.get('candidates')!r}",
                          TRAIN_COMMAND)
    channels = check_count(path, data, "channels", MAX_CHANNELS, TRAIN_COMMAND)
    arrays = weight_arrays(path, data, shapes(len(features), channels),
                           f"{len(features)} features and {channels} channels", TRAIN_COMMAND)
    return MixtureNetwork(features, **arrays)


def candidate_images(frame: FrameArrays, p: ASVGFParams, history: ASVGFHistory | None, index: mi.UInt32 | None,
                     valid: mi.Bool | None) -> tuple[list, dict, ASVGFHistory]:
    """asvgf's images of :data:`CANDIDATES` (demodulated Vector3f, evaluated),
    the network's inputs by name (:data:`FEATURES`, evaluated) and asvgf's
    history for the next frame. The chains at σ × ½ and × 2 start from
    σ × 1's before its last three regular levels (at 320 pixels wide, 3 levels, from
    the slow history); with fewer than three levels (a narrow image) the finest is repeated."""
    v = FilterValues.of(p)
    statistics = {}
    fast, slow, moments, length = temporal_accumulation(frame, history, index, valid, p, v, statistics=statistics)
    dr.eval(fast, slow, moments, length)
    var = variance(frame, moments, length, p, v)
    dr.eval(var)
    inputs = features(frame, statistics, fast, slow, length, var)
    levels = p.levels if p.levels is not None else levels_for(frame.width)
    branch = max(0, levels - 3)  # the chains at σ × ½ and × 2 branch off σ × 1's before its last three levels
    images, feedback, output, start, chain = [slow], slow, None, (slow, var), {}
    for factor in (1.0, *(f for f in SIGMA_FACTORS.values() if f != 1.0)):
        values = replace(v, sigma_luminance=v.sigma_luminance * factor)
        first = 0 if factor == 1.0 else branch
        (color, level_var), regular = (slow, var) if factor == 1.0 else start, []
        for level in range(first, levels):
            if factor == 1.0 and level == branch:
                start = (color, level_var)
            color, level_var = atrous_level(frame, color, level_var, 1 << level, values)
            dr.eval(color, level_var)
            regular.append(color)
            if factor == 1.0 and level == min(p.feedback_level, levels - 1):
                feedback = color
        wide = color
        for level in range(levels, levels + p.wide_levels):
            wide, level_var = atrous_level(frame, wide, level_var, 1 << level, values)
            dr.eval(wide, level_var)
        chain[factor] = regular[-3:] if len(regular) >= 3 else [regular[0]] * (3 - len(regular)) + regular
        chain[factor] = [*chain[factor], wide]
        if factor == 1.0:
            output = wide_blend(wide, color, length, v) if p.wide_levels else color
    for factor in SIGMA_FACTORS.values():
        images += chain[factor]
    images.append(output)
    base = dr.abs(luminance(slow)) + FLOOR
    for name, image in zip(RATIOS, images[1:]):
        inputs[name] = dr.clip(dr.log((dr.abs(luminance(image)) + FLOOR) / base), -RATIO_LIMIT, RATIO_LIMIT)
    dr.eval(*images, *inputs.values())
    return images, inputs, ASVGFHistory(fast, feedback, moments, length)


class Taps:
    """A 3×3 neighbourhood's reads of per-pixel Floats, the border pixel
    repeated beyond the edges: where shifted planes are usable
    (:mod:`denoise.neighbours`, LLVM, no gradient) plain loads at each tap's
    offset, a tap beyond an edge replaced by the one that stays in the
    row or column (``dr.select``); else gathers at clamped indices."""

    def __init__(self, width: int, height: int):
        self.width, self.height = width, height
        i = dr.arange(mi.UInt32, width * height)
        self.y, self.x = mi.Int32(i // width), mi.Int32(i % width)
        self.x_ok = {-1: self.x >= 1, 1: self.x < width - 1}
        self.y_ok = {-1: self.y >= 1, 1: self.y < height - 1}
        dr.eval(self.x_ok, self.y_ok)

    def reads(self, channels: list) -> list[list]:
        """For each channel, its 9 taps (row by row: dy, then dx, from -1 to 1)."""
        if usable(*channels):
            planes = ShiftedPlanes(channels, margin_for(self.width, 1))
            taps = []
            for c in range(len(channels)):
                at = {(dy, dx): planes.at(c, dy * self.width + dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1)}
                row = []
                for dy in (-1, 0, 1):
                    for dx in (-1, 0, 1):
                        value = at[(dy, dx)]
                        if dx:  # beyond the row's end: the tap of column 0 offset
                            value = dr.select(self.x_ok[dx], value, at[(dy, 0)])
                        if dy:
                            inner = at[(0, dx)] if not dx else dr.select(self.x_ok[dx], at[(0, dx)], at[(0, 0)])
                            value = dr.select(self.y_ok[dy], value, inner)
                        row.append(value)
                taps.append(row)
            self.planes = planes  # held until the kernel that reads them is launched
            return taps
        indices = [mi.UInt32(dr.clip(self.y + dy, 0, self.height - 1) * self.width
                             + dr.clip(self.x + dx, 0, self.width - 1)) for dy in (-1, 0, 1) for dx in (-1, 0, 1)]
        return [[dr.gather(mi.Float, channel, index) for index in indices] for channel in channels]


def convolution(channels: list, weights: list, biases: list, taps: Taps) -> list:
    """A 3×3 convolution and ReLU of per-pixel Floats ``channels`` (evaluated);
    ``weights[o][c][ky][kx]`` Python floats; one evaluated Float per output."""
    outputs = [mi.Float(b) for b in biases]
    for c, reads in enumerate(taps.reads(channels)):
        for t, value in enumerate(reads):
            for o in range(len(outputs)):
                outputs[o] = dr.fma(weights[o][c][t // 3][t % 3], value, outputs[o])
    outputs = [dr.maximum(o, 0.0) for o in outputs]
    dr.eval(outputs)
    taps.planes = None
    return outputs


def softmax(weights: np.ndarray, biases: np.ndarray, hidden: list) -> list:
    """The softmax of the logits ``weights @ hidden + biases`` per pixel, unnormalised
    (each pixel's largest is 1): a list of Floats, one per row of ``weights``."""
    logits = []
    for row, bias in zip(weights.tolist(), biases.tolist()):
        total = mi.Float(bias)
        for w, h in zip(row, hidden):
            total = dr.fma(w, h, total)
        logits.append(total)
    top = logits[0]
    for logit in logits[1:]:
        top = dr.maximum(top, logit)
    return [dr.exp(logit - top) for logit in logits]


def weighted_mean(weights: list, values: list):
    """``Σ weights[i] values[i] / Σ weights[i]``."""
    total, blend = weights[0], values[0] * weights[0]
    for w, value in zip(weights[1:], values[1:]):
        total, blend = total + w, dr.fma(value, w, blend)
    return blend / total


def mixture(network: MixtureNetwork, inputs: dict, images: list, width: int, height: int,
            albedo: mi.Vector3f | None = None) -> mi.Vector3f:
    """The network's softmax blend of ``images`` per pixel, filtered by its predicted 3×3
    kernel. ``albedo``: where the images are demodulated, the factor the output is multiplied
    by afterwards; the kernel then filters the blend times it (the image as it is shown,
    and as the training filters it) and the result is divided by it again."""
    taps = Taps(width, height)
    h1 = convolution([inputs[name] for name in network.features], network.w1.tolist(), network.b1.tolist(), taps)
    h2 = convolution(h1, network.w2.tolist(), network.b2.tolist(), taps)
    blend = weighted_mean(softmax(network.w3, network.b3, h2), images)
    if albedo is not None:
        blend = blend * albedo
    dr.eval(blend)
    reads = taps.reads([blend.x, blend.y, blend.z])
    kernel = softmax(network.w4, network.b4, h2)  # in the kernel that reads the taps: 9 arrays fewer written
    result = mi.Vector3f(*(weighted_mean(kernel, channel) for channel in reads))
    if albedo is not None:
        result = result / albedo
    dr.eval(result)
    taps.planes = None
    return result


def learned_mixture(frame: FrameArrays, p: ASVGFParams, network: MixtureNetwork, history: ASVGFHistory | None = None,
                    index: mi.UInt32 | None = None, valid: mi.Bool | None = None
                    ) -> tuple[mi.TensorXf, ASVGFHistory]:
    """One frame (see the module). Returns (the filtered colour, the history for the next frame)."""
    images, inputs, history = candidate_images(frame, p, history, index, valid)
    albedo = None if frame.albedo is None else dr.unravel(mi.Vector3f, albedo_factor(frame.albedo))
    return frame.tensor(mixture(network, inputs, images, frame.width, frame.height, albedo)), history


class LearnedMixture(TrainedMethod):
    """asvgf's images (its slow history; its last three À-Trous levels and
    wide level at its fitted luminance σ times ½, 1 and 2; its output),
    blended per pixel by a small convolutional network (two 3×3 layers)
    trained on the project's own renders
    (``python -m denoise.train --method learned-mixture``) from asvgf's
    temporal statistics and the images' luminance ratios; the blend is then
    filtered by a 3×3 kernel the same network predicts per pixel. The presets are
    the benchmark's ablations: ``no-temporal-inputs`` (the network without
    asvgf's temporal statistics) and ``half-channels``.
    Temporal by nature; it always demodulates by the albedo when the frames have one.
    """
    name = "learned-mixture"
    description = ("asvgf's levels at three edge stops, blended and filtered per pixel by a trained "
                   "convolutional network")
    weights_file = WEIGHTS_FILE
    ablations = ABLATIONS
    load_network = staticmethod(load_network)
    denoise = staticmethod(learned_mixture)
