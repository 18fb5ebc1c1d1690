"""Training ``learned-mixture``'s network (``python -m denoise.train --method learned-mixture``).

The data are :mod:`denoise.training`'s: the project's own exported
sequences with their independent (Noise2Noise) targets, :data:`HELD_OUT`
held out. The blend changes no later frame (asvgf's history is its own), so
each frame's images and inputs are computed once, by the method's own Dr.Jit
code (:func:`denoise.methods.learned_mixture.candidate_images`, in sequence,
the history carried), and kept in ``WORK/mixture-inputs/NAME.npz`` (made anew
when the frames or asvgf's parameters change). The network then trains in
NumPy (its chain rule written out below): a step is :data:`BATCH` random
crops of :data:`CROP` pixels of frames from :data:`LOSS_FROM` on, flipped at
random and scaled by a random exposure, the loss each crop's relMSE over
asvgf's output's on it. The held-out loss (whole frames) is measured every
:data:`HELD_OUT_EVERY` steps and at the last; the steps between report the
last measured. Draws come from ``numpy.random.default_rng((seed, step))``: a
resumed run draws what an uninterrupted one would.
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import replace
from pathlib import Path

import drjit as dr
import numpy as np

from core.errors import UsageError
from export import reference_folder
from export.frames import frame_indices
from imaging.image_io import atomic_path
from imaging.metrics import RELMSE_EPSILON, relmse

from .filters import remodulate
from .methods.asvgf import PARAMETER_FILE, fitted
from .methods.learned_mixture import (
    ARRAYS,
    CANDIDATES,
    FEATURES,
    KERNEL_START_LOGIT,
    KERNEL_TAPS,
    START_LOGIT,
    MixtureNetwork,
    candidate_images,
    flatten,
    network_of,
    shapes,
)
from .training import EXPOSURE, HELD_OUT, augmented, load_sequence, split_loaded
from .training_state import Adam, Settings, resume, run_steps

#: the committed network's steps, learning rate and channels: the command without flags makes its weights
STEPS, RATE, CHANNELS = 6000, 0.003, 8
#: crops per step and their size in pixels
BATCH, CROP = 8, 64
#: the loss counts the frames from this one on (a first frame has no history)
LOSS_FROM = 1
#: the held-out loss is measured at every this many steps
HELD_OUT_EVERY = 50
#: the least denominator of a crop's loss: a crop asvgf gets exactly right counts 0, not NaN
BASE_LOSS_FLOOR = 1e-12
#: the folder of ``--work`` that keeps each sequence's images and inputs
INPUTS_FOLDER = "mixture-inputs"
#: changes whenever what :func:`sequence_inputs` stores changes
INPUTS_VERSION = 2


#: bytes per pixel of a loaded frame (inputs, images, target as float32), and what the process holds besides
LOADED_BYTES, BASE_BYTES = 4 * (len(FEATURES) + 3 * len(CANDIDATES) + 3), 1 << 30


def training_memory(specs: list[tuple[str, object]]) -> int:
    """Bytes a training holds at its peak for sequences ``(name, spec)``: every
    frame's inputs at once, and one frame's held-out pass (its convolutions' taps)."""
    pixels = [spec.frames * spec.size[0] * spec.size[1] for _, spec in specs]
    largest = max((spec.size[0] * spec.size[1] for _, spec in specs), default=0)
    return BASE_BYTES + LOADED_BYTES * sum(pixels) + 8 * 9 * (len(FEATURES) + 2 * CHANNELS + 3) * largest


def stamp(folder: Path) -> str:
    """What a sequence's stored inputs were made from: its frames' and targets'
    files (name, size, time) and asvgf's fitted parameters."""
    digest = hashlib.sha256(f"{INPUTS_VERSION} {CANDIDATES} {FEATURES}".encode())
    digest.update(PARAMETER_FILE.read_bytes() if PARAMETER_FILE.is_file() else b"")
    for place in (folder, reference_folder(folder)):
        for path in sorted(place.glob("*.exr")):
            info = path.stat()
            digest.update(f"{path.name} {info.st_size} {info.st_mtime_ns}".encode())
    return digest.hexdigest()


def compute_inputs(folder: Path) -> dict[str, np.ndarray]:
    """Every frame's inputs (frame, feature, y, x), images remodulated as the
    method's output is (frame, image, y, x, rgb) and target, by the method's Dr.Jit code."""
    frames = augmented(load_sequence(folder), None, 0, 0, False, False, 1.0)
    params = fitted()
    params = params if params.levels is not None else replace(params, levels=frames[0].levels)
    history, xs, images_all, targets = None, [], [], []
    for f in frames:
        images, inputs, history = candidate_images(f.buffers, params, history if f.index is not None else None,
                                                   f.index, f.valid)
        height, width = f.buffers.height, f.buffers.width
        images_all.append(np.stack([np.array(f.buffers.tensor(i) if f.albedo is None
                                             else remodulate(f.buffers.tensor(i), f.albedo), np.float32)
                                    for i in images]))
        xs.append(np.stack([np.array(inputs[name], np.float32).reshape(height, width) for name in FEATURES]))
        targets.append(np.array(f.target, np.float32))
        dr.flush_malloc_cache()
    return {"x": np.stack(xs), "images": np.stack(images_all), "target": np.stack(targets)}


def stored_inputs(path: Path, expected: str, frames: int) -> dict[str, np.ndarray] | None:
    """The inputs kept at ``path`` if they are whole, of the same stamp and
    frame count, of consistent shapes and finite; else None (made anew)."""
    try:
        with np.load(path, allow_pickle=False) as data:
            if str(data["stamp"]) != expected:
                return None
            kept = {k: data[k] for k in ("x", "images", "target")}
    except Exception:  # noqa: BLE001  a cut, damaged or foreign file (BadZipFile, CRC, a missing key) is made anew
        return None
    x, images, target = kept["x"], kept["images"], kept["target"]
    if (x.ndim != 4 or x.shape[:2] != (frames, len(FEATURES))
            or images.shape != (frames, len(CANDIDATES), *x.shape[2:], 3) or target.shape != (frames, *x.shape[2:], 3)
            or not all(a.dtype == np.float32 and np.isfinite(a).all() for a in kept.values())):
        return None
    return kept


def sequence_inputs(folder: Path, store: Path) -> dict[str, np.ndarray]:
    """:func:`compute_inputs` of ``folder``, from ``store`` where it holds them
    whole for the same frames and parameters, else computed and kept there
    (a write a stop cut short is removed then)."""
    if store.exists() and not store.is_dir():
        raise UsageError(f"{store}: not a folder, where the training keeps each sequence's inputs; remove it")
    path, expected = store / f"{folder.name}.npz", stamp(folder)
    if path.exists() and not path.is_file():
        raise UsageError(f"{path}: not a file, where the training keeps {folder.name}'s inputs; remove it")
    if path.is_file():
        kept = stored_inputs(path, expected, len(frame_indices(folder)))
        if kept is not None:
            return kept
    data = compute_inputs(folder)
    store.mkdir(parents=True, exist_ok=True)
    for partial in store.glob(f".{folder.name}.npz.*"):  # atomic_path's temporary, left by a killed worker
        partial.unlink(missing_ok=True)
    with atomic_path(path, ".npz") as temporary:
        with open(temporary, "wb") as file:
            np.savez(file, stamp=expected, **data)
    return data


def taps(x: np.ndarray) -> np.ndarray:
    """The 3×3 neighbourhood of every pixel of ``x`` (channels, y, x), the border
    pixel repeated: (channels, 9 taps row by row, y, x)."""
    h, width = x.shape[1:]
    padded = np.pad(x, ((0, 0), (1, 1), (1, 1)), mode="edge")
    return np.stack([padded[:, dy:dy + h, dx:dx + width] for dy in range(3) for dx in range(3)], 1)


def taps_adjoint(d_taps: np.ndarray) -> np.ndarray:
    """d x of :func:`taps` for the taps' gradient ``d_taps`` (channels, 9, y, x)."""
    c, _, h, width = d_taps.shape
    d_padded = np.zeros((c, h + 2, width + 2), d_taps.dtype)
    for t in range(9):
        d_padded[:, t // 3:t // 3 + h, t % 3:t % 3 + width] += d_taps[:, t]
    # the repeated border pixels' gradients go to the pixel they repeat
    d_padded[:, 1, :] += d_padded[:, 0, :]
    d_padded[:, -2, :] += d_padded[:, -1, :]
    d_padded[:, :, 1] += d_padded[:, :, 0]
    d_padded[:, :, -2] += d_padded[:, :, -1]
    return d_padded[:, 1:-1, 1:-1]


def convolution(x: np.ndarray, w: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """3×3 convolution of ``x`` (channels, y, x), the border pixel repeated;
    returns (output, the taps as columns for :func:`convolution_gradient`)."""
    c, h, width = x.shape
    columns = taps(x).reshape(c * 9, h * width)
    return (w.reshape(w.shape[0], -1) @ columns + b[:, None]).reshape(-1, h, width), columns


def convolution_gradient(d_out: np.ndarray, columns: np.ndarray, w: np.ndarray, shape: tuple
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(d w, d b, d x) of :func:`convolution` for the output's gradient ``d_out``."""
    c, h, width = shape
    d2 = d_out.reshape(w.shape[0], -1)
    d_columns = (w.reshape(w.shape[0], -1).T @ d2).reshape(c, 9, h, width)
    return (d2 @ columns.T).reshape(w.shape), d2.sum(1), taps_adjoint(d_columns)


def softmax(w: np.ndarray, b: np.ndarray, hidden: np.ndarray) -> np.ndarray:
    """Per pixel, the softmax over the rows of ``w @ hidden + b`` (row, y, x)."""
    logits = np.einsum("kc,chw->khw", w, hidden) + b[:, None, None]
    weights = np.exp(logits - logits.max(0, keepdims=True))
    return weights / weights.sum(0, keepdims=True)


def softmax_gradient(weights: np.ndarray, d_weights: np.ndarray, w: np.ndarray, hidden: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(d w, d b, d hidden) of :func:`softmax` for its output's gradient ``d_weights``."""
    d_logits = weights * (d_weights - (weights * d_weights).sum(0, keepdims=True))
    return (np.einsum("khw,chw->kc", d_logits, hidden), d_logits.sum((1, 2)),
            np.einsum("kc,khw->chw", w, d_logits))


def forward(net: MixtureNetwork, x: np.ndarray, images: np.ndarray) -> tuple[np.ndarray, tuple]:
    """The blend of ``images`` (image, y, x, rgb) for inputs ``x`` (feature, y, x),
    filtered by the predicted kernel, and what the gradient needs."""
    p1, c1 = convolution(x, net.w1, net.b1)
    h1 = np.maximum(p1, 0)
    p2, c2 = convolution(h1, net.w2, net.b2)
    h2 = np.maximum(p2, 0)
    weights, kernel = softmax(net.w3, net.b3, h2), softmax(net.w4, net.b4, h2)
    blend = np.einsum("khw,khwc->chw", weights, images)
    blend_taps = taps(blend)
    out = np.einsum("thw,cthw->hwc", kernel, blend_taps)
    return out, (x, c1, p1, h1, c2, p2, h2, weights, images, kernel, blend_taps)


def backward(net: MixtureNetwork, d_out: np.ndarray, kept: tuple) -> np.ndarray:
    """d loss / d theta (the order of :func:`flatten`) for the output's gradient ``d_out``."""
    x, c1, p1, h1, c2, p2, h2, weights, images, kernel, blend_taps = kept
    d_w4, d_b4, d_h2_kernel = softmax_gradient(kernel, np.einsum("hwc,cthw->thw", d_out, blend_taps), net.w4, h2)
    d_blend = taps_adjoint(np.einsum("thw,hwc->cthw", kernel, d_out))
    d_w3, d_b3, d_h2 = softmax_gradient(weights, np.einsum("chw,khwc->khw", d_blend, images), net.w3, h2)
    d_h2 = (d_h2 + d_h2_kernel) * (p2 > 0)
    d_w2, d_b2, d_h1 = convolution_gradient(d_h2, c2, net.w2, h1.shape)
    d_w1, d_b1, _ = convolution_gradient(d_h1 * (p1 > 0), c1, net.w1, x.shape)
    gradients = {"w1": d_w1, "b1": d_b1, "w2": d_w2, "b2": d_b2, "w3": d_w3, "b3": d_b3, "w4": d_w4, "b4": d_b4}
    return np.concatenate([gradients[name].ravel() for name in ARRAYS]).astype(np.float64)


def initial(features: tuple[str, ...], channels: int, seed: int) -> np.ndarray:
    """He-initialised convolutions, the output layers 0 but asvgf's logit (:data:`START_LOGIT`)
    and the kernel's centre's (:data:`KERNEL_START_LOGIT`)."""
    rng = np.random.default_rng(seed)
    s = shapes(len(features), channels)
    w1 = rng.normal(0.0, math.sqrt(2.0 / (len(features) * 9)), s["w1"])
    w2 = rng.normal(0.0, math.sqrt(2.0 / (channels * 9)), s["w2"])
    b3 = np.zeros(s["b3"])
    b3[CANDIDATES.index("asvgf")] = START_LOGIT
    b4 = np.zeros(s["b4"])
    b4[KERNEL_TAPS // 2] = KERNEL_START_LOGIT
    return flatten(MixtureNetwork(tuple(features), w1.astype(np.float32), np.zeros(channels, np.float32),
                                  w2.astype(np.float32), np.zeros(channels, np.float32),
                                  np.zeros(s["w3"], np.float32), b3.astype(np.float32),
                                  np.zeros(s["w4"], np.float32), b4.astype(np.float32))).astype(np.float64)


def selected(data: dict, features: tuple[str, ...]) -> dict:
    """``data`` with the inputs ``features`` alone (an ablation's)."""
    rows = [FEATURES.index(name) for name in features]
    return {**data, "x": data["x"][:, rows]}


def train_step(adam: Adam, settings: Settings, train: list[dict], step: int) -> float:
    """One step on :data:`BATCH` augmented crops; returns the loss before it.
    A loss or gradient that is not finite is a UsageError, the weights left as they were."""
    rng = np.random.default_rng((settings.seed, step))
    net = network_of(adam.theta, settings.features, settings.hidden)
    asvgf = CANDIDATES.index("asvgf")
    gradient, losses = np.zeros_like(adam.theta), []
    for _ in range(BATCH):
        data = train[int(rng.integers(len(train)))]
        frames, _, height, width = data["x"].shape
        f = int(rng.integers(min(LOSS_FROM, frames - 1), frames))
        h, w = min(CROP, height), min(CROP, width)
        y0, x0 = int(rng.integers(0, height - h + 1)), int(rng.integers(0, width - w + 1))
        ys, xs = slice(y0, y0 + h), slice(x0, x0 + w)
        x, images, target = data["x"][f][:, ys, xs], data["images"][f][:, ys, xs], data["target"][f][ys, xs]
        if rng.integers(2):
            x, images, target = x[:, :, ::-1], images[:, :, ::-1], target[:, ::-1]
        if rng.integers(2):
            x, images, target = x[:, ::-1], images[:, ::-1], target[::-1]
        exposure = np.float32(np.exp(rng.uniform(*np.log(EXPOSURE))))
        x, images, target = np.ascontiguousarray(x), images * exposure, target * exposure
        out, kept = forward(net, x, images)
        base = max(relmse(images[asvgf], target), BASE_LOSS_FLOOR)
        losses.append(relmse(out, target) / base)
        d_out = (2.0 * (out - target) / (target ** 2 + RELMSE_EPSILON) / out.size / base).astype(np.float32)
        gradient += backward(net, d_out, kept)
    loss = float(np.mean(losses))
    if not math.isfinite(loss):
        raise UsageError(f"the training loss is {loss} at step {step} (a diverging step); the weights file "
                         f"was not written")
    gradient /= BATCH
    if not np.all(np.isfinite(gradient)):
        raise UsageError(f"the gradient is not finite at step {step}; the weights file was not written")
    adam.step(gradient)
    return loss


def held_out_loss(theta: np.ndarray, settings: Settings, held: list[dict]) -> float | None:
    """Mean over the held-out sequences (None: none) of their relMSE over asvgf's,
    whole frames from :data:`LOSS_FROM` on, no augmentation; 1 is asvgf, below 1 better."""
    if not held:
        return None
    net = network_of(theta, settings.features, settings.hidden)
    asvgf = CANDIDATES.index("asvgf")
    ratios = []
    for data in held:
        frames = range(min(LOSS_FROM, len(data["x"]) - 1), len(data["x"]))
        ours = np.mean([relmse(forward(net, data["x"][f], data["images"][f])[0], data["target"][f]) for f in frames])
        base = np.mean([relmse(data["images"][f][asvgf], data["target"][f]) for f in frames])
        ratios.append(float(ours) / max(float(base), BASE_LOSS_FLOOR))
    return float(np.mean(ratios))


def train(folders: list[Path], settings: Settings, checkpoint: Path, report, restart: bool = False,
          progress=None) -> tuple[np.ndarray, list, float]:
    """As :func:`denoise.training.train`, for ``learned-mixture``: the steps on the
    exported ``folders`` (:data:`HELD_OUT` held out), resumed from ``checkpoint``
    where it exists and written there after every step; ``report(step, loss,
    held-out loss, seconds)`` after each, ``progress(done, total, name)`` after
    each sequence's inputs. Returns (the weights, the curve, the seconds)."""
    names = [f.name for f in folders]
    store = checkpoint.parent / INPUTS_FOLDER

    def load(folder: Path) -> dict:
        if not frame_indices(folder):
            raise UsageError(f"{folder}: no frames")
        return selected(sequence_inputs(folder, store), settings.features)

    train_set, held = split_loaded(folders, load, progress)
    adam, curve, seconds = resume(checkpoint, settings, names, any(n in HELD_OUT for n in names),
                                  initial(settings.features, settings.hidden, settings.seed), restart)
    measured = {"loss": curve[-1][2] if curve else None, "fresh": not curve}

    def held_out(number: int) -> float | None:
        if number % HELD_OUT_EVERY == 0 or number == settings.steps - 1 or measured["fresh"]:
            measured["loss"], measured["fresh"] = held_out_loss(adam.theta, settings, held), False
        return measured["loss"]

    return run_steps(adam, curve, seconds, settings, names, checkpoint, report,
                     lambda adam, number: train_step(adam, settings, train_set, number), held_out)
