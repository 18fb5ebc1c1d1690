"""Fitting asvgf's continuous parameters by gradient descent through Dr.Jit's autodiff.

    python -m denoise.fit [SPEC.json ...] [--work DIR] [--steps N] [--rate R]
                          [--switch-frame F] [--out FILE] [--quiet]
    python -m denoise.fit --evaluate FOLDER [--switch-frame F]

The training sequences (default ``scenes/sequences/training/*.json``, none of
them the benchmark's) are exported into ``--work`` once (a rerun renders
nothing). Each step runs :func:`denoise.methods.asvgf.asvgf` over every frame of
every sequence in ``llvm_ad_rgb`` with gradients enabled on the continuous
parameters (the edge-stopping sigmas, the history lengths, both clip widths,
the anti-lag gain and threshold, the wide level's history length), the
history carried from frame to frame, so ``dr.backward`` differentiates the
whole temporal and spatial pipeline. The steps run in a worker process: one
step is one native call, and Ctrl-C or SIGTERM must not wait for it.
The loss is the relMSE of every frame against its ground truth, averaged.
Each sequence also enters a second time with a light switch: beauty and
ground truth of frames >= ``--switch-frame`` scaled by 0.2, a light dimming
to 20 % in one frame (what the anti-lag is for).

Parameters are fitted as logarithms with Adam (``mi.ad.Adam``) and kept inside
the ranges asvgf's options declare (:mod:`denoise.methods.asvgf`); the loss per step is
printed (not with ``--quiet``). A step whose loss is not finite stops the fit
with one line and exit 2, the parameter file left as it was; otherwise the
parameters of the lowest loss are written to ``--out``
(``denoise/asvgf_params.json``, which ``asvgf`` reads by default).

``--evaluate FOLDER`` fits nothing: it prints the relMSE per frame of
``svgf``, ``asvgf`` hand-set and ``asvgf`` fitted on an exported folder, as
rendered and with the light switch at ``--switch-frame``, and the response:
frames after the switch until the relMSE is back within 1.5x of the frame
before it (relMSE as dimmed, and of the images divided by 0.2, which the
metric's epsilon does not favour).
"""
from __future__ import annotations

if __name__ == "__main__":  # first: ./.venv's Python, the libLLVM, then Dr.Jit (see core.launcher)
    from core.launcher import start
    start("python -m denoise.fit", "denoise.fit")

import argparse
import json
import math
from dataclasses import dataclass, replace
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

from core.entry import ArgumentParser, finish, printable, run
from core.errors import UsageError
from core.inputs import check_outside
from core.numbers import ascii_float, ascii_int
from export import Spec, reference_folder
from export.cluster import CLUSTER_OPTIONS, add_cluster_options, cluster_options
from export.frames import frame_indices, read_frame, same_size
from export.ground_truth import GROUND_TRUTH_RECORD, check_ground_truth, check_outside_exports, check_work_folder
from imaging.image_io import atomic_path, check_writable, read_exr_rgb
from imaging.metrics import relmse
from renderer.variants import set_variant

from .filters import FrameArrays, demodulate, relmse_loss, remodulate, reproject
from .methods import data_files, from_name, make
from .methods.asvgf import FITTED_OPTIONS, PARAMETER_FILE, FilterValues, asvgf, fitted, hand_set
from .pipeline import check_sequences_fit
from .temporal_metrics import QUALITY_FROM
from .validate import check_spec_name, render
from .worker_process import ignore_group_signals, run_in_worker

ROOT = Path(__file__).resolve().parent.parent
TRAINING = sorted((ROOT / "scenes" / "sequences" / "training").glob("*.json"))
#: what a light switch scales the frames after it by
SWITCH_SCALE = 0.2


@dataclass
class PreparedFrame:
    """One frame as the filter takes it: buffers (demodulated colour), the back
    projection onto the previous frame, the albedo to remodulate, the truth."""
    buffers: object  # denoise.filters.FrameArrays
    index: object  # mi.UInt32 or None (first frame)
    valid: object  # mi.Bool or None
    albedo: object  # mi.TensorXf or None
    reference: object  # mi.TensorXf


def prepare(folder: Path, scale_from: int | None = None, scale: float = SWITCH_SCALE) -> list[PreparedFrame]:
    """Every frame of ``folder`` with its ground truth from ``FOLDER_reference``,
    as the Denoiser would feed asvgf (usable values, albedo demodulation, back
    projection); beauty and truth of frames >= ``scale_from`` times ``scale``."""
    def tensor(a):
        return mi.TensorXf(np.ascontiguousarray(a, np.float32))

    usable = make("asvgf").usable_frame
    prepared, previous, previous_ids, prepared_indices = [], None, None, []
    for i in frame_indices(folder):
        frame = usable(read_frame(folder, i))
        truth_path = reference_folder(folder) / f"beauty_{i}.exr"
        truth = read_exr_rgb(truth_path)
        same_size(folder / f"beauty_{i}.exr", frame.beauty.shape, truth_path, truth.shape)
        if previous is not None:
            same_size(folder / f"beauty_{i}.exr", frame.beauty.shape, folder / f"beauty_{prepared_indices[-1]}.exr",
                      previous.beauty.shape)
        prepared_indices.append(i)
        factor = scale if scale_from is not None and i >= scale_from else 1.0
        color, ids, position = tensor(frame.beauty * factor), tensor(frame.ids), tensor(frame.position)
        albedo = tensor(frame.albedo) if frame.albedo is not None else None
        if albedo is not None:
            color = demodulate(color, albedo)
        index = valid = None
        if previous is not None:
            index, valid = reproject(position, ids, previous_ids, frame.object_to_world, previous.object_to_world,
                                     previous.world_to_screen)
        prepared.append(PreparedFrame(FrameArrays(color, tensor(frame.normal), position, albedo), index, valid, albedo,
                                      tensor(truth * factor)))
        previous, previous_ids = frame, ids
    return prepared


def run_sequence(frames: list[PreparedFrame], params, values=None) -> list:
    """asvgf over ``frames``: the remodulated results (TensorXf), history carried along."""
    history, results = None, []
    for f in frames:
        result, history = asvgf(f.buffers, params, history if f.index is not None else None, f.index, f.valid,
                                values)
        results.append(remodulate(result, f.albedo) if f.albedo is not None else result)
    return results


def sequence_loss(sequences: list[list[PreparedFrame]], params, values=None):
    """Mean relMSE over every frame of every sequence (a Dr.Jit Float)."""
    total, count = 0.0, 0
    for frames in sequences:
        for f, result in zip(frames, run_sequence(frames, params, values)):
            total = total + relmse_loss(result, f.reference)
            count += 1
    return total / count


class Fit:
    """Adam on the logarithms of the continuous parameters, kept in range."""

    def __init__(self, params, rate: float):
        # the parameter vector, its names and bounds: asvgf's declarations of what is fitted
        self.params, self.ranges = params, {o.key: (o.low, o.high) for o in FITTED_OPTIONS}
        self.optimizer = mi.ad.Adam(lr=rate)
        for name, value in params.continuous().items():
            # a clip width or threshold of 0 has no logarithm: fit from a tiny value instead
            self.optimizer[name] = mi.Float(math.log(max(value, 1e-3)))
        self.dr = dr

    def values(self):


        dr = self.dr
        return FilterValues(**{name: dr.clip(dr.exp(self.optimizer[name]), max(low, 1e-6), high)
                               for name, (low, high) in self.ranges.items()})

    def step(self, sequences) -> float:
        """One gradient step; returns the loss before it."""
        dr = self.dr
        values = self.values()
        loss = sequence_loss(sequences, self.params, values)
        value = float(loss[0])
        if not math.isfinite(value):
            raise UsageError(f"the loss is {value} (a diverging step); the parameter file was not written")
        dr.backward(loss)
        self.optimizer.step()
        return value

    def current(self) -> dict[str, float]:
        return self.values().as_floats()


def display_path(path: Path) -> str:
    """``path`` relative to the repository where it lies inside it."""
    path = Path(path).resolve()
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path)


def write_parameters(path: Path, values: dict[str, float], loss: float, hand_set_loss: float, sources) -> None:
    data = {"parameters": {k: round(v, 6) for k, v in values.items()},
            "training_loss": loss, "hand_set_loss": hand_set_loss,
            "training": [display_path(s) for s in sources]}
    with atomic_path(path, ".json") as temporary:
        Path(temporary).write_text(json.dumps(data, indent=2) + "\n")


def evaluate(folder: Path, switch: int | None) -> dict[str, tuple[list[float], list[float]]]:
    """Per method: (relMSE per frame as rendered or dimmed, relMSE of the images divided by the dimming)."""
    indices = frame_indices(folder)
    factors = [SWITCH_SCALE if switch is not None and i >= switch else 1.0 for i in indices]
    truth = [read_exr_rgb(reference_folder(folder) / f"beauty_{i}.exr") * f for i, f in zip(indices, factors)]
    denoiser = from_name("svgf")
    outputs = {"svgf": [denoiser.step(replace(frame, beauty=frame.beauty * f))
                        for frame, f in zip((read_frame(folder, i) for i in indices), factors)]}
    frames = prepare(folder, switch)
    for name, params in (("asvgf hand-set", hand_set()), ("asvgf fitted", fitted())):
        outputs[name] = [np.array(r) for r in run_sequence(frames, params)]
    return {name: ([relmse(o, t) for o, t in zip(images, truth)],
                   [relmse(o / f, t / f) for o, t, f in zip(images, truth, factors)])
            for name, images in outputs.items()}


def response(values: list[float], switch: int) -> str:
    """Frames after ``switch`` until ``values`` is back within 1.5x of the frame before it."""
    for k in range(switch, len(values)):
        if values[k] <= 1.5 * values[switch - 1]:
            return str(k - switch)
    return f">{len(values) - 1 - switch}"


def print_evaluation(folder: Path, switch: int) -> None:
    for label, at in (("as rendered", None), (f"light dimmed to 20 % from frame {switch}", switch)):
        print(f"{printable(folder.name)}, {label}: relMSE per frame")
        for name, (dimmed, undimmed) in evaluate(folder, at).items():
            rows = [("", dimmed)] if at is None else [(" (as dimmed)", dimmed), (" (/0.2)", undimmed)]
            for suffix, values in rows:
                mean = (f"  mean>={QUALITY_FROM} {sum(values[QUALITY_FROM:]) / (len(values) - QUALITY_FROM):.4f}"
                        if len(values) > QUALITY_FROM else "")
                tail = (f"{mean}  last {values[-1]:.4f}"
                        + (f"  response {response(values, at)}" if at is not None else ""))
                print(f"  {name + suffix:28s} " + " ".join(f"{v:.4f}" for v in values) + tail)


def _parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(prog="python -m denoise.fit", description=__doc__.split("\n\n")[0])
    parser.add_argument("specs", type=Path, nargs="*", metavar="SPEC.json",
                        help="training sequences (default: scenes/sequences/training/*.json)")
    parser.add_argument("--work", type=Path, default=ROOT / "out" / "fit", help="where they are rendered (out/fit)")
    parser.add_argument("--steps", type=ascii_int, default=40, help="gradient steps (40)")
    parser.add_argument("--rate", type=ascii_float, default=0.05, help="Adam's learning rate on log parameters (0.05)")
    parser.add_argument("--switch-frame", type=ascii_int, default=None,
                        help="the light switch's first dimmed frame in the switched copies (4)")
    parser.add_argument("--out", type=Path, default=ROOT / "denoise" / "asvgf_params.json",
                        help="the parameter file (denoise/asvgf_params.json)")
    parser.add_argument("--quiet", action="store_true", help="print nothing but errors")
    parser.add_argument("--evaluate", type=Path, metavar="FOLDER",
                        help="fit nothing: relMSE per frame of svgf and asvgf (hand-set, fitted) on FOLDER")
    add_cluster_options(parser)
    return parser


#: the light switch's first dimmed frame when --switch-frame is not given
SWITCH_FRAME = 4


def check_switch_frame(frame: int | None, frames: int, where: Path) -> int:
    """The switch frame (``frame``, or :data:`SWITCH_FRAME` where --switch-frame was not given):
    a switch needs a frame before it and one after it, in every sequence (``where`` has the fewest)."""
    if frames < 2:
        raise UsageError(f"{where}: {frames} frame; a light switch needs at least 2 frames")
    if frame is None:
        if SWITCH_FRAME <= frames - 1:
            return SWITCH_FRAME
        raise UsageError(f"{where}: {frames} frames; the light switch goes at frame {SWITCH_FRAME} unless "
                         f"--switch-frame says otherwise (from 1 to {frames - 1} here), which needs "
                         f"{SWITCH_FRAME + 1} frames")
    if not 1 <= frame <= frames - 1:
        raise UsageError(f"--switch-frame must be from 1 to {frames - 1} (the sequences have {frames} frames), "
                         f"got {frame}")
    return frame


#: the options of a fit, which --evaluate (it fits nothing) does not take
FIT_ONLY = {"specs": "SPEC.json", "work": "--work", "steps": "--steps", "rate": "--rate", "out": "--out",
            **{name: flag for name, (flag, _) in CLUSTER_OPTIONS.items()}}


def _main(argv: list[str] | None) -> int:
    args = _parser().parse_args(argv)
    if args.evaluate is not None:
        defaults = _parser().parse_args([])
        given = [flag for name, flag in FIT_ONLY.items() if getattr(args, name) != getattr(defaults, name)]
        if given:
            raise UsageError(f"--evaluate fits nothing: {given[0]} does not apply to it")
    specs = args.specs or TRAINING
    if not specs:
        raise UsageError("no training sequences (scenes/sequences/training/*.json is empty)")
    if not 1 <= args.steps <= 10000:
        raise UsageError(f"--steps must be from 1 to 10000, got {args.steps}")
    if not (0.0 < args.rate <= 10.0):
        raise UsageError(f"--rate must be in (0, 10], got {args.rate}")
    where = cluster_options(args)

    for spec in specs:  # a fit never writes onto a spec it reads, nor into the frames it trains on
        check_outside({"--out": args.out, "--work": args.work}, {"SPEC.json": spec})
        check_spec_name(spec)
        frames = args.work / Path(spec).stem
        check_outside({"--out": args.out}, {f"frame folder (--work) of {Path(spec).name}": frames,
                                            f"ground truth (--work) of {Path(spec).name}": reference_folder(frames)})
    check_work_folder(args.work)  # after: a --work that is a spec is told so, not merely that it is a file
    if args.out.suffix.lower() != ".json":
        raise UsageError(f"--out {args.out}: the parameter file is JSON; give a name ending in .json")
    if args.evaluate is not None:
        if (args.evaluate / GROUND_TRUTH_RECORD).is_file():  # its beauty_i.exr are the truth, not frames
            frames = args.evaluate.parent / args.evaluate.name.removesuffix("_reference")
            raise UsageError(f"--evaluate {args.evaluate}: an export's ground truth ({GROUND_TRUTH_RECORD}), not its "
                             f"frames" + (f"; give {frames}" if frames != args.evaluate and frames.is_dir() else ""))
        if not (args.evaluate / "beauty_0.exr").is_file():
            raise UsageError(f"{args.evaluate}: not an exported frame folder (no beauty_0.exr)")
        indices = frame_indices(args.evaluate)
        truth = reference_folder(args.evaluate)
        missing = [i for i in indices if not (truth / f"beauty_{i}.exr").is_file()]
        if missing:
            raise UsageError(f"{args.evaluate}: no ground truth for frame {missing[0]} "
                             f"(no {truth / f'beauty_{missing[0]}.exr'}; python -m export renders it)")
        check_ground_truth("--evaluate's ground truth", truth, args.evaluate, frames_flag="--evaluate")
        switch = check_switch_frame(args.switch_frame, len(indices), args.evaluate)
        set_variant("llvm_ad_rgb", jit=True)
        print_evaluation(args.evaluate, switch)
        return 0

    check_outside_exports({"--out": args.out})
    check_outside({"--out": args.out}, data_files(keep=(PARAMETER_FILE,)))  # a fit writes parameters, no weights
    check_writable("--out", args.out)  # before minutes of fitting, not after
    loaded = [(path, Spec.load(path)) for path in specs]  # all checked before any work
    check_frames_fit(loaded)
    shortest, spec = min(loaded, key=lambda loaded_spec: loaded_spec[1].frames)
    switch = check_switch_frame(args.switch_frame, spec.frames, shortest)
    set_variant("llvm_ad_rgb", jit=True)

    targets = [args.work / path.stem for path, _ in loaded]
    render([(spec, target) for (_, spec), target in zip(loaded, targets)], **where)
    best, hand_set_loss = fit_interruptibly(targets, switch, args.steps, args.rate, args.quiet)
    write_parameters(args.out, best[1], best[0], hand_set_loss, specs)
    if not args.quiet:
        print(f"lowest loss {best[0]:.6f} (hand-set {hand_set_loss:.6f}); parameters written to {printable(args.out)}")
    return 0


#: a fit holds every frame of every sequence (each twice: as rendered and switched) with
#: its derivatives: bytes per pixel of a spec's frame, and what the process holds besides
#: (measured from the peak memory of fits at two sizes: docs/asvgf.md)
FIT_BYTES_PER_PIXEL, FIT_BASE_BYTES = 1400, 512 * 2 ** 20


def check_frames_fit(loaded: list[tuple[Path, Spec]], memory: int | None = None) -> None:
    """Every frame of ``loaded`` held at once within the memory available (``memory``:
    bytes; measured if None), else a :class:`LimitError` before anything is rendered."""
    pixels = sum(spec.frames * spec.size[0] * spec.size[1] for _, spec in loaded)
    check_sequences_fit("fitting", loaded, FIT_BASE_BYTES + FIT_BYTES_PER_PIXEL * pixels,
                        "fit on smaller frames or fewer of them", memory)


def fit_steps(targets: list[Path], switch_frame: int, steps: int, rate: float, quiet: bool):
    """The gradient steps on the exported ``targets``; returns ((lowest loss, its values), the hand-set loss)."""
    sequences = []
    for target in targets:
        sequences.append(prepare(target))
        sequences.append(prepare(target, scale_from=switch_frame))
    fit = Fit(hand_set(), rate)
    best, hand_set_loss = None, None
    for step in range(steps):
        values = fit.current()
        loss = fit.step(sequences)
        hand_set_loss = loss if hand_set_loss is None else hand_set_loss
        if best is None or loss < best[0]:
            best = (loss, values)
        if not quiet:
            print(f"step {step}: loss {loss:.6f}  " + " ".join(f"{k} {v:.4g}" for k, v in values.items()), flush=True)
    return best, hand_set_loss


def fit_worker(connection, *arguments) -> None:
    """:func:`fit_steps` in a worker process, started with GROUP_SIGNALS blocked
    and then ignoring them: the parent alone answers a terminal's signals and
    stops this process, which prints nothing of its own (a thread of a native
    library may run with them unblocked); sends ("done", the result) or ("error", its line)."""
    ignore_group_signals()
    set_variant("llvm_ad_rgb", quiet=True)
    try:
        connection.send(("done", fit_steps(*arguments)))
    except UsageError as error:
        connection.send(("error", str(error)))


def fit_interruptibly(targets: list[Path], switch_frame: int, steps: int, rate: float, quiet: bool):
    """:func:`fit_steps` in a worker process that this one waits for
    (:func:`denoise.worker_process.run_in_worker`: Ctrl-C and SIGTERM end it)."""
    return run_in_worker(fit_worker, (targets, switch_frame, steps, rate, quiet), "the fit")[0]


def main(argv: list[str] | None = None) -> int:
    return run("python -m denoise.fit", lambda: _main(argv))


if __name__ == "__main__":
    finish(main())
