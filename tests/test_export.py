"""export in one process: the reference's halves, seeds, spec checks,
folders that refuse other settings, and an interrupted export that resumes."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from core.errors import SpecError

TINY = {"scene": "lamps", "frames": 2, "size": [24, 16], "spp": 1, "reference_spp": 8, "bounces": 1,
        "camera": {"dolly": 0.5}, "objects": {"5": {"translate": [0.6, 0, 0.3]}}}
BATCH_SPP = 2  # 4 batches per frame: 2 per half


def rgb(path: Path) -> np.ndarray:
    from imaging.image_io import read_exr

    channels = read_exr(path)
    return np.stack([channels[c] for c in "RGB"], -1)


def folder_bytes(target: Path) -> dict[str, bytes]:
    """Every image and matrix file of a sequence and its reference."""
    from export import reference_folder

    files = {}
    for folder in (target, reference_folder(target)):
        for path in sorted(folder.iterdir()):
            if path.suffix in (".exr", ".mat"):
                files[f"{folder.name}/{path.name}"] = path.read_bytes()
    return files


def export_tiny(target: Path, **kwargs):
    from export import Spec, export

    return export(Spec.from_dict(dict(TINY)), target, batch_spp=BATCH_SPP, **kwargs)


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    """The tiny sequence exported in one go, in this process."""
    from renderer import variants

    variants.set_variant(None, quiet=True)  # llvm_ad_rgb where usable
    target = tmp_path_factory.mktemp("whole") / "seq"
    assert export_tiny(target) == [0, 1]
    return target


def test_reference_is_the_mean_of_two_independent_halves(uninterrupted):
    from export import reference_folder

    reference = reference_folder(uninterrupted)
    for frame in (0, 1):
        beauty, a, b = (rgb(reference / f"{name}_{frame}.exr") for name in ("beauty", "half_a", "half_b"))
        # beauty = (a + b) / 2 up to float32 rounding of the three files
        assert np.allclose(beauty, (a.astype(np.float64) + b) / 2, rtol=2e-7, atol=1e-9)
        assert halves_look_independent(a, b)


def halves_look_independent(a: np.ndarray, b: np.ndarray) -> bool:
    """Independently seeded halves of 4 spp differ in most lit pixels; the same
    seeds (a broken seed rule) make them identical."""
    lit = (a.sum(-1) > 0) | (b.sum(-1) > 0)
    return lit.sum() > 0 and np.mean(a[lit] != b[lit]) > 0.5


def test_halves_check_fails_when_seeds_repeat(tmp_path, uninterrupted, monkeypatch):
    """The check above on purpose-broken seeds (batch ignored): the halves come out equal."""
    import export.store as export_module
    from export import reference_folder

    monkeypatch.setattr(export_module, "seed", lambda key, frame, stream, batch=0: 7 + frame)
    target = tmp_path / "seq"
    export_tiny(target)
    reference = reference_folder(target)
    assert not halves_look_independent(rgb(reference / "half_a_0.exr"), rgb(reference / "half_b_0.exr"))


def test_seeds_depend_on_sequence_frame_pass_and_batch_only():
    from export import seed

    seeds = {seed(key, frame, stream, batch) for key in ("k1", "k2") for frame in range(3)
             for stream in ("noisy", "reference") for batch in range(4)}
    assert len(seeds) == 2 * 3 * 2 * 4
    assert seed("k1", 2, "reference", 3) == seed("k1", 2, "reference", 3)
    assert all(0 <= s < 2 ** 31 for s in seeds)


def test_batches_split_each_half_exactly():
    from export import Sequence, Spec

    for reference_spp, batch_spp in ((8, 2), (256, 64), (10, 4), (2, 64), (1024, 1000)):
        spec = Spec.from_dict(dict(TINY, reference_spp=reference_spp))
        batches = Sequence("s", spec, "x.txt", "out", batch_spp).batches()
        for half in "ab":
            sizes = [spp for h, spp in batches if h == half]
            assert sum(sizes) == reference_spp // 2 and max(sizes) <= batch_spp


@pytest.mark.parametrize("change, message", [
    ({"spp": 0}, "spp: expected 1.."),
    ({"frames": 0}, "frames: expected 1.."),
    ({"reference_spp": 7}, "reference_spp: expected an even number"),
    ({"size": [0, 16]}, "width"),
    ({"size": [100000, 16]}, "width"),
    ({"size": [16]}, "size: expected [width, height]"),
    ({"spp": 2.5}, "spp: expected an integer"),
    ({"shadows": "yes"}, "shadows: expected true or false"),
    ({"shadows": None}, "shadows: expected true or false, found null"),  # in JSON's words, not Python's
    ({"": 1}, 'unknown keys ""'),  # an empty key is shown, not left out
    ({"colour": 1}, 'unknown keys "colour"'),
    ({"camera": {"zoom": 2}}, 'unknown keys "zoom"'),
    ({"camera": {"dolly": float("nan")}}, "camera.dolly: expected a finite number"),
    ({"objects": {"x": {}}}, "expected an object index"),
    ({"objects": {"1": {"rotate": {"axis": [0, 0, 0], "degrees": 3}}}}, "expected an axis of length"),
    ({"objects": {"1": {"rotate": {"axis": [1e-170, 0, 0], "degrees": 3}}}}, "expected an axis of length"),
    ({"size": [16384, 16384], "spp": 64}, "samples in one render"),
])
def test_bad_specs_are_refused_before_any_work(change, message):
    from export import Spec

    with pytest.raises(SpecError, match=message.replace("[", r"\[").replace("]", r"\]")):
        Spec.from_dict(dict(TINY, **change))


def test_cli_refuses_bad_specs_with_one_line(tmp_path, capsys):
    """spp 0 once ended in SIGFPE; a missing object index after loading the scene;
    both are one line and exit 2, and nothing is written."""
    from export import main

    for change, message in (({"spp": 0}, "spp: expected 1..1048576, found 0"),
                            ({"objects": {"99": {"translate": [1, 0, 0]}}}, "object 99 does not exist")):
        spec = tmp_path / "spec.json"
        spec.write_text(json.dumps(dict(TINY, **change)))
        assert main([str(spec), str(tmp_path / "out"), "--local"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("python -m export: error: ") and message in err
        assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("where, remedy", [(["--local"], "; make the spec's size smaller"),
                                           (["--workers", "2"], "; give fewer --workers, or make the spec's size")])
def test_frames_too_large_for_the_memory_are_one_line_before_any_render(tmp_path, capsys, where, remedy):
    """A 16384x16384 frame (within every spec limit) was killed for memory in its
    first render; now one line, exit 2, nothing written, no worker started."""
    from export import main

    spec = tmp_path / "huge.json"
    spec.write_text(json.dumps(dict(TINY, size=[16384, 16384], reference_spp=2)))
    assert main([str(spec), str(tmp_path / "out"), *where]) == 2
    err = capsys.readouterr().err
    at_once = " (2 at once)" if "--workers" in where else ""
    assert err.count("\n") == 1 and err.startswith(f"python -m export: error: {spec}: rendering its 16384x16384 "
                                                   f"frames{at_once} needs about "), err
    assert "GiB is available" + remedy in err, err
    assert not (tmp_path / "out").exists()


def test_folder_made_with_other_settings_is_refused(tmp_path, uninterrupted, capsys):
    import shutil

    from export import main, reference_folder

    target = tmp_path / "seq"
    shutil.copytree(uninterrupted, target)
    shutil.copytree(reference_folder(uninterrupted), reference_folder(target))
    spec = tmp_path / "seq.json"
    spec.write_text(json.dumps(TINY))
    common = [str(spec), str(target), "--local", "--batch-spp", str(BATCH_SPP)]
    before = folder_bytes(target)
    for other in (["--frames", "3"], ["--size", "20", "16"], ["--reference-spp", "4"], ["--batch-spp", "4"]):
        assert main(common + other) == 2
        err = capsys.readouterr().err
        assert "made with other settings" in err and "--force" in err, err
        assert folder_bytes(target) == before
    assert main(common) == 0  # the same settings: resumes, nothing to do
    assert "0 frames rendered" in capsys.readouterr().out
    # the same scene under another path (another checkout) is the same setting; other contents are not
    record = json.loads((target / "sequence.json").read_text())
    (target / "sequence.json").write_text(json.dumps(dict(record, scene_file="/elsewhere/scenes/x.txt")))
    assert main(common) == 0 and "0 frames rendered" in capsys.readouterr().out
    (target / "sequence.json").write_text(json.dumps(dict(record, scene_sha256="0" * 64)))
    assert main(common) == 2 and "scene_sha256" in capsys.readouterr().err
    # a damaged record (not an object, a key twice, UTF-16) is one line, as other settings are
    for damaged in (b"[1]", json.dumps(record)[:-1].encode() + b', "spp": 1}', json.dumps(record).encode("utf-16")):
        (target / "sequence.json").write_bytes(damaged)
        assert main(common) == 2
        err = capsys.readouterr().err
        assert "made with other settings" in err and len(err.splitlines()) == 1, err
    (target / "sequence.json").write_text(json.dumps(record))
    # a folder of frames without a record (an older export) is refused too
    (target / "sequence.json").unlink()
    assert main(common) == 2
    assert "without a sequence.json" in capsys.readouterr().err
    # --force starts over with the new settings
    assert main(common + ["--frames", "1", "--force"]) == 0
    assert sorted(p.name for p in target.glob("beauty_*.exr")) == ["beauty_0.exr"]
    assert sorted(p.name for p in reference_folder(target).glob("*.exr")) == [
        "beauty_0.exr", "half_a_0.exr", "half_b_0.exr"]
    assert json.loads((target / "sequence.json").read_text())["spec"]["frames"] == 1


class Stop(KeyboardInterrupt):
    pass


def export_interrupted_after(target: Path, count: int) -> list:
    """The tiny sequence exported until ``count`` tasks are done, then stopped
    as Ctrl-C would stop it; returns those tasks."""
    done = []

    def interrupt(task):
        done.append(task)
        if len(done) == count:
            raise Stop

    with pytest.raises(Stop):
        export_tiny(target, after_task=interrupt)
    return done


def test_interrupted_export_resumes_with_only_the_missing_tasks(tmp_path, uninterrupted):
    """Ctrl-C after 3 of the 10 tasks (between a frame's batches); the rerun
    renders only the 7 missing tasks, and the files equal an uninterrupted run's."""
    from export import Spec, plan, sequences_for

    target = tmp_path / "seq"
    done = export_interrupted_after(target, 3)
    [sequence] = sequences_for([("seq", Spec.from_dict(dict(TINY)))], target, batch_spp=BATCH_SPP)
    remaining = plan(sequence)
    assert len(remaining) == 10 - 3
    assert {(t.frame, t.kind, t.batch) for t in remaining}.isdisjoint({(t.frame, t.kind, t.batch) for t in done})
    manifest = json.loads((target / "dataset.json").read_text())
    assert [f["status"] for f in manifest["sequences"][0]["frames"]] == ["missing", "missing"]
    rerun = []
    assert export_tiny(target, after_task=rerun.append) == [0, 1]
    assert len(rerun) == 7
    assert folder_bytes(target) == folder_bytes(uninterrupted)
    assert not (target.parent / "seq_reference" / ".batches").exists()
    manifest = json.loads((target / "dataset.json").read_text())
    frames = manifest["sequences"][0]["frames"]
    assert [f["status"] for f in frames] == ["rendered", "rendered"]
    assert sum(len(f["tasks"]) for f in frames) == 10  # the first run's timings are kept


def test_a_ctrl_c_that_a_task_swallows_still_stops_the_export(tmp_path, monkeypatch, uninterrupted):
    """SIGINT while a task renders in this process, where the task's own code
    swallows the KeyboardInterrupt (an export ran to the end and exited 0 after
    a Ctrl-C, 3 runs in 30): the export records that task and stops."""
    import os
    import signal
    import time

    import export.runners as runners

    real, calls = runners.run_task, []

    def swallowing(task):
        calls.append(task)
        if len(calls) == 2:
            try:  # a handler that raises does so in here
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(0.5)
            except KeyboardInterrupt:
                pass
        return real(task)

    monkeypatch.setattr(runners, "run_task", swallowing)
    # Python's own Ctrl-C handler, whatever this process inherited (started in the background, a
    # shell's job has SIGINT ignored)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            export_tiny(tmp_path / "seq")
    finally:
        signal.signal(signal.SIGINT, previous)
    assert len(calls) == 2


def test_resume_check_fails_when_finished_batches_are_ignored(tmp_path, monkeypatch):
    """The resume test's count on purpose-broken resuming (every batch redone):
    more than the missing tasks are planned."""
    import export.store as export_module
    from export import Spec, plan, sequences_for

    target = tmp_path / "seq"
    export_interrupted_after(target, 3)
    monkeypatch.setattr(export_module, "batch_path", lambda *args: Path("/nonexistent/batch.npy"))
    [sequence] = sequences_for([("seq", Spec.from_dict(dict(TINY)))], target, batch_spp=BATCH_SPP)
    assert len(plan(sequence)) > 10 - 3


def passes_on(threads: int, spp: int, batch_spp: int) -> list[bytes]:
    """The frame and batch results of frame 0 at 160x120 (more than one Dr.Jit
    block, so 2 threads split each image) rendered on ``threads`` Dr.Jit threads."""
    from export import Spec, plan, run_task, sequences_for

    spec = Spec.from_dict(dict(TINY, size=[160, 120], spp=spp, reference_spp=2 * batch_spp))
    [sequence] = sequences_for([("big", spec)], Path("/nonexistent/big"), batch_spp=batch_spp)
    results = []
    for task in plan(sequence, threads):
        if task.frame == 0:
            result, _ = run_task(task)
            parts = [result] if task.kind == "batch" else [result.beauty, result.normal, result.position,
                                                          result.depth, result.ids, result.albedo]
            results += [np.ascontiguousarray(p).tobytes() for p in parts]
    return results


@pytest.mark.parametrize("spp, batch_spp", [(1, 3), (2, 8), (1, 16)])
def test_bytes_do_not_depend_on_the_thread_count(uninterrupted, spp, batch_spp):
    """1 and 2 Dr.Jit threads (a worker's and the local process's) give the same bytes."""
    import drjit as dr
    import mitsuba as mi

    if not dr.is_jit_v(mi.Float):
        pytest.skip("Dr.Jit's thread count does not apply to scalar_rgb (and this takes minutes there)")

    threads = dr.thread_count()
    try:
        assert passes_on(1, spp, batch_spp) == passes_on(2, spp, batch_spp)
    finally:
        dr.set_thread_count(threads)


def test_thread_check_fails_without_single_threaded_passes(uninterrupted, monkeypatch):
    """The check above on purpose-broken code (passes on the process's threads):
    the renders follow the thread count."""
    import drjit as dr
    import mitsuba as mi

    import export.tasks as export_module

    if not dr.is_jit_v(mi.Float):
        pytest.skip("scalar_rgb renders on one thread whatever the thread count: the mutation cannot show")
    monkeypatch.setattr(export_module, "RENDER_THREADS", None)
    threads = dr.thread_count()
    try:
        assert passes_on(1, 1, 3) != passes_on(2, 1, 3)
    finally:
        dr.set_thread_count(threads)


def test_a_spec_made_unsound_by_a_flag_names_the_flags(tmp_path):
    """light_switch.json is sound as written; with --frames 3 its switch at frame 5
    is out of range: the line said only the spec's key, as if the file were wrong."""
    from export import Spec

    spec = Path(__file__).resolve().parent.parent / "scenes" / "sequences" / "light_switch.json"
    Spec.load(spec)
    with pytest.raises(SpecError, match=r"lights\.0\.frames\[0\]: expected 0\.\.2, found 5 \(with --frames 3\)$"):
        Spec.load(spec, frames=3)


def test_a_folder_of_other_settings_is_refused_in_a_short_line(tmp_path, capsys):
    """A folder made with a million 1-spp batches was refused in one line of 3.2 MB
    (the whole batch list); each changed value is now cut to a few dozen characters."""
    from export import main
    from export.ground_truth import SEQUENCE_RECORD

    spec = tmp_path / "spec.json"
    spec.write_text(json.dumps(TINY))
    target = tmp_path / "seq"
    target.mkdir()
    (target / SEQUENCE_RECORD).write_text(json.dumps({"batches": [1] * 100_000, "format": 2}))
    assert main([str(spec), str(target), "--local"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "made with other settings" in err and "(300000 characters)" in err, err[:300]
    assert len(err) < 1000, len(err)
