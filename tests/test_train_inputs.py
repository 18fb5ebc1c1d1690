"""``python -m denoise.train`` on bad inputs: a damaged or implausible
checkpoint, damaged or non-finite frames in --work, outputs inside input
folders, a benchmark scene named by path, odd bytes in --out's name and
messages that name flags the command lacks. Each is one line, exit 2, before
any step, with nothing written (the odd name trains and writes)."""
from __future__ import annotations

import json
import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
TINY = {"scene": "showcase", "frames": 3, "size": [32, 18], "spp": 1, "reference_spp": 2, "bounces": 1,
        "camera": {"dolly": 0.5}}
NAME = "tiny_showcase"
#: the flags of every run here (a checkpoint must be made with these settings)
FLAGS = ["--hidden", "4", "--steps", "2", "--rate", "0.01"]


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """A tiny training sequence, exported once (each test copies it)."""
    from export import Spec, export
    from renderer.variants import set_variant

    folder = tmp_path_factory.mktemp("tiny")
    spec = folder / f"{NAME}.json"
    spec.write_text(json.dumps(TINY))
    set_variant("llvm_ad_rgb", jit=True)
    export(Spec.load(spec), folder / "work" / NAME)
    return spec, folder / "work"


@pytest.fixture
def setup(exported, tmp_path):
    spec, work = exported
    shutil.copytree(work, tmp_path / "work")
    out = tmp_path / "w.json"
    out.write_text("before\n")
    return spec, tmp_path / "work", out


def train(spec: Path, work: Path, out: Path, *more) -> list[str]:
    return [str(spec), "--work", str(work), "--out", str(out), "--plot", str(out.with_suffix(".png")),
            *FLAGS, *map(str, more)]


def refused(capfd, argv: list[str], *words: str) -> str:
    """Runs the command: exit 2 and exactly one error line holding ``words`` on stderr
    (the worker's too), naming only flags the command has."""
    from denoise.train import _parser, main

    assert main(argv) == 2
    err = capfd.readouterr().err
    assert err.count("\n") == 1 and err.startswith("python -m denoise.train: error: "), err
    for word in words:
        assert word in err, err
    flags = {o for action in _parser()._actions for o in action.option_strings}
    assert set(re.findall(r"(?<![\w-])--[a-z][a-z-]*", err)) <= flags, err  # only flags it has
    return err


def checkpoint_of(work: Path) -> Path:
    from denoise.training import initial
    from denoise.training_state import Adam, Settings, feature_set, save_checkpoint

    settings = Settings(feature_set(True), 4, 0, 0.01, 2)
    adam = Adam(initial(settings.features, 4, 0), 0.01)
    adam.t = 1
    path = work / "w.checkpoint.npz"
    save_checkpoint(path, settings, [NAME], adam, [(0, 0.02, None)], 1.5)
    return path


def damage_checkpoint(path: Path, case: str) -> None:
    if case == "zero bytes":
        path.write_bytes(b"")
        return
    if case == "cut in half":
        path.write_bytes(path.read_bytes()[:path.stat().st_size // 2])
        return
    if case == "a folder":
        path.unlink()
        path.mkdir()
        return
    if case == "a text file":
        path.write_text("junk\n")
        return
    with np.load(path) as data:
        state = {k: data[k] for k in data.files}
    change = {"theta one short": lambda s: s.update(theta=s["theta"][:-1]),
              "theta 2-D": lambda s: s.update(theta=s["theta"].reshape(1, -1)),
              "no m": lambda s: s.pop("m"),
              "theta a string": lambda s: s.update(theta=np.array("x")),
              "t=-1": lambda s: s.update(t=np.array(-1)),
              "t=10**12": lambda s: s.update(t=np.array(10 ** 12)),
              "curve 1-D": lambda s: s.update(curve=s["curve"].ravel()),
              "m nan": lambda s: s["m"].__setitem__(3, np.nan),
              "v negative": lambda s: s["v"].__setitem__(3, -1.0),
              "curve nan": lambda s: s["curve"].__setitem__((0, 1), np.nan),
              "seconds nan": lambda s: s.update(seconds=np.array(np.nan)),
              "theta inf": lambda s: s["theta"].__setitem__(5, np.inf),
              "theta 1e30": lambda s: s.update(theta=s["theta"] * 1e30 + 1e30),
              "theta 1e300": lambda s: s.update(theta=s["theta"] * 1e300 + 1e300),
              "curve steps out of order": lambda s: s["curve"].__setitem__((0, 0), 7.0)}[case]
    change(state)
    with open(path, "wb") as file:
        np.savez(file, **state)


@pytest.mark.parametrize("case", ["zero bytes", "cut in half", "a folder", "a text file", "theta one short",
                                  "theta 2-D", "no m",
                                  "theta a string", "t=-1", "t=10**12", "curve 1-D", "m nan", "v negative",
                                  "curve nan", "seconds nan", "theta inf", "theta 1e30", "theta 1e300",
                                  "curve steps out of order"])
def test_a_damaged_checkpoint_is_one_line_before_any_step(setup, capfd, case):
    spec, work, out = setup
    path = checkpoint_of(work)
    damage_checkpoint(path, case)
    advice = "remove it" if case == "a folder" else "--restart"
    with no_warnings():
        err = refused(capfd, train(spec, work, out), str(path), advice)
    if case == "seconds nan":  # the value as a user reads it, not NumPy's repr
        assert "seconds is nan, not a finite time" in err and "array(" not in err, err
    if case == "a text file":  # NumPy takes any file that is no archive for pickled data
        assert "not a training checkpoint (not an .npz archive)" in err and "Python objects" not in err, err
    assert out.read_text() == "before\n" and not out.with_suffix(".png").exists()


class no_warnings:
    """Fails on any warning (a RuntimeWarning of NumPy's would be a line on stderr)."""

    def __enter__(self):
        import warnings

        self.catcher = warnings.catch_warnings()
        self.catcher.__enter__()
        warnings.simplefilter("error")

    def __exit__(self, *exc):
        self.catcher.__exit__(*exc)


def test_a_sound_checkpoint_resumes(setup, capfd):
    from denoise.train import main

    spec, work, out = setup
    checkpoint_of(work)
    assert main(train(spec, work, out)) == 0, capfd.readouterr().err
    assert json.loads(out.read_text())["record"]["steps"] == 2


def damaged_pixels(path: Path, whole: bool, value: float = np.nan) -> None:
    from imaging.image_io import read_exr_rgb, write_exr

    image = read_exr_rgb(path)
    if whole:
        image[:] = value
    else:
        image[2:12, 3:13] = value
    write_exr(path, {"": image})


@pytest.mark.parametrize("case, file, words", [
    ("truncated beauty", "tiny_showcase/beauty_1.exr", "not a readable EXR"),
    ("garbage matrix", "tiny_showcase/matrix_2.mat", "not a matrix file"),
    ("all-NaN truth", "tiny_showcase_reference/beauty_1.exr", "not finite"),
    ("NaN patch in the truth", "tiny_showcase_reference/beauty_2.exr", "100 pixels"),
    ("NaN patch in the beauty", "tiny_showcase/beauty_0.exr", "not finite"),
    ("a truth of -1000", "tiny_showcase_reference/beauty_1.exr", "negative radiance"),
    ("a beauty patch of -3e38", "tiny_showcase/beauty_0.exr", "100 pixels"),
    ("a truth patch of 3e38", "tiny_showcase_reference/beauty_2.exr", "beyond"),
    ("a FIFO for a truth", "tiny_showcase_reference/beauty_1.exr", "not a regular file"),
])
def test_damaged_or_non_finite_frames_are_one_line_naming_the_file(setup, capfd, case, file, words):
    spec, work, out = setup
    path = work / file
    if case == "truncated beauty":
        path.write_bytes(path.read_bytes()[:path.stat().st_size // 2])
    elif case == "garbage matrix":
        path.write_bytes(b"garbage, not matrices")
    elif case == "a FIFO for a truth":
        path.unlink()
        os.mkfifo(path)
    elif "NaN" in case:
        damaged_pixels(path, case.startswith("all"))
    else:
        damaged_pixels(path, "patch" not in case, float(case.split(" of ")[1]))
    refused(capfd, train(spec, work, out), str(path), words)
    assert out.read_text() == "before\n" and not (work / "w.checkpoint.npz").exists()


@pytest.mark.parametrize("flag, where", [("--out", "tiny_showcase/x.json"), ("--plot", "tiny_showcase_reference/x.png"),
                                         ("--out", "tiny_showcase_reference/x.json")])
def test_outputs_inside_an_input_folder_are_refused(setup, capfd, flag, where):
    spec, work, out = setup
    argv = train(spec, work, out)
    argv[argv.index(flag) + 1] = str(work / where)
    refused(capfd, argv, flag, "inside the input frame folder (--work)" if "reference" not in where
            else "inside the input ground truth (--work)")
    assert not (work / where).exists()


@pytest.mark.parametrize("spelling", ["absolute", "relative", "dotted", "a copy",
                                      "a copy with comments, blank lines and 1.0 for 1",
                                      "a copy whose mesh path is absolute"])
def test_a_benchmark_scene_by_any_spelling_is_refused(tmp_path, capfd, spelling):
    shutil.copy(ROOT / "scenes" / "lamps.txt", tmp_path / "my_lamps.txt")
    lines = (ROOT / "scenes" / "lamps.txt").read_text().splitlines()
    (tmp_path / "my_lamps_edited.txt").write_text("# my own scene\n" + "\n\n".join(
        line.replace(" 1 ", " 1.0 ", 1) + "   # mine" for line in lines) + "\n")
    (tmp_path / "my_lamps_meshes.txt").write_text((ROOT / "scenes" / "lamps.txt").read_text().replace(
        "meshes/torus.obj", str(ROOT / "scenes" / "meshes" / "torus.obj")))  # as the procedural scenes spell it
    scene = {"absolute": str(ROOT / "scenes" / "lamps.txt"),
             "relative": os.path.relpath(ROOT / "scenes" / "glossy_shadow.txt"),
             "dotted": os.path.join(os.path.relpath(ROOT.parent), ROOT.name, "scenes", ".", "transforms.txt"),
             "a copy": str(tmp_path / "my_lamps.txt"),
             "a copy with comments, blank lines and 1.0 for 1": str(tmp_path / "my_lamps_edited.txt"),
             "a copy whose mesh path is absolute": str(tmp_path / "my_lamps_meshes.txt")}[spelling]
    spec = tmp_path / "by_path.json"
    spec.write_text(json.dumps({**TINY, "scene": scene}))
    refused(capfd, train(spec, tmp_path / "work", tmp_path / "w.json"), "is the benchmark's")
    assert not (tmp_path / "work").exists()


def test_a_folder_of_other_settings_names_only_flags_the_command_has(setup, capfd, tmp_path):
    spec, work, out = setup
    other = tmp_path / "spec" / f"{NAME}.json"
    other.parent.mkdir()
    other.write_text(json.dumps({**TINY, "spp": 2}))
    err = refused(capfd, train(other, work, out), "made with other settings", "--work")
    assert "--force" not in err


@pytest.mark.parametrize("course", ["found", "absent"])
def test_a_scene_not_found_names_only_flags_the_command_has(tmp_path, capfd, monkeypatch, course):
    """Without the course, the scene lookup's remedy ("set --data ..., or
    COURSE_ROOT ...") becomes this command's: it has no --data."""
    import course as course_module

    if course == "absent":
        monkeypatch.delenv("COURSE_ROOT", raising=False)
        monkeypatch.setattr(course_module, "DEFAULT_ROOT", tmp_path / "no_course")
    spec = tmp_path / "nowhere.json"
    spec.write_text(json.dumps({**TINY, "scene": "no_such_scene_anywhere"}))
    err = refused(capfd, train(spec, tmp_path / "work", tmp_path / "w.json"), "no_such_scene_anywhere")
    assert ("; set COURSE_ROOT to the course folder" in err) == (course == "absent"), err
    assert not (tmp_path / "work").exists()


def test_an_out_name_that_is_not_utf8_trains_and_writes(setup, capfd):
    from denoise.train import main

    spec, work, _ = setup
    out = work.parent / os.fsdecode(b"\xff bad.json")
    argv = train(spec, work, out)
    argv[argv.index("--steps") + 1] = "1"
    assert main(argv) == 0, capfd.readouterr().err
    printed = capfd.readouterr().out  # the final line, naming the weights
    assert json.loads(out.read_text())["record"]["steps"] == 1 and out.with_suffix(".png").is_file()
    assert "\\xff bad.json" in printed and all(line.isprintable() for line in printed.splitlines())


def test_an_error_in_the_worker_is_sent_as_one_line(setup):
    """Whatever fails in the training's worker reaches the parent as one line, never a traceback."""
    import signal

    from denoise.train import train_worker
    from denoise.training_state import Settings, feature_set

    spec, work, out = setup
    beauty = work / NAME / "beauty_1.exr"
    beauty.write_bytes(beauty.read_bytes()[:100])
    sent = []

    class Connection:
        send = sent.append

    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    try:
        train_worker(Connection(), [work / NAME], Settings(feature_set(True), 4, 0, 0.01, 2), work / "w.npz", False)
        train_worker(Connection(), [], None, work / "w.npz", False)  # a bug: no settings
    finally:
        for signum, handler in handlers.items():
            signal.signal(signum, handler)
    assert [tag for tag, _ in sent] == ["error", "error"]
    assert sent[0][1].startswith(f"{beauty}: not a readable EXR") and "\n" not in sent[0][1]
    assert sent[1][1].startswith("the training's worker process failed (AttributeError: ") and "\n" not in sent[1][1]


def test_frames_too_many_to_hold_are_refused_before_any_render(tmp_path, capfd):
    """Training holds every frame at once: a set that cannot fit in any memory
    here is one line before anything is rendered; the default set fits in 4 GiB."""
    from denoise.train import check_frames_fit, check_specs
    from denoise.training import TRAINING

    spec = tmp_path / "huge.json"
    spec.write_text(json.dumps({**TINY, "size": [16384, 16384], "frames": 100, "reference_spp": 4}))
    refused(capfd, train(spec, tmp_path / "work", tmp_path / "w.json"), "training on 100 frames held at once",
            f"16384x16384, {spec}) needs about", "GiB is available; train on smaller frames")
    assert not (tmp_path / "work").exists()
    check_frames_fit(check_specs(TRAINING), memory=4 << 30)


def test_restart_leaves_the_checkpoint_while_the_run_is_refused(setup, capfd):
    """--restart replaces the checkpoint at the first step, not before: a run refused
    before it (a damaged frame) leaves it as it was, and says how to render the frame anew."""
    spec, work, out = setup
    path = checkpoint_of(work)
    before = path.read_bytes()
    beauty = work / NAME / "beauty_1.exr"
    beauty.write_bytes(beauty.read_bytes()[:200])
    refused(capfd, train(spec, work, out, "--restart"), str(beauty), "not a readable EXR",
            f"remove {work / NAME} and {work / NAME}_reference and run again")
    assert path.read_bytes() == before and out.read_text() == "before\n"


def test_a_checkpoint_beyond_the_steps_asked_is_refused(setup, capfd):
    """A checkpoint of more steps than --steps is one line naming it: its weights are not what was asked."""
    spec, work, out = setup
    path = checkpoint_of(work)
    with np.load(path) as data:
        state = {k: data[k] for k in data.files}
    state.update(t=np.array(2), curve=np.array([[0, 0.02, np.nan], [1, 0.019, np.nan]]))
    with open(path, "wb") as file:
        np.savez(file, **state)
    argv = [str(spec), "--work", str(work), "--out", str(out), "--plot", str(out.with_suffix(".png")),
            "--hidden", "4", "--rate", "0.01", "--steps", "1"]
    refused(capfd, argv, str(path), "holds 2 steps, more than --steps 1", "--restart")
    assert out.read_text() == "before\n"


def test_a_pickled_checkpoint_is_refused_without_numpys_advice(setup, capfd):
    """A checkpoint that holds Python objects: one line, never NumPy's advice to load it unsafely."""
    spec, work, out = setup
    path = work / "w.checkpoint.npz"
    np.save(path.with_suffix(".tmp.npy"), np.array([{"a": 1}], dtype=object), allow_pickle=True)
    path.with_suffix(".tmp.npy").rename(path)
    err = refused(capfd, train(spec, work, out), str(path), "Python objects", "--restart")
    assert "allow_pickle" not in err


def test_a_one_frame_training_sequence_is_refused(tmp_path, capfd):
    """The loss leaves frame 0 out: a sequence of one frame has nothing to train on."""
    spec = tmp_path / "one.json"
    spec.write_text(json.dumps({**TINY, "frames": 1}))
    refused(capfd, [str(spec), "--work", str(tmp_path / "work"), "--out", str(tmp_path / "w.json")],
            str(spec), "1 frame(s)", "2 or more")
    assert not (tmp_path / "work").exists() and not (tmp_path / "w_loss.png").exists()


@pytest.mark.parametrize("out, plot", [("scratch/w.json", "scratch/w_loss.png"),
                                       ("denoise/learned_asvgf.json", "docs/learned_asvgf_loss.png"),
                                       ("denoise/learned_asvgf_half_hidden.json",
                                        "docs/learned_asvgf_half_hidden_loss.png")])
def test_the_plot_goes_to_docs_only_for_a_committed_weights_file(tmp_path, out, plot):
    """Without --plot, a scratch run's curves go beside its --out, never into the repository."""
    from denoise.train import ROOT, default_plot

    base = ROOT if out.startswith("denoise/") else tmp_path
    assert default_plot(base / out) == (ROOT if plot.startswith("docs/") else tmp_path) / plot


def test_a_second_training_in_a_busy_work_folder_is_refused(setup, capfd):
    """Two trainings in one --work at once wrote one checkpoint, step after step, each
    resuming nothing of the other's; the second is now one line, its checkpoint and --out untouched."""
    from export.files import locked

    spec, work, out = setup
    with locked([work], doing="training", remedy="give another --work"):  # as a training in progress holds it
        refused(capfd, train(spec, work, out), f"{work}: another training is writing into this folder; wait for it "
                "to finish, or give another --work")
    assert out.read_text() == "before\n" and not list(work.glob("*.checkpoint.npz"))


def test_a_second_training_into_a_busy_out_is_refused(setup, capfd, tmp_path):
    """Two trainings into one --out from two --work folders: the one that ended last replaced
    the other's weights without a word; the second is now one line, --out untouched."""
    from export.files import name_lock_file, name_locked

    spec, work, out = setup
    other = tmp_path / "other work"
    with name_locked(out, doing="training", remedy="give another --out"):  # as a training in progress holds it
        refused(capfd, train(spec, other, out), f"{out}: another training is writing this file; wait for it to "
                "finish, or give another --out")
        assert name_lock_file(out).is_file()
    assert out.read_text() == "before\n" and not other.exists()
    assert not name_lock_file(out).exists()  # the lock file goes with the lock: none is left in /tmp per --out


@pytest.mark.parametrize("method, weights", [("learned-mixture", "learned_mixture.json"),
                                             ("learned-asvgf", "learned_asvgf.json")])
@pytest.mark.parametrize("change, expected", [({}, ""), ({"steps": 1}, "steps 1, not its"),
                                               ({"seed": 3}, "seed 3, not its"),
                                               ({"specs": 1}, "spec files, not its")])
def test_a_run_that_would_replace_a_committed_network_by_another_is_noted(method, weights, change, expected):
    """The default command (the README's) remakes the committed weights file without a
    word; a run of other settings, steps or sequences that would replace it is named
    before any work, where it is easy to give another --out."""
    from denoise.train import PROCEDURAL, display_path
    from denoise.trainers import TRAINED
    from denoise.training import TRAINING
    from denoise.training_state import Settings, feature_set

    trained = TRAINED[method]
    out = Path(__file__).resolve().parents[1] / "denoise" / weights
    settings = Settings(feature_set(True, method), trained.hidden, change.get("seed", 0), trained.rate,
                        change.get("steps", trained.steps), method)
    specs = [display_path(p) for p in list(TRAINING)[:change.get("specs", len(TRAINING))]]
    difference = trained.committed_difference(out, settings, specs, PROCEDURAL)
    assert (expected in difference) and bool(difference) == bool(expected), difference
    assert trained.committed_difference(Path("elsewhere.json"), settings, specs, PROCEDURAL) == ""
