"""Running an export: the sequences of a dataset checked and claimed, their
missing tasks run in this process or on Dask, the manifest written."""
from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path

import mitsuba as mi

from core.errors import NEED_SMALLER_RENDER, SceneError, SpecError, UsageError
from course import data_dir, resolve_scene
from renderer.checks import check_memory

from .cluster import cluster_description, dask_client, deferred_signals, run_futures
from .files import locked, remove_staging
from .ground_truth import DATASET_RECORD, SEQUENCE_RECORD
from .recorder import Recorder, progress_bar
from .sequence import DEFAULT_BATCH_SPP, Sequence
from .spec import MAX_SAMPLES_PER_RENDER, MAX_SPP, Spec
from .store import check_folder, claim_folder, plan, recover
from .tasks import Task, course_scene, run_task


def run_local(tasks: list[Task], recorder: Recorder, after_task: Callable[[Task], None] | None = None,
              total_frames: int = 0) -> None:
    """Runs ``tasks`` one after the other in this process (no Dask). A signal
    during a task is acted on once its result is recorded (a task is native
    code that no signal interrupts, and one raised inside it could be lost)."""
    with deferred_signals() as raise_noted, progress_bar(len(tasks), total_frames) as bar:
        for task in tasks:
            raise_noted()
            result, timing = run_task(task)
            recorder.record(task, result, timing)
            bar.update()
            bar.set_postfix(frames=f"{recorder.frames_done()}/{total_frames}", refresh=False)
            if after_task:
                after_task(task)
            raise_noted()


def sequences_for(specs: list[tuple[str, Spec]], out: Path, data: Path | None = None, whitted: bool = False,
                  batch_spp: int = DEFAULT_BATCH_SPP, variant: str | None = None) -> list[Sequence]:
    """One :class:`Sequence` per (name, spec); one spec writes ``out`` itself,
    several write ``out/<name>``. Scenes are loaded and checked here, before any work."""
    if batch_spp < 1 or batch_spp > MAX_SPP:
        raise SpecError(f"--batch-spp: expected 1..{MAX_SPP}, found {batch_spp}")
    names = [name for name, _ in specs]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise SpecError(f"two specs named {', '.join(twice)} would share one folder; rename one")
    result = []
    for name, spec in specs:
        where = spec.source or name  # the spec's file where it came from one
        spec.check(where)
        width, height = spec.size
        if width * height * min(batch_spp, spec.reference_spp // 2) > MAX_SAMPLES_PER_RENDER:
            raise SpecError(f"{where}: {width}x{height} at {batch_spp} spp per batch is more than "
                            f"{MAX_SAMPLES_PER_RENDER} samples in one render", "lower --batch-spp", NEED_SMALLER_RENDER)
        try:
            path = resolve_scene(spec.scene, data_dir(data)).resolve()
        except UsageError as error:
            raise SpecError(f"{where}: scene: {error.problem}", error.remedy, error.need) from None
        try:
            scene = course_scene(str(path))
        except SceneError as error:  # the scene file's own line, named as the spec's scene
            raise SpecError(f"{where}: scene: {error}") from None
        spec.check_scene(scene, where)
        target = out if len(specs) == 1 else out / name
        result.append(Sequence(name, spec, str(path), str(target), batch_spp, whitted, variant or mi.variant()))
    check_distinct_folders(result)
    return result


def check_distinct_folders(sequences: list[Sequence]) -> None:
    """Raises :class:`SpecError` where one sequence's frame or ground-truth
    folder is another's (a spec named ``a_reference`` beside ``a``)."""
    owners: dict[Path, tuple[str, str, Path]] = {}
    for sequence in sequences:
        for role, folder in (("frame folder", Path(sequence.target)), ("ground truth", sequence.reference)):
            other = owners.setdefault(folder.resolve(), (sequence.name, role, folder))
            if other[0] != sequence.name:
                raise SpecError(f"{folder}: would be both {other[0]}'s {other[1]} and {sequence.name}'s {role}; "
                                f"rename one of the specs")


#: a render task's peak memory: bytes per pixel of its frame, and what its process holds
#: besides (measured with the export's peak RSS at several sizes: docs/export.md)
RENDER_BYTES_PER_PIXEL, RENDER_BASE_BYTES = 320, 400 * 2 ** 20


def check_renders_fit(sequences: list[Sequence], processes: int, memory: int | None = None) -> None:
    """``processes`` render tasks at once, each of the largest frame, within the
    memory available (``memory``: bytes; measured if None): else a
    :class:`LimitError` before anything is written, where a render would
    otherwise be killed for memory."""
    if not sequences:
        return
    largest = max(sequences, key=lambda s: s.spec.size[0] * s.spec.size[1])
    width, height = largest.spec.size
    one = RENDER_BASE_BYTES + RENDER_BYTES_PER_PIXEL * width * height
    at_once = f" ({processes} at once)" if processes > 1 else ""
    check_memory(processes * one, f"{largest.spec.source or largest.name}: rendering its {width}x{height} frames"
                 f"{at_once}", ("give fewer --workers, or " if processes > 1 else "") + "make the spec's size smaller",
                 NEED_SMALLER_RENDER, memory)


def export_sequences(sequences: list[Sequence], force: bool = False, scheduler: str | None = None,
                     workers: int | None = None, local: bool | None = None, manifest: Path | None = None,
                     after_task: Callable[[Task], None] | None = None, client=None,
                     threads: int | None = None) -> dict[str, list[int]]:
    """Renders what is missing of ``sequences`` (in this process with ``local``,
    else on Dask: ``client``, a scheduler address or a new LocalCluster of
    ``workers``; ``local`` None: in this process unless one of those is given, and
    False with none of them a LocalCluster of one worker per core, as the CLI's
    default); returns the indices of the frames that had work done, per
    sequence name. ``threads``: Dr.Jit threads per process that runs tasks.
    Folders that refuse the sequences are refused before anything is written;
    while it runs the export holds every folder's lock."""
    if local is None:
        local = client is None and not scheduler and not workers
    if not force:
        for sequence in sequences:
            check_folder(sequence)
    if client is None and not scheduler:  # renders on this machine: this process, or a LocalCluster's workers
        check_renders_fit(sequences, 1 if local else workers or os.cpu_count() or 1)
    folders = [folder for s in sequences for folder in (Path(s.target), s.reference)]
    made = made_by_claim(folders)
    started = False
    try:
        with locked(folders):
            for sequence in sequences:
                claim_folder(sequence, force)
                recover(sequence)
            if manifest is not None:
                remove_staging(manifest.parent)
            if local or client is not None or not any(plan(s) for s in sequences):  # no cluster for nothing to do
                started = True
                return _run(sequences, manifest, after_task, client, threads)
            with dask_client(scheduler, workers) as (client, threads):
                started = True
                return _run(sequences, manifest, after_task, client, threads, scheduler or "LocalCluster")
    except BaseException:
        if not started:  # no cluster to render on (unreachable, interrupted as it started): no claims left behind
            remove_claims(made)
        raise


def made_by_claim(folders: list[Path]) -> list[Path]:
    """The outermost of ``folders`` and their parents that do not exist yet: what claiming them makes."""
    made = set()
    for folder in folders:
        folder = Path(folder).absolute()
        while not folder.parent.exists():
            folder = folder.parent
        if not folder.exists():
            made.add(folder)
    return sorted(made)


def remove_claims(made: list[Path]) -> None:
    """Removes each folder of ``made`` (:func:`made_by_claim`) that holds nothing but
    folders and sequence records; one that holds anything else stays whole."""
    for top in made:
        inside = [top, *top.rglob("*")]
        if not all(p.is_dir() or (p.is_file() and p.name == SEQUENCE_RECORD) for p in inside):
            continue
        for path in sorted(inside, key=lambda p: -len(p.parts)):
            if path.is_dir():
                path.rmdir()
            else:
                path.unlink()


def _run(sequences: list[Sequence], manifest: Path | None, after_task, client, threads,
         scheduler: str | None = None) -> dict[str, list[int]]:
    """Runs the missing tasks of claimed ``sequences``; writes the manifest."""
    recorder = Recorder(sequences, manifest)
    frames = sum(s.spec.frames for s in sequences)
    tasks = [t for s in sequences for t in plan(s, threads)]
    extra: dict = {"started": recorder.run_id, "tasks": len(tasks), "drjit_threads": threads}
    start = time.perf_counter()
    try:
        if client is None:
            extra.update(runner="local")
            run_local(tasks, recorder, after_task, frames)
        else:
            extra.update(cluster_description(client, scheduler))
            run_futures(client, tasks, recorder, after_task, frames)
    finally:
        extra["wall_s"] = round(time.perf_counter() - start, 3)
        recorder.write(extra)
    return {name: sorted(frames) for name, frames in recorder.rendered.items()}


def export(spec: Spec, target: Path, data: Path | None = None, whitted: bool = False, force: bool = False,
           batch_spp: int = DEFAULT_BATCH_SPP, **where) -> list[int]:
    """Renders the missing frames of one sequence into ``target`` in this
    process (``where``: ``scheduler=``/``workers=`` for Dask); returns their indices."""
    target = Path(target)
    sequences = sequences_for([(target.name, spec)], target, data, whitted, batch_spp)
    done = export_sequences(sequences, force, manifest=target / DATASET_RECORD, **where)
    return done[target.name]


def sequences_into(folders: list[tuple[Spec, Path]], data: Path | None = None) -> list[Sequence]:
    """One :class:`Sequence` per (spec, frame folder), each named by its folder
    (scenes loaded and checked, as :func:`sequences_for`); writes nothing."""
    sequences = [s for spec, folder in folders for s in sequences_for([(Path(folder).name, spec)], Path(folder), data)]
    check_distinct_folders(sequences)
    return sequences
