"""Trained networks judged on the held-out training sequences against a converged truth.

    python -m denoise.validate [SPEC.json ...] [--work DIR] [--reference-spp N] [--methods NAME ...]
                               [--network FILE ...] [--json FILE]

The training's held-out loss is against the training's own noisy targets
(Noise2Noise): fine for a curve, not for choosing between networks. This
command renders the held-out sequences (:data:`denoise.training.HELD_OUT`,
or the specs given: a sequence on a scene left out of a training) again
with a ground truth of ``--reference-spp`` samples per pixel (512 by
default; a rerun renders nothing), runs every method (``asvgf``, the
committed networks and their ablations by default; ``--network FILE`` adds
a weights file, named by its file name) and prints each one's mean relMSE
over frames >= :data:`denoise.temporal_metrics.QUALITY_FROM` and its ratio to
``asvgf``'s. Networks are chosen here; the benchmark's sequences only judge
the one chosen.
"""
from __future__ import annotations

if __name__ == "__main__":  # first: ./.venv's Python, the libLLVM, then Dr.Jit (see core.launcher)
    from core.launcher import start
    start("python -m denoise.validate", "denoise.validate")

import argparse
import json
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from core.entry import ArgumentParser, finish, printable, run
from core.errors import NEED_COURSE, NEED_OWN_FOLDER, NEED_SMALLER_RENDER, ToolkitError, UsageError
from core.inputs import check_outside
from core.json_input import JSONInputError, read_json
from core.numbers import ascii_int
from course import ENVIRONMENT
from export import Sequence, Spec, export_sequences, reference_folder, sequences_into
from export.cluster import add_cluster_options, cluster_options
from export.frames import frame_indices, read_frame
from export.ground_truth import DATASET_RECORD, check_outside_exports, check_work_folder
from export.store import check_folder
from imaging.image_io import atomic_path, check_writable, read_exr_rgb
from imaging.metrics import relmse
from renderer.checks import check_memory
from renderer.variants import set_variant

from .methods import check_method_names, data_files, from_name, resolve
from .methods.learned_asvgf import FORMAT as ASVGF_FORMAT, LearnedASVGF
from .methods.learned_mixture import FORMAT as MIXTURE_FORMAT, LearnedMixture
from .methods.weights_file import MAX_WEIGHTS_BYTES
from .pipeline import BASE_BYTES as FRAME_BASE_BYTES, BYTES_PER_PIXEL as FRAME_BYTES_PER_PIXEL
from .temporal_metrics import QUALITY_FROM
from .training import HELD_OUT, LOADED_BYTES, ROOT, TRAINING

#: the methods judged when --methods is not given
METHODS = ("asvgf", *LearnedASVGF.benchmark, *LearnedMixture.benchmark)
#: the methods whose weights files --network judges
TRAINED = (LearnedASVGF, LearnedMixture)
#: the training sequences a network learned from (the held-out ones it never did), by name
TRAINED_ON = {p.stem: p for p in TRAINING if p.stem not in HELD_OUT}
#: the ground truth's samples per pixel when --reference-spp is not given
REFERENCE_SPP = 512


def _parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(prog="python -m denoise.validate", description=__doc__.split("\n\n")[0])
    parser.add_argument("specs", type=Path, nargs="*", metavar="SPEC.json",
                        help="sequences to judge (default: the held-out training sequences)")
    parser.add_argument("--work", type=Path, default=ROOT / "out" / "validate",
                        help="where the held-out sequences are rendered (out/validate)")
    parser.add_argument("--reference-spp", type=ascii_int, default=REFERENCE_SPP,
                        help=f"the ground truth's samples per pixel, even ({REFERENCE_SPP})")
    parser.add_argument("--methods", nargs="+", default=list(METHODS), metavar="NAME",
                        help=f"methods of python -m denoise --method (default: {' '.join(METHODS)})")
    parser.add_argument("--network", nargs="+", type=Path, default=[], metavar="FILE",
                        help="weights files of learned-asvgf or learned-mixture (by their format) to judge "
                             "besides, each named by its file name")
    parser.add_argument("--json", type=Path, help="write every number as JSON")
    add_cluster_options(parser)
    return parser


#: the remedy, by what it provides (``core.errors.NEED_*``), in the export's errors as a
#: command tells them whose --work is a cache and which has no --data, --batch-spp or --force
CACHE_REMEDIES = {NEED_COURSE: f"set {ENVIRONMENT} to the course folder",
                  NEED_SMALLER_RENDER: "make the spec's size smaller"}


@contextmanager
def cache_remedies(folder: Path | None = None) -> Iterator[None]:
    """The export's errors (and the scene lookup's) about the sequence in
    ``folder`` (None: in the folder the error names) with the remedies of a
    command whose --work is a cache (:data:`CACHE_REMEDIES`; a folder made with
    other settings: remove it)."""
    try:
        yield
    except ToolkitError as error:
        removal = (f"remove {folder} and {reference_folder(folder)}" if folder is not None else
                   "remove the folder it names and its _reference folder")
        remedy = (f"{removal} to render them again, or give another --work"
                  if error.need == NEED_OWN_FOLDER else CACHE_REMEDIES.get(error.need))
        if remedy is None:
            raise
        raise error.with_remedy(remedy) from None


def check_spec_name(spec: Path) -> None:
    """A spec's name (its file name less ``.json``) names its folder in --work:
    ``..json`` would render into --work itself and ``...json`` into its parent."""
    if Path(spec).stem in ("", ".", ".."):
        raise UsageError(f"{printable(spec)}: a sequence named {Path(spec).stem!r} has no folder of its own in "
                         f"--work; rename the spec")


def check_folders(folders: list[tuple[Spec, Path]], files: tuple[Path, ...] = ()) -> list[Sequence]:
    """The export's sequence of every (spec, frame folder) in a --work cache, its
    scene and its folders (new, or made with the same settings) checked with the
    cache's remedies (:func:`cache_remedies`). ``files``: what the command
    writes into the --work besides (the export's manifest always), which no
    sequence's folder may be and which must not be a folder. Writes nothing."""
    with cache_remedies():  # the scenes, and no folder of one sequence another's
        sequences = sequences_into(folders)
    own = {Path(f).parent / DATASET_RECORD for _, f in folders} | set(files)
    for sequence in sequences:
        for folder in (Path(sequence.target), sequence.reference):
            if folder in own:
                raise UsageError(f"{printable(folder)}: a sequence's folder would be the file the command writes "
                                 f"there; rename the spec {printable(sequence.spec.source or sequence.name)}")
    for path in own:
        if path.is_dir():
            raise UsageError(f"{printable(path)}: a folder where the command writes a file; remove it, "
                             f"or give another --work")
    for sequence, (_, folder) in zip(sequences, folders):
        with cache_remedies(folder):
            check_folder(sequence)
    return sequences


def render(folders: list[tuple[Spec, Path]], **where) -> None:
    """Renders what is missing of every (spec, frame folder) of a --work cache in
    one export: in this process by default, or as ``where`` says (the keywords
    of :func:`export.cluster.cluster_options`: one Dask cluster for them all).
    Every folder is checked before any is written (:func:`check_folders`); the
    export's manifest is written into the folders' parent, the --work."""
    if not folders:
        return
    sequences = check_folders(folders)
    parents = {Path(folder).parent for _, folder in folders}
    if len(parents) != 1:
        raise ValueError(f"render: the folders lie in {len(parents)} folders, not in one --work")
    with cache_remedies():
        export_sequences(sequences, manifest=parents.pop() / DATASET_RECORD, **where)


def check_frames(spec: Path, frames: int) -> None:
    """A sequence judged by its mean over frames >= QUALITY_FROM needs such frames."""
    if frames <= QUALITY_FROM:
        raise UsageError(f"{spec}: {frames} frame{'s' if frames != 1 else ''}; the mean relMSE is taken over frames "
                         f">= {QUALITY_FROM}, so a sequence needs at least {QUALITY_FROM + 1} frames")


def check_sequence_fits(loaded: dict[Path, Spec], memory: int | None = None) -> None:
    """The largest sequence judged within the memory available (``memory``:
    bytes; measured if None), else a :class:`LimitError` before anything is
    rendered: :func:`judge` holds its frames and truth while a method
    denoises one frame at a time."""
    path, spec = max(loaded.items(), key=lambda item: item[1].frames * item[1].size[0] * item[1].size[1])
    pixels = spec.size[0] * spec.size[1]
    check_memory(FRAME_BASE_BYTES + (LOADED_BYTES * spec.frames + FRAME_BYTES_PER_PIXEL) * pixels,
                 f"{path}: judging its {spec.frames} frames of {spec.size[0]}x{spec.size[1]}",
                 "judge smaller frames or fewer of them", memory=memory)


def cell(name: str) -> str:
    """A name a user chose (a spec's, a weights file's) as one Markdown table cell."""
    return printable(name).replace("|", "\\|")


def training_sequences(loaded: dict[Path, Spec], reference_spp: int) -> list[str]:
    """The names of the specs in ``loaded`` that are a training sequence the networks
    learned from (:data:`TRAINED_ON`): of its name and the same in every setting but
    the truth's samples (not merely a sequence of its name)."""
    return [path.stem for path, spec in loaded.items() if path.stem in TRAINED_ON
            and Spec.load(TRAINED_ON[path.stem], reference_spp=reference_spp) == spec]


def network_method(path: Path) -> str:
    """The method weights file ``path`` is for, by its ``"format"``; a file that names
    neither method's is one line naming both and the training command."""
    if not Path(path).is_file():  # a pipe would block the read; the loading says what it is in one line
        return LearnedASVGF.name
    commands = f"python -m denoise.train [--method {LearnedMixture.name}]"
    try:
        data = read_json(path, MAX_WEIGHTS_BYTES)
    except (JSONInputError, OSError) as error:
        raise UsageError(f"{path}: not a weights file ({str(error).removeprefix(f'{path}: ')}); make one with "
                         f"{commands}") from None
    found = {ASVGF_FORMAT: LearnedASVGF.name, MIXTURE_FORMAT: LearnedMixture.name}
    file_format = data.get("format") if isinstance(data, dict) else None
    name = found.get(file_format) if isinstance(file_format, str) else None
    if name is None:
        raise UsageError(f"{path}: not a weights file of {LearnedASVGF.name} (\"format\": \"{ASVGF_FORMAT}\") or "
                         f"{LearnedMixture.name} (\"{MIXTURE_FORMAT}\"); make one with {commands}")
    return name


def judge(folder: Path, runners: dict) -> dict[str, list[float]]:
    """Per method (a factory of a fresh method), its relMSE per frame of ``folder`` against its ground truth."""
    indices = frame_indices(folder)
    try:
        frames = [read_frame(folder, i) for i in indices]
        truth = [read_exr_rgb(reference_folder(folder) / f"beauty_{i}.exr") for i in indices]
    except ToolkitError as error:  # a damaged file of the cache: render the sequence anew
        raise error.with_remedy(f"remove {folder} and {reference_folder(folder)} to render them again") from None
    errors = {}
    for name, make in runners.items():
        method = make()
        errors[name] = [relmse(method.step(frame), reference) for frame, reference in zip(frames, truth)]
    return errors


def table(results: dict[str, dict[str, list[float]]]) -> list[str]:
    """A Markdown table: per sequence and method, the mean relMSE over frames >= QUALITY_FROM, its ratio to asvgf's."""
    methods = list(next(iter(results.values())))
    lines = ["| sequence | " + " | ".join(map(cell, methods)) + " |", "|---" * (len(methods) + 1) + "|"]
    for sequence, errors in results.items():
        if any(len(e) <= QUALITY_FROM for e in errors.values()):
            raise ValueError(f"{sequence}: no frames >= {QUALITY_FROM} to take the mean of")
        means = {m: float(np.mean(e[QUALITY_FROM:])) for m, e in errors.items()}
        base = means.get("asvgf")
        cells = [f"{v:.4f}" + (f" ({v / base:.2f}×)" if base and m != "asvgf" else "") for m, v in means.items()]
        lines.append(f"| {cell(sequence)} | " + " | ".join(cells) + " |")
    return lines


def _main(argv: list[str] | None) -> int:
    args = _parser().parse_args(argv)
    if not 2 <= args.reference_spp <= 1 << 16 or args.reference_spp % 2:
        raise UsageError(f"--reference-spp must be even, from 2 to 65536, got {args.reference_spp}")
    check_method_names("--methods", args.methods)  # every name python -m denoise --method takes, each once
    where = cluster_options(args)
    named = {}
    for path in args.network:
        if path.stem in named or path.stem in args.methods:
            raise UsageError(f"--network {printable(path)}: a second method named {path.stem} (each is named by "
                             "its file name: copy one to another name)")
        named[path.stem] = path
    if args.json is not None and args.json.suffix.lower() != ".json":
        raise UsageError(f"--json writes JSON: name it .json, got {args.json}")
    specs = args.specs or [p for p in TRAINING if p.stem in HELD_OUT]
    if not specs:
        raise UsageError(f"no held-out sequence ({', '.join(HELD_OUT)}) among the training specs")
    twice = sorted({p.stem for p in specs if [q.stem for q in specs].count(p.stem) > 1})
    if twice:
        raise UsageError(f"two specs named {', '.join(map(printable, twice))}: they would share a folder in --work")
    loaded = {p: Spec.load(p, reference_spp=args.reference_spp) for p in specs}  # a bad spec before any work
    for spec in specs:
        check_frames(spec, loaded[spec].frames)
    check_sequence_fits(loaded)
    for spec in specs:  # the command never writes onto a spec, a weights file or a frame folder it reads
        check_spec_name(spec)
        folder = args.work / spec.stem
        check_outside({"--work": args.work, "--json": args.json}, {"SPEC.json": spec})
        check_outside({"--json": args.json}, {f"frame folder (--work) of {spec.stem}": folder,
                                              f"ground truth (--work) of {spec.stem}": reference_folder(folder)})
    check_work_folder(args.work)  # after: a --work that is a spec is told so, not merely that it is a file
    for path in named.values():
        check_outside({"--json": args.json}, {"--network": path})
    check_outside({"--json": args.json}, data_files())
    check_outside_exports({"--json": args.json})
    if args.json is not None:
        check_writable("--json", args.json)
    set_variant(None, jit=True)  # the methods have no scalar form: an unusable libLLVM is one line naming it
    runners = {m: (lambda m=m: from_name(m)) for m in args.methods}
    runners.update({name: (lambda p=p: from_name(network_method(p), network=str(p))) for name, p in named.items()})
    for name in list(runners):  # a bad weights file is one line before any rendering
        runners[name]()
    networks = [n for n in runners if n in named or resolve(n)[0] in TRAINED]
    trained_on = training_sequences(loaded, args.reference_spp)
    if networks and trained_on:  # judged all the same, but its numbers are not held-out ones
        print(f"note: the networks were trained on {', '.join(map(printable, trained_on))}: "
              f"{'its' if len(trained_on) == 1 else 'their'} numbers are not held-out ones",
              file=sys.stderr, flush=True)
    render([(loaded[spec], args.work / spec.stem) for spec in specs], **where)
    results = {}
    for spec in specs:
        folder = args.work / spec.stem
        print(f"{printable(spec.stem)}: judging {len(runners)} method{'' if len(runners) == 1 else 's'}",
              file=sys.stderr, flush=True)
        results[spec.stem] = judge(folder, runners)
    print(f"mean relMSE over frames >= {QUALITY_FROM} against a {args.reference_spp}-spp truth"
          + (" (ratio to asvgf's):" if "asvgf" in runners and len(runners) > 1 else ":"))
    print("\n".join(table(results)))
    if args.json is not None:
        with atomic_path(args.json, ".json") as temporary:
            Path(temporary).write_text(json.dumps({"reference_spp": args.reference_spp, "quality_from": QUALITY_FROM,
                                                   "relmse": results}, indent=1) + "\n")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run("python -m denoise.validate", lambda: _main(argv))


if __name__ == "__main__":
    finish(main())
