"""Training ``learned-asvgf``'s or ``learned-mixture``'s network (the libraries:
:mod:`denoise.training`, :mod:`denoise.mixture_training`).

    python -m denoise.train [SPEC.json ...] [--method M] [--procedural N] [--work DIR] [--steps N] [--rate R]
                            [--hidden H] [--no-temporal-inputs] [--seed S] [--out FILE] [--plot FILE]
                            [--restart] [--quiet]

The training sequences (default ``scenes/sequences/training/network/*.json``
and the sequences of 48 procedurally generated scenes, ``scenes/procedural.py``,
written into ``WORK/procedural/``)
are exported into ``--work`` once (a rerun renders nothing); a benchmark
sequence or scene, or a sequence without ground truth, is refused in one
line before any work. Each step prints the training loss and the held-out
sequences' loss on stderr (progress: each sequence's relMSE over asvgf's, 1
is asvgf, below 1 better; the final line goes to stdout), and writes a checkpoint
(``WORK/OUT-NAME.checkpoint.npz``): Ctrl-C stops at once (exit 130) with
the last step's checkpoint kept, and a rerun with the same settings resumes
from it (``--restart`` starts over). After the last step the weights file
(``--out``, default the method's ``denoise/learned_asvgf.json`` or
``denoise/learned_mixture.json``) gets the weights and a
record of the run, and ``--plot`` the loss curves. A run of other settings or
sequences than the record of the committed file it would replace says so in
one note before any work. A loss that is not
finite stops the run with one line (exit 2), the weights file untouched.
One training at a time in a ``--work`` and into an ``--out``: a second is refused in one line.
The steps run in a worker process: one step is native code that no signal
interrupts, and Ctrl-C must not wait for it.
"""
from __future__ import annotations

if __name__ == "__main__":  # first: ./.venv's Python, the libLLVM, then Dr.Jit (see core.launcher)
    from core.launcher import start
    start("python -m denoise.train", "denoise.train")

import argparse
import datetime
import hashlib
import json
import os
import re
import shlex
import sys
import time
from pathlib import Path

import numpy as np

from core.entry import ArgumentParser, finish, one_line, printable, run
from core.errors import FrameError, SpecError, ToolkitError, UsageError
from core.inputs import check_outside
from core.machine import machine
from core.numbers import ascii_float, ascii_int
from course import data_dir, resolve_scene
from export import Spec, reference_folder
from export.cluster import add_cluster_options, cluster_options
from export.files import locked, name_locked
from export.frames import frame_indices, read_frame, same_size
from export.ground_truth import check_outside_exports, check_work_folder
from imaging.image_io import atomic_path, check_writable, read_exr_rgb
from renderer.variants import set_variant
from scenes.procedural import SEED as PROCEDURAL_SEED, write_sequences

from . import training
from .methods import data_files
from .methods.base import RADIANCE_LIMIT
from .methods.weights_file import WEIGHT_LIMIT
from .pipeline import check_sequences_fit
from .trainers import TRAINED, WEIGHTS_FILES
from .training import BENCHMARK, HELD_OUT, ROOT, TRAINING
from .training_state import Settings, check_checkpoint_place, feature_set, load_checkpoint
from .validate import check_folders, check_spec_name, render
from .worker_process import ignore_group_signals, run_in_worker

DOCS = ROOT / "docs"
#: procedural scenes trained on beside the default specs, and the folder of --work they are written into
PROCEDURAL, PROCEDURAL_FOLDER = 48, "procedural"
PROCEDURAL_MAX = 1000


def _parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(prog="python -m denoise.train", description=__doc__.split("\n\n")[0])
    parser.add_argument("specs", type=Path, nargs="*", metavar="SPEC.json",
                        help="training sequences (default: scenes/sequences/training/network/*.json)")
    parser.add_argument("--method", choices=tuple(TRAINED), default="learned-asvgf",
                        help="the method whose network is trained (learned-asvgf)")
    parser.add_argument("--procedural", type=ascii_int, metavar="N",
                        help=f"also train on N procedurally generated scenes' sequences (scenes/procedural.py, "
                             f"written into WORK/{PROCEDURAL_FOLDER}/; default {PROCEDURAL} with the default "
                             f"specs, 0 with specs given)")
    parser.add_argument("--work", type=Path, default=ROOT / "out" / "train",
                        help="where they are rendered, and the checkpoint (out/train)")
    defaults = {key: ", ".join(f"{getattr(t, key)} for {name}" for name, t in TRAINED.items())
                for key in ("steps", "rate", "hidden")}
    parser.add_argument("--steps", type=ascii_int, help=f"gradient steps ({defaults['steps']})")
    parser.add_argument("--rate", type=ascii_float, help=f"Adam's learning rate ({defaults['rate']})")
    parser.add_argument("--hidden", type=ascii_int,
                        help=f"hidden units, or learned-mixture's channels ({defaults['hidden']})")
    parser.add_argument("--no-temporal-inputs", dest="temporal_inputs", action="store_false",
                        help="the ablation: the network reads none of the history's statistics (the noise "
                             "estimate stays, and learned-mixture's image ratios)")
    parser.add_argument("--seed", type=ascii_int, default=0, help="the first layer's draw and every step's (0)")
    parser.add_argument("--out", type=Path, help="the weights file (denoise/learned_asvgf.json or "
                        "denoise/learned_mixture.json)")
    parser.add_argument("--plot", type=Path, help="the loss curves' PNG (default: docs/OUT-NAME_loss.png for "
                        "the committed weights files, else OUT-NAME_loss.png beside --out)")
    parser.add_argument("--restart", action="store_true", help="start over instead of resuming the checkpoint")
    parser.add_argument("--quiet", action="store_true", help="print nothing but errors")
    add_cluster_options(parser)
    return parser


#: the largest --seed (a 32-bit word: every generator and record takes it)
SEED_MAX = 2 ** 32 - 1


def default_plot(out: Path) -> Path:
    """The loss curves' PNG without --plot: docs/OUT-NAME_loss.png for a committed weights
    file (its page shows it), else OUT-NAME_loss.png beside ``out`` (a scratch run writes
    nothing into the repository)."""
    committed = {p.resolve() for p in WEIGHTS_FILES}
    folder = DOCS if out.resolve() in committed else out.parent
    return folder / f"{out.stem}_loss.png"


def _main(argv: list[str] | None) -> int:
    args = _parser().parse_args(argv)
    where = cluster_options(args)
    trained = TRAINED[args.method]
    for key in ("steps", "rate", "hidden"):
        if getattr(args, key) is None:
            setattr(args, key, getattr(trained, key))
    if args.out is None:
        args.out = trained.weights
    if not 1 <= args.steps <= 100000:
        raise UsageError(f"--steps must be from 1 to 100000, got {args.steps}")
    if not 0.0 < args.rate <= 1.0:
        raise UsageError(f"--rate must be in (0, 1], got {args.rate}")
    if not 1 <= args.hidden <= trained.max_hidden:
        raise UsageError(f"--hidden must be from 1 to {trained.max_hidden} for {args.method}, got {args.hidden}")
    if not 0 <= args.seed <= SEED_MAX:  # NumPy's generator takes no negative seed (it failed in the worker)
        raise UsageError(f"--seed must be from 0 to {SEED_MAX}, got {args.seed}")
    if args.plot is not None and args.plot.suffix.lower() != ".png":
        raise UsageError(f"--plot writes PNG: name it .png, got {printable(args.plot)}")
    if args.out.suffix.lower() != ".json":
        raise UsageError(f"--out {args.out}: the weights file is JSON; give a name ending in .json")
    for name, other in TRAINED.items():  # the other method's committed file would stop that method loading
        committed = {p.resolve() for p in (other.weights, *other.ablations.values())}
        if name != args.method and args.out.resolve() in committed:
            raise UsageError(f"--out {printable(args.out)} is {name}'s committed weights file, not {args.method}'s; "
                             f"give {args.method}'s ({display_path(trained.weights)} or an ablation's) or another name")
    plot = args.plot if args.plot is not None else default_plot(args.out)
    specs = args.specs or TRAINING
    if not specs:
        raise UsageError("no training sequences (scenes/sequences/training/network/*.json is empty)")
    for spec in specs:  # a run never writes onto a spec it reads
        check_outside({"--out": args.out, "--work": args.work, "--plot": plot}, {"SPEC.json": spec})
    check_work_folder(args.work)  # after: a --work that is a spec is told so, not merely that it is a file
    procedural = args.procedural if args.procedural is not None else (0 if args.specs else PROCEDURAL)
    if not 0 <= procedural <= PROCEDURAL_MAX:
        raise UsageError(f"--procedural must be from 0 to {PROCEDURAL_MAX}, got {procedural}")
    generated = write_sequences(args.work / PROCEDURAL_FOLDER, procedural) if procedural else []
    specs = [*specs, *generated]
    # every refusal before any work; in name order: a training is of a set of sequences, whatever order they came in
    loaded = sorted(check_specs(specs), key=lambda item: item[0].stem)
    check_frames_fit(loaded, method=args.method)
    names = [path.stem for path, _ in loaded]
    if len(set(names)) != len(names):
        twice = sorted({str(p) for p, _ in loaded if names.count(p.stem) > 1})
        raise UsageError(f"two training sequences of one name ({', '.join(twice)}): they would share a "
                         f"folder in --work")
    if not [n for n in names if n not in HELD_OUT]:
        raise UsageError(f"every sequence given is held out ({', '.join(HELD_OUT)}): nothing to train on")
    for path, _ in loaded:  # nor into a sequence's frames or its ground truth
        check_spec_name(path)
        frames = args.work / path.stem
        check_outside({"--out": args.out, "--plot": plot},
                      {f"frame folder (--work) of {path.name}": frames,
                       f"ground truth (--work) of {path.name}": reference_folder(frames)})
    check_outside_exports({"--out": args.out, "--plot": plot})
    check_outside({"--out": args.out}, data_files(keep=WEIGHTS_FILES))  # weights, no parameters
    check_writable("--out", args.out)
    check_writable("--plot", plot)
    settings = Settings(feature_set(args.temporal_inputs, args.method), args.hidden, args.seed, args.rate, args.steps,
                        args.method, str(args.out.resolve()),
                        tuple((path.stem, hashlib.sha256(json.dumps(spec.as_json(), sort_keys=True).encode())
                               .hexdigest()[:16]) for path, spec in loaded))
    difference = trained.committed_difference(args.out, settings, [display_path(p) for p, _ in loaded
                                                                     if p not in generated], procedural)
    if difference and not args.quiet:
        print(f"python -m denoise.train: note: --out {printable(args.out)} is a committed weights file and this "
              f"run is not the one that made it ({difference}); it will replace it (git checkout restores it; "
              f"--out NAME.json keeps it)", file=sys.stderr)
    checkpoint = args.work / f"{args.out.stem}.checkpoint.npz"
    if args.restart:  # the checkpoint is overwritten at the first step, not before: a refused run leaves it
        check_checkpoint_place(checkpoint)
    else:  # a mismatched one is refused before rendering
        state = load_checkpoint(checkpoint, settings, names, any(n in HELD_OUT for n in names))
        if state is not None and int(state["t"]) > args.steps:
            raise UsageError(f"{checkpoint}: the checkpoint holds {int(state['t'])} steps, more than --steps "
                             f"{args.steps}; give --steps {int(state['t'])} or more, or --restart")

    set_variant("llvm_ad_rgb", jit=True)
    check_folders([(spec, args.work / path.stem) for path, spec in loaded], (checkpoint,))  # before any render
    folders = [args.work / path.stem for path, _ in loaded]
    # one training at a time in a --work (two would write one checkpoint, step by step) and into an
    # --out (the one that ends last would replace the other's weights without a word)
    with name_locked(args.out, doing="training", remedy="give another --out"), \
            locked([args.work], doing="training", remedy="give another --work"):
        checked = {f: [i for i in frame_indices(f) if (reference_folder(f) / f"beauty_{i}.exr").exists()]
                   if f.is_dir() else [] for f in folders}
        for folder in folders:  # what is there already, before any rendering prints its progress
            check_frames(folder, checked[folder])
        render([(spec, folder) for (_, spec), folder in zip(loaded, folders)], **where)
        for folder in folders:
            check_frames(folder, [i for i in frame_indices(folder) if i not in checked[folder]])
        theta, curve, seconds = train_interruptibly(folders, settings, checkpoint, args.quiet, args.restart)
        given = argv if argv is not None else sys.argv[1:]
        write_weights(args, settings, [p for p, _ in loaded if p not in generated], procedural, theta, curve,
                      seconds, "python -m denoise.train " + " ".join(shlex.quote(a) for a in given))
    plot_curve(plot, curve, f"{printable(args.out.name)}: {settings.hidden} {trained.hidden_name}, "
                            f"{len(settings.features)} inputs")
    if not args.quiet:
        held = "no sequence held out" if curve[-1][2] is None else f"held out {curve[-1][2]:.6f}"
        print(f"final loss {curve[-1][1]:.6f} ({held}); weights written to {printable(args.out)}, "
              f"curves to {printable(plot)}")  # the result, on stdout as every command's; steps are progress
    return 0


def write_weights(args: argparse.Namespace, settings: Settings, specs: list[Path], procedural: int,
                  theta: np.ndarray, curve: list, seconds: float, command: str) -> None:
    """The weights file ``args.out``: the network of ``theta`` and the record of the run
    (``specs``: the spec files; ``procedural``: how many procedural sequences beside them)."""
    record = {"command": command.strip(), "training": [display_path(p) for p in specs if p.stem not in HELD_OUT],
              "held_out": [display_path(p) for p in specs if p.stem in HELD_OUT],
              "procedural": {"count": procedural, "seed": PROCEDURAL_SEED, "generator": "scenes/procedural.py"},
              "steps": len(curve), "seconds": round(seconds, 1), "seed": args.seed, "rate": args.rate,
              "method": settings.method, "batch": TRAINED[settings.method].batch,
              "crop": list(TRAINED[settings.method].crop), "exposure": list(training.EXPOSURE),
              "first_train_loss": curve[0][1], "first_held_out_loss": curve[0][2],
              "final_train_loss": curve[-1][1], "final_held_out_loss": curve[-1][2],
              "machine": machine(), "date": datetime.date.today().isoformat(),
              "curve": [[int(s), round(a, 6), None if b is None else round(b, 6)] for s, a, b in curve]}
    if not (np.isfinite(theta).all() and (np.abs(theta) <= WEIGHT_LIMIT).all()):
        raise UsageError(f"the training ended with weights beyond {WEIGHT_LIMIT:g}, which no weights file may hold "
                         f"(a diverging run: a lower --rate); {printable(args.out)} left as it was")
    network = TRAINED[settings.method].network_of(theta, settings.features, settings.hidden)
    with atomic_path(args.out, ".json") as temporary:
        Path(temporary).write_text(json.dumps({**network.to_json(), "record": record}, indent=1) + "\n")


def scene_file(name: str) -> str:
    """A spec's scene as the export resolves it, by its content (SHA-256 of its
    words, comments left out, numbers read as numbers and meshes and cube maps
    by their file names), so that every spelling of one scene, a copy of its
    file, and a copy with other comments, spacing, number formats or paths to
    its meshes compare equal; a scene not found stays its name (the check of the folders
    says so, before any work)."""
    try:
        text = resolve_scene(name, data_dir()).read_text(errors="replace")
    except (UsageError, OSError):
        return name
    words = re.findall(r"[{}]|[^\s{}]+", re.sub(r"#[^\n]*", " ", text))
    for k in range(1, len(words)):  # a mesh or cube map by its name, wherever its path leads
        if words[k - 1] in ("obj_file", "cubeMap"):
            words[k] = Path(words[k]).name
    return hashlib.sha256(" ".join(number_or_word(w) for w in words).encode()).hexdigest()


def number_or_word(word: str) -> str:
    """``word`` as a number's canonical text where it is one (``1.0``, ``1``, ``1e0`` alike)."""
    try:
        return repr(float(word))
    except ValueError:
        return word


def check_specs(paths: list[Path]) -> list[tuple[Path, Spec]]:
    """Each training spec loaded; one line (a UsageError) for a benchmark
    sequence, one of its scenes (by name or by any path to its file), or a
    sequence without ground truth."""
    benchmark = {p.resolve(): Spec.load(p) for p in BENCHMARK}
    scenes = {scene_file(spec.scene): p.stem for p, spec in benchmark.items()}
    loaded = []
    for path in paths:
        try:
            spec = Spec.load(path)
        except SpecError as error:
            if "reference_spp" not in str(error):
                raise
            raise UsageError(f"{path}: no ground truth to train on ({str(error).removeprefix(f'{path}: ')})") from None
        if Path(path).resolve() in benchmark or Path(path).stem in {p.stem for p in benchmark}:
            raise UsageError(f"{path}: a benchmark sequence; training on it would score the network on its own "
                             f"training data")
        if scene_file(spec.scene) in scenes:
            raise UsageError(f"{path}: scene {spec.scene!r} is the benchmark's (sequence "
                             f"{scenes[scene_file(spec.scene)]}); train on other scenes")
        if spec.reference_spp < 2:
            raise UsageError(f"{path}: no ground truth (reference_spp {spec.reference_spp}); training needs "
                             f"a target per frame")
        if spec.frames <= training.LOSS_FROM:
            raise UsageError(f"{path}: {spec.frames} frame(s); the loss counts frames {training.LOSS_FROM} on "
                             f"(the first has no history), so a training sequence needs {training.LOSS_FROM + 1} "
                             f"or more")
        loaded.append((Path(path), spec))
    return loaded


def check_frames_fit(loaded: list[tuple[Path, Spec]], memory: int | None = None,
                     method: str = "learned-asvgf") -> None:
    """Every frame of ``loaded`` held at once within the memory available (``memory``:
    bytes; measured if None; the method's ``training_memory``), else a
    :class:`LimitError` before anything is rendered."""
    trained = TRAINED[method]
    check_sequences_fit("training", loaded, trained.memory([(p.stem, s) for p, s in loaded]),
                        f"train on smaller frames or fewer of them (a step reads {trained.crop[0]}x"
                        f"{trained.crop[1]} crops)", memory)


def rerender(folder: Path) -> str:
    """What a damaged frame's message advises (--restart starts the steps over, it renders nothing)."""
    return f"remove {folder} and {reference_folder(folder)} and run again: the training renders the sequence anew"


def check_frames(folder: Path, indices: list[int]) -> None:
    """Frames ``indices`` of an exported ``folder`` and their ground truth, read
    as the training reads them: a damaged file, a missing target, another
    size or a value that is not finite is one line naming the file."""
    shape = None
    for i in indices:
        try:
            frame = read_frame(folder, i)
        except FrameError as error:
            raise FrameError(f"{error}; {rerender(folder)}") from None
        truth_path = reference_folder(folder) / f"beauty_{i}.exr"
        if truth_path.exists() and not truth_path.is_file():
            raise FrameError(f"{truth_path}: not a regular file, where frame {i}'s ground truth belongs")
        if not truth_path.is_file():
            raise UsageError(f"{folder}: no ground truth for frame {i} (no {truth_path}; python -m export renders it)")
        try:
            truth = read_exr_rgb(truth_path)
        except (OSError, RuntimeError, ValueError, KeyError) as error:
            raise FrameError(f"{truth_path}: not a readable EXR ({' '.join(str(error).split())}); "
                             f"{rerender(folder)}") from None
        same_size(folder / f"beauty_{i}.exr", frame.beauty.shape, truth_path, truth.shape)
        shape = shape or (folder / f"beauty_{i}.exr", frame.beauty.shape)
        same_size(folder / f"beauty_{i}.exr", frame.beauty.shape, *shape)
        images = {"beauty": frame.beauty, "normal": frame.normal, "position": frame.position, "albedo": frame.albedo}
        for path, image in [*((folder / f"{k}_{i}.exr", v) for k, v in images.items()), (truth_path, truth)]:
            bad = 0 if image is None else int((~np.isfinite(image).all(axis=-1)).sum())
            if bad:
                raise FrameError(f"{path}: {bad} pixels of {image.shape[0] * image.shape[1]} are not finite "
                                 f"(NaN or infinite); the training needs finite frames and targets: {rerender(folder)}")
        for path, image in ((folder / f"beauty_{i}.exr", frame.beauty), (truth_path, truth)):
            bad = int(((image < 0) | (image > RADIANCE_LIMIT)).any(axis=-1).sum())
            if bad:  # a render's radiance is never negative
                raise FrameError(f"{path}: {bad} pixels of {image.shape[0] * image.shape[1]} have a negative "
                                 f"radiance or one beyond {RADIANCE_LIMIT:g}; not a render's: {rerender(folder)}")


def train_worker(connection, folders: list[Path], settings: Settings, checkpoint: Path, restart: bool) -> None:
    """The steps in a worker process, started with GROUP_SIGNALS blocked and
    then ignoring them: the parent alone answers a terminal's signals and
    ends this process. Sends ("step", step, loss, held-out loss, seconds) per
    step, then ("done", theta, curve, seconds), or ("error", its line)."""
    ignore_group_signals()
    set_variant("llvm_ad_rgb", quiet=True)
    try:
        connection.send(("done", *TRAINED[settings.method].train(
            folders, settings, checkpoint, lambda *report: connection.send(("step", *report)), restart,
            progress=lambda *done: connection.send(("loaded", *done)))))
    except Exception as error:  # noqa: BLE001  one line in the parent, never the worker's traceback
        connection.send(("error", worker_error(error)))


def worker_error(error: Exception) -> str:
    """The line the parent prints for an error in the worker: a ToolkitError's
    own, a file's error naming the file, anything else (a bug) with its type."""
    if isinstance(error, ToolkitError):
        return one_line(error)
    if isinstance(error, OSError) and error.filename:
        return f"{printable(error.filename)}: {error.strerror or one_line(error)}"
    if isinstance(error, MemoryError):
        return "out of memory in the training's worker process"
    return f"the training's worker process failed ({type(error).__name__}: {one_line(error)})"


def train_interruptibly(folders: list[Path], settings: Settings, checkpoint: Path, quiet: bool, restart: bool):
    """:func:`denoise.training.train` in a worker this process waits for
    (:func:`denoise.worker_process.run_in_worker`), printing its steps."""
    started = time.monotonic()

    def report(message: tuple) -> None:
        if message[0] == "loaded":
            if not quiet:
                print(f"loaded {message[1]}/{message[2]}: {message[3]}", file=sys.stderr, flush=True)
            return
        _, step, loss, held, seconds = message
        if not quiet:
            held = "none" if held is None else f"{held:.6f}"
            print(f"step {step + 1}/{settings.steps}: loss {loss:.6f}  held-out {held}  "
                  f"({seconds:.1f} s in all, {time.monotonic() - started:.0f} s this run)", file=sys.stderr, flush=True)

    return run_in_worker(train_worker, (folders, settings, checkpoint, restart), "the training", report)


def display_path(path: Path) -> str:
    """``path`` relative to the repository where it lies inside it."""
    path = Path(path).resolve()
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path)


def plot_curve(path: Path, curve: list, title: str) -> None:
    """The training and held-out losses per step, as a PNG."""
    steps, loss, held = (np.array(c, np.float64) for c in zip(*((s, a, np.nan if b is None else b)
                                                                  for s, a, b in curve)))
    from matplotlib.figure import Figure  # noqa: PLC0415  only once the steps are done

    figure = Figure(figsize=(6.4, 3.6), dpi=100)  # no pyplot: no display backend, no global state
    axes = figure.subplots()
    axes.plot(steps, loss, lw=0.8, alpha=0.5, label="training batch (random crops, flips, exposure)")
    if len(loss) >= 10:
        kernel = np.ones(10) / 10
        axes.plot(steps[9:], np.convolve(loss, kernel, "valid"), lw=1.5, label="training, mean of 10 steps")
    axes.plot(steps, held, lw=1.5, label="held-out sequences (whole frames)")
    axes.axhline(1.0, color="0.5", lw=0.8, ls="--", label="asvgf as fitted")
    axes.set_xlabel("step")
    axes.set_ylabel("relMSE / asvgf's")
    axes.set_title(title, fontsize=9)
    axes.legend(fontsize=8)
    figure.tight_layout()
    with atomic_path(path, ".png") as temporary:
        figure.savefig(temporary, format="png")


def main(argv: list[str] | None = None) -> int:
    return run("python -m denoise.train", lambda: _main(argv))


if __name__ == "__main__":
    code = main()
    if code > 128:  # stopped by a signal: the worker is ended and every file written or not at all, so
        sys.stdout.flush()  # the teardown of Dr.Jit, Dask and matplotlib (seconds on a loaded machine)
        sys.stderr.flush()  # would only delay the exit
        os._exit(code)
    finish(code)
