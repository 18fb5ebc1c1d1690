"""The command line of :mod:`export`: ``python -m export``."""
from __future__ import annotations

import argparse
from pathlib import Path

from core.entry import ArgumentParser, printable, run
from core.errors import UsageError
from core.inputs import check_outside
from core.numbers import ascii_int
from course import check_data_flag
from renderer.variants import set_variant

from . import __doc__ as PACKAGE_DOC
from .cluster import add_cluster_options, cluster_options
from .ground_truth import DATASET_RECORD, reference_folder
from .runners import export_sequences, sequences_for
from .sequence import DEFAULT_BATCH_SPP
from .spec import Spec


def _parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(prog="python -m export", description=PACKAGE_DOC.split("\n\n")[0],
                            usage="%(prog)s SPEC.json [SPEC.json ...] OUT [options]")
    parser.add_argument("paths", type=Path, nargs="+", metavar="SPEC.json... OUT",
                        help="one or more specs, then the output folder")
    parser.add_argument("--frames", type=ascii_int)
    parser.add_argument("--size", type=ascii_int, nargs=2, metavar=("W", "H"))
    parser.add_argument("--spp", type=ascii_int)
    parser.add_argument("--reference-spp", type=ascii_int)
    parser.add_argument("--batch-spp", type=ascii_int, default=DEFAULT_BATCH_SPP,
                        help=f"ground-truth samples per task (default {DEFAULT_BATCH_SPP})")
    parser.add_argument("--whitted", action="store_true", help="noisy beauty from whitted (jittered), not path")
    parser.add_argument("--data", type=Path, help="course data folder for course scene names")
    parser.add_argument("--variant")
    parser.add_argument("--force", action="store_true", help="start over in folders made with other settings")
    add_cluster_options(parser)
    return parser


def check_not_spec_folders(out: Path, spec_paths: list[Path]) -> None:
    """No frame or ground-truth folder of the export is a folder holding a spec
    it reads (``python -m export DIR/x.json DIR`` mixed frames into the specs)."""
    targets = {"OUT": out} if len(spec_paths) == 1 else {f"OUT/{p.stem}": out / p.stem for p in spec_paths}
    folders = {path.parent.resolve(): path for path in spec_paths}
    for label, target in targets.items():
        for role, folder in ((label, target), (f"{label}'s ground truth", reference_folder(target))):
            if folder.resolve() in folders:
                raise UsageError(f"{role} {folder} is the folder of the input SPEC.json "
                                 f"{folders[folder.resolve()]}; write outputs elsewhere")


def _main(argv: list[str] | None) -> int:
    args = _parser().parse_args(argv)
    if len(args.paths) < 2:
        raise UsageError("expected one or more SPEC.json files, then the output folder")
    *spec_paths, out = args.paths
    check_outside({"OUT": out}, {"--data": args.data})
    check_data_flag(args.data)
    for path in spec_paths:
        check_outside({"OUT": out}, {"SPEC.json": path})
    check_not_spec_folders(out, spec_paths)
    where = cluster_options(args)
    overrides = dict(frames=args.frames, size=tuple(args.size) if args.size else None, spp=args.spp,
                     reference_spp=args.reference_spp)
    specs = [(path.stem, Spec.load(path, **overrides)) for path in spec_paths]  # all checked before any work
    variant = set_variant(args.variant)
    sequences = sequences_for(specs, out, args.data, args.whitted, args.batch_spp, variant)
    manifest = out / DATASET_RECORD
    done = export_sequences(sequences, args.force, manifest=manifest, **where)
    for sequence in sequences:
        print(f"{len(done[sequence.name])} frames rendered into {printable(sequence.target)} "
              f"(ground truth in {printable(sequence.reference)})")
    print(f"manifest: {printable(manifest)}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """``python -m export``; returns the exit code."""
    return run("python -m export", lambda: _main(argv))
