"""The training's state between steps: what a run trains (:class:`Settings`),
its optimiser (:class:`Adam`) and the checkpoint file that holds both and
the loss curve, written after every step and read to resume.

A checkpoint is a NumPy ``.npz`` of :data:`CHECKPOINT_KEYS`; one that
cannot be read, or holds what no run writes, is refused in one line naming
it and ``--restart``.
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from core.errors import UsageError
from imaging.image_io import atomic_path

from .methods import learned_asvgf, learned_mixture
from .methods.weights_file import WEIGHT_LIMIT


class Adam:
    """Adam on a NumPy parameter vector (its state is three arrays and a count: a checkpoint)."""

    def __init__(self, theta: np.ndarray, rate: float, m=None, v=None, t: int = 0):
        self.theta, self.rate, self.t = np.asarray(theta, np.float64), rate, t
        self.m = np.zeros_like(self.theta) if m is None else np.asarray(m, np.float64)
        self.v = np.zeros_like(self.theta) if v is None else np.asarray(v, np.float64)

    def step(self, gradient: np.ndarray, beta1: float = 0.9, beta2: float = 0.999, epsilon: float = 1e-8) -> None:
        self.t += 1
        self.m = beta1 * self.m + (1 - beta1) * gradient
        self.v = beta2 * self.v + (1 - beta2) * gradient * gradient
        step = self.rate * (self.m / (1 - beta1 ** self.t)) / (np.sqrt(self.v / (1 - beta2 ** self.t)) + epsilon)
        self.theta = self.theta - step


@dataclass
class Settings:
    """What a run trains: its method, features, hidden units (``learned-mixture``: channels), seed, rate,
    steps (a checkpoint must match all but steps)."""
    features: tuple[str, ...]
    hidden: int
    seed: int
    rate: float
    steps: int
    method: str = "learned-asvgf"
    #: the weights file the run writes (resolved): a checkpoint of another's is not resumed
    out: str = ""
    #: each sequence's spec by name, as a digest: a checkpoint of a sequence since changed is not resumed
    specs: tuple[tuple[str, str], ...] = ()

    def key(self) -> str:
        return json.dumps({"method": self.method, "features": list(self.features), "hidden": self.hidden,
                           "seed": self.seed, "rate": self.rate, "out": self.out,
                           "specs": {name: digest for name, digest in self.specs}})

    def parameter_count(self) -> int:
        return NETWORKS[self.method].parameter_count(len(self.features), self.hidden)


#: each trained method's network module: its feature sets and parameter count
NETWORKS = {"learned-asvgf": learned_asvgf, "learned-mixture": learned_mixture}


#: what a checkpoint records of its run beside the settings proper: compared each on its own (one that
#: records none, written before, matches any)
RUN_KEYS = ("out", "specs")


def feature_set(temporal_inputs: bool, method: str = "learned-asvgf") -> tuple[str, ...]:
    return NETWORKS[method].feature_set(temporal_inputs)


#: what a checkpoint holds (:func:`save_checkpoint`)
CHECKPOINT_KEYS = ("settings", "sequences", "theta", "m", "v", "t", "curve", "seconds")


def check_checkpoint_place(path: Path) -> None:
    """Where the checkpoint goes holds no checkpoint, or a file (a folder there is refused in one line)."""
    if (path.exists() or path.is_symlink()) and not path.is_file():
        raise UsageError(f"{path}: not a file, where the training keeps its checkpoint; remove it, or give "
                         f"--out another name (the checkpoint is named after it)")


#: the first bytes of a .npz archive (a zip file) and of a .npy array
ZIP_MAGIC, NPY_MAGIC = b"PK\x03\x04", b"\x93NUMPY"


def load_checkpoint(path: Path, settings: Settings, names: list[str], held_out: bool) -> dict | None:
    """The checkpoint's state, or None where there is none; one that cannot
    be read, holds values no run writes, or was made with other settings or
    sequences is a one-line refusal naming it (``--restart`` starts over).
    ``held_out``: whether some of ``names`` are held out (else the curve's held-out losses are NaN)."""
    check_checkpoint_place(path)
    if not path.exists() and not path.is_symlink():
        return None
    try:
        with open(path, "rb") as file:  # np.load leaves a file it opened open when it is no archive
            if file.read(len(ZIP_MAGIC)) not in (ZIP_MAGIC, NPY_MAGIC[:len(ZIP_MAGIC)]):  # else NumPy tries pickle
                raise ValueError("not an .npz archive")
            file.seek(0)
            data = np.load(file, allow_pickle=False)
            if not hasattr(data, "files"):
                raise ValueError("one array, not an archive of arrays")
            state = {k: data[k] for k in data.files}
    except Exception as error:  # noqa: BLE001  zero bytes (EOFError), a cut file (BadZipFile), not a .npz
        reason = " ".join(str(error).split()) or type(error).__name__
        if "pickle" in reason:  # NumPy's own advice is to load it unsafely: a checkpoint never holds objects
            reason = "it holds Python objects, where a checkpoint holds arrays"
        raise UsageError(f"{path}: not a training checkpoint ({reason}); --restart starts over") from None
    problem = checkpoint_problem(state, settings, names, held_out)
    if problem is not None:
        raise UsageError(f"{path}: {problem}; --restart starts over")
    return state


def checkpoint_problem(state: dict, settings: Settings, names: list[str], held_out: bool) -> str | None:
    """What is wrong with a checkpoint's ``state`` (None: nothing): every key, type and
    shape :func:`save_checkpoint` writes, finite values, a step count that is its curve's."""
    missing = [k for k in CHECKPOINT_KEYS if k not in state]
    if missing:
        return f"not a training checkpoint (no {', '.join(missing)})"
    if any(state[k].shape != () or state[k].dtype.kind != "U" for k in ("settings", "sequences")):
        return "not a training checkpoint (its settings or sequences are not a text)"
    try:
        sequences = json.loads(str(state["sequences"]))
    except ValueError:
        sequences = None
    try:
        stored = json.loads(str(state["settings"]))
    except ValueError:
        stored = None
    current = json.loads(settings.key())
    if isinstance(stored, dict) and stored.get("out") and current["out"] and stored["out"] != current["out"]:
        return (f"the checkpoint of another training, into {stored['out']}; give this one another --out file "
                f"name or another --work (--restart would discard that training's steps)")
    if not isinstance(stored, dict) or {k: v for k, v in stored.items() if k not in RUN_KEYS} != {
            k: v for k, v in current.items() if k not in RUN_KEYS}:
        differing = sorted(k for k in current if k not in RUN_KEYS and (stored or {}).get(k) != current[k])
        return f"a checkpoint of other settings ({', '.join(differing) or 'unreadable'})"
    before, now = stored.get("specs") or {}, current["specs"]
    changed = sorted(name for name in now if isinstance(before, dict) and name in before and before[name] != now[name])
    if changed:
        return f"a checkpoint of other sequences ({', '.join(changed)}: its spec changed since)"
    if sequences != names:
        return "a checkpoint of other sequences"
    count = settings.parameter_count()
    for k in ("theta", "m", "v"):
        if state[k].dtype.kind != "f" or state[k].shape != (count,):
            return f"{k} holds {state[k].dtype} of shape {state[k].shape}, not the {count} parameters' values"
        if not np.isfinite(state[k]).all():
            return f"{k} holds values that are not finite"
    if (np.abs(state["theta"]) > WEIGHT_LIMIT).any():
        return f"theta holds weights beyond {WEIGHT_LIMIT:g}, which no weights file may hold"
    if (state["v"] < 0).any():
        return "v (Adam's mean squared gradient) holds negative values"
    t, curve, seconds = state["t"], state["curve"], state["seconds"]
    if t.shape != () or t.dtype.kind not in "iu":
        return f"t is {t.dtype} of shape {t.shape}, not a step count"
    if curve.dtype.kind != "f" or curve.ndim != 2 or curve.shape[1] != 3:
        return f"curve is {curve.dtype} of shape {curve.shape}, not rows of (step, loss, held-out loss)"
    if int(t) != len(curve):
        return f"t is {int(t)}, but its curve holds {len(curve)} steps"
    if not np.array_equal(curve[:, 0], np.arange(len(curve))):
        return f"its curve's steps are not 0 to {len(curve) - 1} in order"
    losses = curve[:, 1:] if held_out else curve[:, 1:2]  # else the held-out losses are NaN
    if not (np.isfinite(losses).all() and (losses >= 0).all()):
        return "its curve holds a loss that is not finite or is negative"
    if seconds.shape != () or seconds.dtype.kind != "f":
        return f"seconds is {seconds.dtype} of shape {seconds.shape}, not a time"
    if not 0 <= float(seconds) < math.inf:
        return f"seconds is {float(seconds)}, not a finite time"
    return None


def save_checkpoint(path: Path, settings: Settings, names: list[str], adam: Adam, curve: list, seconds: float) -> None:
    # a step without held-out sequences is stored with a NaN held-out loss
    rows = np.array([(s, a, np.nan if b is None else b) for s, a, b in curve], np.float64).reshape(-1, 3)
    with atomic_path(path, ".npz") as temporary:
        with open(temporary, "wb") as file:
            np.savez(file, settings=settings.key(), sequences=json.dumps(names), theta=adam.theta, m=adam.m,
                     v=adam.v, t=adam.t, curve=rows, seconds=seconds)


def resume(checkpoint: Path, settings: Settings, names: list[str], held_out: bool, start: np.ndarray,
           restart: bool) -> tuple[Adam, list, float]:
    """(Adam, the curve [(step, loss, held-out loss)], the seconds so far): from
    ``checkpoint`` where it exists and not ``restart``, else from weights ``start``."""
    state = None if restart else load_checkpoint(checkpoint, settings, names, held_out)
    if state is None:
        return Adam(start, settings.rate), [], 0.0
    curve = [(int(s), a, None if math.isnan(b) else b) for s, a, b in state["curve"].tolist()]
    return (Adam(state["theta"], settings.rate, state["m"], state["v"], int(state["t"])), curve,
            float(state["seconds"]))


def run_steps(adam: Adam, curve: list, seconds: float, settings: Settings, names: list[str], checkpoint: Path,
              report, step, held_out) -> tuple[np.ndarray, list, float]:
    """The steps from ``adam.t`` to ``settings.steps``: each measures ``held_out(number)``
    (None: no held-out sequences), takes ``step(adam, number)`` (the loss before it),
    extends the curve, writes the checkpoint and calls ``report(number, loss, held-out
    loss, seconds)``. Returns (the weights, the curve, the seconds of all steps)."""
    for number in range(adam.t, settings.steps):
        start = time.perf_counter()
        held_loss = held_out(number)
        if held_loss is not None and not math.isfinite(held_loss):
            raise UsageError(f"the held-out loss is {held_loss} at step {number}; the weights file was not written")
        loss = step(adam, number)
        seconds += time.perf_counter() - start
        curve.append((number, loss, held_loss))
        save_checkpoint(checkpoint, settings, names, adam, curve, seconds)
        report(number, loss, held_loss, seconds)
    if not curve:
        raise UsageError(f"{checkpoint}: the checkpoint has no steps; --restart starts over")
    return adam.theta, curve, seconds
