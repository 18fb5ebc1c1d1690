"""Training ``learned-asvgf``'s network end to end through asvgf's temporal and spatial pipeline.

The data: sequences the project renders itself (``python -m export``), by
default ``scenes/sequences/training/network/*.json`` (18 sequences of 320×180,
the benchmark's size, on the showcase and mirrors scenes and the course's
arch and bunny, which no benchmark sequence uses) and 48 sequences of
procedurally generated scenes (:mod:`scenes.procedural`), each with an independently seeded
ground truth of 128 samples per pixel: an unbiased (Noise2Noise) target, its
noise averaging out over pixels and steps.
:func:`denoise.train.check_specs` refuses a sequence without ground truth and any benchmark
sequence or scene (``scenes/sequences/*.json``). :data:`HELD_OUT` sequences
are not trained on: their loss is reported at each step. The bunny's one
sequence is among them, so one scene is one the network never sees.

A step: :data:`BATCH` training sequences drawn at random, each cropped to
:data:`CROP` at a random place, flipped at random in x and y and scaled by a
random exposure; :func:`denoise.methods.learned_asvgf.learned_asvgf` runs over
all of its frames in ``llvm_ad_rgb`` with the network's weights as Dr.Jit
Floats with gradients, the history carried from frame to frame, and
``dr.backward`` of the mean relMSE (every frame from :data:`LOSS_FROM` on, against its target), each
sequence's divided by asvgf's on the same crop (:func:`base_loss`), gives
the gradient through the filter of every frame and the slow histories fed
back to the frames after. Adam (NumPy, :class:`Adam`) updates the weights.
The draws come from ``numpy.random.default_rng((seed, step))``: a resumed run
draws what an uninterrupted one would.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

from core.errors import UsageError
from export import reference_folder
from export.frames import frame_indices, read_frame, same_size
from imaging.image_io import read_exr_rgb

from .filters import FrameArrays, demodulate, relmse_loss, remodulate, reproject
from .methods import make
from .methods.asvgf import fitted
from .methods.learned_asvgf import OUTPUTS, Network, learned_asvgf
from .svgf_common import levels_for
from .training_state import Adam, Settings, resume, run_steps

ROOT = Path(__file__).resolve().parent.parent
TRAINING = sorted((ROOT / "scenes" / "sequences" / "training" / "network").glob("*.json"))
#: the benchmark's sequences: neither they nor their scenes may be trained on
BENCHMARK = sorted((ROOT / "scenes" / "sequences").glob("*.json"))
#: sequences whose loss is reported and never trained on
HELD_OUT = ("mirrors_switch", "showcase_disocclusion", "bunny_dolly")
#: training sequences per step, and the size each is cropped to (one size: one set of kernels)
BATCH, CROP = 4, (160, 90)
#: the loss counts the frames from this one on: a first frame (no history anywhere) has errors
#: several times the others', which would drown what the frames with a history teach
LOSS_FROM = 1
#: the range of the random exposure (a factor on colour and target)
EXPOSURE = (0.5, 2.0)
#: the output layer's biases at the start: asvgf as fitted
START_BIAS = (0.0, 0.0, 0.0)
#: the least denominator of the loss: a crop that asvgf gets exactly right (all black) counts 0, not NaN
BASE_LOSS_FLOOR = 1e-12


@dataclass
class Frame:
    """One frame as NumPy arrays: demodulated colour, guides, albedo, target,
    and the back projection as a flat index into the previous frame (-1: none)."""
    color: np.ndarray
    normal: np.ndarray
    position: np.ndarray
    albedo: np.ndarray | None
    target: np.ndarray
    previous: np.ndarray | None


#: bytes per pixel of a frame that :func:`load_sequence` keeps (its buffers, target and
#: back projection), and of a frame of a held-out sequence during its whole-frame loss
LOADED_BYTES, HELD_OUT_BYTES = 80, 280
#: what the process holds besides (Python, Dr.Jit, the libraries)
BASE_BYTES = 1 << 30


def training_memory(specs: list[tuple[str, object]]) -> int:
    """Bytes a training run holds at its peak for sequences ``(name, spec)``:
    every frame loaded at once, and the largest held-out sequence's loss pass."""
    pixels = {name: spec.frames * spec.size[0] * spec.size[1] for name, spec in specs}
    held = [pixels[name] for name in pixels if name in HELD_OUT]
    return BASE_BYTES + LOADED_BYTES * sum(pixels.values()) + HELD_OUT_BYTES * max(held, default=0)


def load_sequence(folder: Path) -> list[Frame]:
    """Every frame of an exported folder with its ground truth, as asvgf gets it
    (usable values, albedo demodulation, back projection)."""
    def tensor(a):
        return mi.TensorXf(np.ascontiguousarray(a, np.float32))

    usable = make("asvgf").usable_frame
    frames, last, last_ids = [], None, None
    for i in frame_indices(folder):
        frame = usable(read_frame(folder, i))
        truth_path = reference_folder(folder) / f"beauty_{i}.exr"
        if not truth_path.is_file():
            raise UsageError(f"{folder}: no ground truth for frame {i} (no {truth_path}; python -m export renders it)")
        truth = read_exr_rgb(truth_path)
        same_size(folder / f"beauty_{i}.exr", frame.beauty.shape, truth_path, truth.shape)
        ids = tensor(frame.ids)
        color = frame.beauty
        if frame.albedo is not None:
            color = np.array(demodulate(tensor(color), tensor(frame.albedo)))
        previous = None
        if last is not None:
            index, valid = reproject(tensor(frame.position), ids, last_ids, frame.object_to_world,
                                     last.object_to_world, last.world_to_screen)
            previous = np.where(np.array(valid), np.array(index).astype(np.int64), -1).reshape(color.shape[:2])
        frames.append(Frame(color, frame.normal, frame.position, frame.albedo, truth, previous))
        last, last_ids = frame, ids
    return frames


@dataclass
class Prepared:
    """One (augmented) frame as the filter takes it."""
    buffers: FrameArrays
    index: object
    valid: object
    albedo: object  # mi.TensorXf or None
    target: mi.TensorXf
    levels: int  # the À-Trous levels of the whole frame's width, which a crop keeps


def augmented(frames: list[Frame], crop: tuple[int, int] | None, x0: int, y0: int, flip_x: bool, flip_y: bool,
              exposure: float) -> list[Prepared]:
    """``frames`` cropped to ``crop`` (None: whole) at (x0, y0), flipped, times
    ``exposure``; the back projection follows the crop and the flips (a pixel
    whose previous place left the crop has no history). The filter's weights
    read world-space normals and positions, which a flip of the pixel grid leaves as they are.
    A crop is filtered with the whole frame's À-Trous levels, as the method filters that frame."""
    height, width = frames[0].color.shape[:2]
    w, h = crop if crop is not None else (width, height)
    xs, ys = np.arange(x0, x0 + w), np.arange(y0, y0 + h)
    xs, ys = (xs[::-1] if flip_x else xs), (ys[::-1] if flip_y else ys)
    where = np.full(width * height, -1, np.int64)  # full-frame pixel -> its index in the crop
    where[(ys[:, None] * width + xs[None, :]).ravel()] = np.arange(w * h)

    def cut(a, dtype=np.float32):
        return np.ascontiguousarray(a[ys][:, xs], dtype)

    def tensor(a):
        return upload(cut(a))

    out = []
    for f in frames:
        index = valid = None
        if f.previous is not None:
            previous = cut(f.previous, np.int64).ravel()
            mapped = where[np.maximum(previous, 0)]
            ok = (previous >= 0) & (mapped >= 0)
            index, valid = upload(np.where(ok, mapped, 0).astype(np.uint32), mi.UInt32), upload(ok, mi.Bool)
        albedo = None if f.albedo is None else tensor(f.albedo)
        out.append(Prepared(FrameArrays(tensor(f.color * exposure), tensor(f.normal), tensor(f.position), albedo),
                            index, valid, albedo, tensor(f.target * exposure), levels_for(width)))
    return out


def upload(array: np.ndarray, kind=None):
    """A Dr.Jit array (``kind``, or a TensorXf of the array's shape) in memory
    of Dr.Jit's own: an array that reads NumPy's memory in place is declared
    with that memory's alignment, so the same kernel would hash, and be
    compiled, anew whenever NumPy's allocation lands elsewhere."""
    if kind is None:
        array = np.ascontiguousarray(array, np.float32)
        return mi.TensorXf(dr.copy(mi.Float(array.ravel())), array.shape)
    return dr.copy(kind(np.ascontiguousarray(array)))


class Recorder:
    """The perceptron of ``theta`` in NumPy, as :func:`learned_asvgf` calls a
    network: its outputs become per-pixel Dr.Jit Floats with gradients (the
    leaves of the differentiation), and what the chain rule needs is kept."""

    def __init__(self, theta: np.ndarray, features: tuple[str, ...], hidden: int, gradients: bool):
        self.network, self.gradients, self.kept = network_of(theta, features, hidden), gradients, []

    def __call__(self, inputs: dict) -> list:
        dr.eval(*inputs.values())
        x = np.stack([np.array(inputs[name], np.float32) for name in self.network.features], axis=1)
        hidden, outputs = numpy_mlp(self.network, x)
        leaves = [upload(outputs[:, k].astype(np.float32), mi.Float) for k in range(outputs.shape[1])]
        if self.gradients:
            for leaf in leaves:
                dr.enable_grad(leaf)
            self.kept.append((x, hidden, leaves))
        return leaves

    def gradient(self) -> np.ndarray:
        """d loss / d theta after ``dr.backward``: each frame's output gradients back through the perceptron."""
        net = self.network
        g_w1, g_b1 = np.zeros_like(net.w1, np.float64), np.zeros_like(net.b1, np.float64)
        g_w2, g_b2 = np.zeros_like(net.w2, np.float64), np.zeros_like(net.b2, np.float64)
        for x, hidden, leaves in self.kept:
            g = np.stack([np.array(dr.grad(leaf), np.float64) for leaf in leaves], axis=1)
            g_w2 += g.T @ hidden
            g_b2 += g.sum(axis=0)
            pre = (g @ net.w2.astype(np.float64)) * (1.0 - hidden * hidden)
            g_w1 += pre.T @ x
            g_b1 += pre.sum(axis=0)
        return np.concatenate([g_w1.ravel(), g_b1, g_w2.ravel(), g_b2])


def numpy_mlp(network: Network, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(hidden, outputs) of the perceptron on ``x`` (pixels, features), in float64."""
    hidden = np.tanh(x.astype(np.float64) @ network.w1.T.astype(np.float64) + network.b1)
    return hidden, hidden @ network.w2.T.astype(np.float64) + network.b2


def flatten(network: Network) -> np.ndarray:
    return np.concatenate([network.w1.ravel(), network.b1, network.w2.ravel(), network.b2]).astype(np.float32)


def network_of(theta: np.ndarray, features: tuple[str, ...], hidden: int) -> Network:
    f, o = len(features), len(OUTPUTS)
    sizes = np.cumsum([hidden * f, hidden, o * hidden])
    w1, b1, w2, b2 = np.split(np.asarray(theta, np.float32), sizes)
    return Network(tuple(features), w1.reshape(hidden, f), b1, w2.reshape(o, hidden), b2)


def initial(features: tuple[str, ...], hidden: int, seed: int) -> np.ndarray:
    """Random first layer, output layer 0 (the method starts as asvgf), :data:`START_BIAS`."""
    rng = np.random.default_rng(seed)
    w1 = rng.normal(0.0, 1.0 / math.sqrt(len(features)), (hidden, len(features)))
    return flatten(Network(features, w1.astype(np.float32), np.zeros(hidden, np.float32),
                           np.zeros((len(OUTPUTS), hidden), np.float32), np.array(START_BIAS, np.float32)))


def sequence_loss(frames: list[Prepared], network) -> object:
    """Mean relMSE of ``learned_asvgf`` with ``network`` (a :class:`Recorder`) over ``frames`` (a Dr.Jit Float)."""
    params = fitted()
    params = params if params.levels is not None else replace(params, levels=frames[0].levels)
    history, total = None, 0.0
    for number, f in enumerate(frames):
        result, history = learned_asvgf(f.buffers, params, network, history if f.index is not None else None,
                                        f.index, f.valid)
        if f.albedo is not None:
            result = remodulate(result, f.albedo)
        if number >= LOSS_FROM or len(frames) <= LOSS_FROM:
            total = total + relmse_loss(result, f.target)
    return total / max(len(frames) - LOSS_FROM, 1)


def draw(rng: np.random.Generator, frames: list[Frame]) -> dict:
    height, width = frames[0].color.shape[:2]
    w, h = min(CROP[0], width), min(CROP[1], height)
    return dict(crop=(w, h), x0=int(rng.integers(0, width - w + 1)), y0=int(rng.integers(0, height - h + 1)),
                flip_x=bool(rng.integers(2)), flip_y=bool(rng.integers(2)),
                exposure=float(np.exp(rng.uniform(*np.log(EXPOSURE)))))


def train_step(adam: Adam, settings: Settings, train: list[list[Frame]], step: int) -> float:
    """One gradient step on :data:`BATCH` augmented training sequences; returns the loss before it.
    A loss that is not finite is a UsageError, the weights left as they were."""
    rng = np.random.default_rng((settings.seed, step))
    chosen = rng.choice(len(train), size=min(BATCH, len(train)), replace=False)
    network = Recorder(adam.theta, settings.features, settings.hidden, gradients=True)
    base = asvgf_network(settings)
    total = 0.0
    for i in chosen:
        crop = augmented(train[i], **draw(rng, train[i]))
        total = total + sequence_loss(crop, network) / base_loss(crop, base)
    loss = total / len(chosen)
    value = float(loss[0])
    if not math.isfinite(value):
        raise UsageError(f"the training loss is {value} at step {step} (a diverging step); the weights file "
                         f"was not written")
    dr.backward(loss)
    gradient = network.gradient()
    if not np.all(np.isfinite(gradient)):
        raise UsageError(f"the gradient is not finite at step {step}; the weights file was not written")
    adam.step(gradient)
    return value


def asvgf_network(settings: Settings) -> Recorder:
    """The network that is asvgf as fitted (:func:`initial`: the output layer at its start), without gradients."""
    return Recorder(initial(settings.features, settings.hidden, settings.seed), settings.features, settings.hidden,
                    gradients=False)


def base_loss(frames: list[Prepared], base: Recorder) -> float:
    """asvgf's loss on ``frames`` (``base``: :func:`asvgf_network`), the denominator of the
    training's loss: each sequence counts by how far it moves from asvgf, not by its own noise
    (a scene whose loss is several times the others' would drive every step it is in)."""
    value = float(sequence_loss(frames, base)[0])
    if not math.isfinite(value):
        raise UsageError(f"asvgf's loss on a training crop is {value}: a target or frame that is not usable")
    return max(value, BASE_LOSS_FLOOR)


def held_out_bases(settings: Settings, held: list[list[Frame]]) -> list[float]:
    """asvgf's loss on each held-out sequence (whole frames): the denominators of
    :func:`held_out_loss`, the same at every step, so computed once a run."""
    base = asvgf_network(settings)
    return [base_loss(augmented(frames, None, 0, 0, False, False, 1.0), base) for frames in held]


def held_out_loss(theta: np.ndarray, settings: Settings, held: list[list[Frame]],
                  bases: list[float] | None = None) -> float | None:
    """Mean over the held-out sequences (None: none) of the loss divided by asvgf's (``bases``:
    :func:`held_out_bases`, computed here if not given): whole frames, no augmentation, no
    gradients; 1 is asvgf, below 1 better."""
    if not held:
        return None
    bases = held_out_bases(settings, held) if bases is None else bases
    network = Recorder(theta, settings.features, settings.hidden, gradients=False)
    losses = [float(sequence_loss(augmented(frames, None, 0, 0, False, False, 1.0), network)[0]) / base
              for frames, base in zip(held, bases)]
    return sum(losses) / len(losses)


def split_loaded(folders: list[Path], load, progress=None) -> tuple[list, list]:
    """(the training sequences, the held-out ones: :data:`HELD_OUT`), each ``load(folder)``;
    ``progress(done, total, name)`` after each."""
    data = {}
    for number, folder in enumerate(folders):
        data[folder.name] = load(folder)
        if progress is not None:
            progress(number + 1, len(folders), folder.name)
    return ([data[f.name] for f in folders if f.name not in HELD_OUT],
            [data[f.name] for f in folders if f.name in HELD_OUT])


def train(folders: list[Path], settings: Settings, checkpoint: Path, report,
          restart: bool = False, progress=None) -> tuple[np.ndarray, list, float]:
    """The steps on the exported ``folders`` (those of :data:`HELD_OUT` held
    out), resumed from ``checkpoint`` where it exists (``restart``: overwritten
    at the first step instead) and written there after every step;
    ``report(step, loss, held-out loss, seconds)`` after each. Both losses
    are those of the weights before the step. Returns (the weights, the
    curve [(step, loss, held-out loss)], the seconds of all steps). ``progress(done, total,
    name)`` follows the loading of each sequence."""
    names = [f.name for f in folders]
    train_set, held = split_loaded(folders, load_sequence, progress)
    adam, curve, seconds = resume(checkpoint, settings, names, any(n in HELD_OUT for n in names),
                                  initial(settings.features, settings.hidden, settings.seed), restart)
    bases = held_out_bases(settings, held)
    return run_steps(adam, curve, seconds, settings, names, checkpoint, report,
                     lambda adam, number: train_step(adam, settings, train_set, number),
                     lambda number: held_out_loss(adam.theta, settings, held, bases))
