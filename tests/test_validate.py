"""python -m denoise.validate: the held-out sequences judged against a converged truth."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest


def test_judge_scores_each_method_per_frame_and_the_table_gives_ratios(exported):
    from denoise.methods import from_name
    from denoise.validate import judge, table

    errors = judge(exported, {"asvgf": lambda: from_name("asvgf"), "raw": lambda: from_name("bilateral")})
    assert set(errors) == {"asvgf", "raw"} and all(len(e) == 2 for e in errors.values())
    assert all(np.isfinite(v) and v > 0 for e in errors.values() for v in e)
    long = {m: e * 3 for m, e in errors.items()}  # six frames: frames >= 4 exist
    lines = table({"seq": long})
    assert lines[0] == "| sequence | asvgf | raw |"
    ratio = np.mean(long["raw"][4:]) / np.mean(long["asvgf"][4:])
    assert f"({ratio:.2f}×)" in lines[2]


@pytest.mark.parametrize("argv, words", [
    (["--reference-spp", "3"], "--reference-spp must be even"),
    (["--methods", "nonsense"], "--methods: unknown method 'nonsense'"),
    (["--methods", "asvgf", "asvgf"], "--methods: asvgf named twice"),
    (["scenes/sequences/training/network/mirrors_switch.json"] * 2, "two specs named mirrors_switch: they would share"),
    (["--network", "denoise/learned_asvgf.json", "denoise/../denoise/learned_asvgf.json"],
     "a second method named learned_asvgf (each is named by its file name: copy one to another name)"),
    (["--network", "nowhere.json"], "nowhere.json: no such weights file"),
    (["nowhere_spec.json"], "nowhere_spec.json"),
    (["scenes/sequences/training/network/mirrors_switch.json", "--json",
      "scenes/sequences/training/network/mirrors_switch.json"], "is the input SPEC.json"),
])
def test_bad_arguments_are_one_line_before_any_rendering(argv, words, tmp_path, capsys):
    from denoise.validate import main

    assert main(argv + ["--work", str(tmp_path / "work")]) == 2
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1
    assert not (tmp_path / "work").exists()


TINY_SPEC = "scenes/sequences/training/network/showcase_orbit.json"


def tiny_spec(tmp_path, frames: int):
    """A copy of a training spec with ``frames`` frames at 32x18, named tinyN."""
    import json
    from pathlib import Path

    data = json.loads(Path(TINY_SPEC).read_text())
    data.update(frames=frames, size=[32, 18])
    path = tmp_path / f"tiny{frames}.json"
    path.write_text(json.dumps(data))
    return path


@pytest.mark.parametrize("argv, words", [
    (["--json", "{work}/tiny5/x.json"], "is inside the input frame folder (--work) of tiny5"),
    (["--json", "{work}/tiny5_reference/x.json"], "is inside the input ground truth (--work) of tiny5"),
    (["--json", "{tmp}/w.json", "--network", "{tmp}/w.json"], "is the input --network"),
    (["--json", "{tmp}/x.txt"], "--json writes JSON: name it .json"),
    (["--network", "{tmp}"], ": a folder, not a weights file"),
])
def test_outputs_into_inputs_and_misnamed_files_are_one_line_before_any_work(argv, words, tmp_path, capsys):
    """--json inside a sequence's folder under --work (or onto a weights file it reads) was accepted."""
    from denoise.validate import main

    (tmp_path / "w.json").write_text("{}")
    argv = [a.format(work=tmp_path / "work", tmp=tmp_path) for a in argv]
    spec = tiny_spec(tmp_path, 5)
    assert main(argv + [str(spec), "--work", str(tmp_path / "work"), "--methods", "asvgf", "--reference-spp", "2"]) == 2
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1, err
    assert not (tmp_path / "work").exists()


def test_any_method_name_is_taken_and_the_header_promises_no_missing_ratio(tmp_path, capsys):
    """validate took only the names of method_names() (not demod+atrous+temporal, which python -m
    denoise takes), printed "ratio to asvgf's" without an asvgf column (or with asvgf alone), and
    noted a training sequence's name where no network was judged, on a sequence of that name alone."""
    from denoise.validate import main

    spec = tiny_spec(tmp_path, 5).rename(tmp_path / "showcase_orbit.json")  # a training sequence's name alone
    runs = ((["demod+atrous+temporal", "bilateral"], "| sequence | demod+atrous+temporal | bilateral |"),
            (["asvgf"], "| sequence | asvgf |"))  # the second renders nothing: the same --work
    for methods, header in runs:
        assert main([str(spec), "--work", str(tmp_path / "work"), "--reference-spp", "2", "--local",
                     "--methods", *methods]) == 0
        captured = capsys.readouterr()
        assert "note:" not in captured.err and "ratio to asvgf" not in captured.out, captured
        assert header in captured.out
    frame = tmp_path / "work" / "showcase_orbit" / "beauty_2.exr"  # a damaged frame of the cache
    frame.write_bytes(frame.read_bytes()[:100])
    assert main([str(spec), "--work", str(tmp_path / "work"), "--reference-spp", "2", "--methods", "asvgf"]) == 2
    err = capsys.readouterr().err.splitlines()[-1]  # after the progress line
    work = tmp_path / "work"
    remedy = f"remove {work / 'showcase_orbit'} and {work / 'showcase_orbit_reference'} to render them again"
    assert err.startswith("python -m denoise.validate: error: ") and str(frame) in err and remedy in err, err


def test_a_training_sequence_is_known_by_its_settings_not_its_name_alone(tmp_path):
    """A judged training sequence gets a note (its numbers are not held-out ones) where it is the
    training's own: the same settings but the truth's samples, wherever the file lies."""
    import json
    import shutil

    from denoise.validate import TRAINED_ON, training_sequences
    from export import Spec

    shutil.copy(TINY_SPEC, tmp_path / "copy")
    copy = (tmp_path / "copy").rename(tmp_path / "showcase_orbit.json")
    assert "showcase_orbit" in TRAINED_ON
    assert training_sequences({copy: Spec.load(copy, reference_spp=2)}, 2) == ["showcase_orbit"]
    changed = json.loads(copy.read_text()) | {"frames": 5}
    copy.write_text(json.dumps(changed))
    assert training_sequences({copy: Spec.load(copy, reference_spp=2)}, 2) == []
    held_out = Path(TINY_SPEC).parent / "mirrors_switch.json"
    assert training_sequences({held_out: Spec.load(held_out, reference_spp=2)}, 2) == []


@pytest.mark.parametrize("frames", [1, 3, 4])
def test_a_sequence_without_judged_frames_is_one_line_before_any_rendering(frames, tmp_path, capsys):
    """A sequence of 4 frames or fewer printed ``| tiny1 | nan | nan (nan×) |`` and NumPy's warning, exit 0."""
    from denoise.validate import main

    spec = tiny_spec(tmp_path, frames)
    assert main([str(spec), "--work", str(tmp_path / "work"), "--reference-spp", "2",
                 "--methods", "asvgf", "svgf"]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.count("\n") == 1, captured
    assert f"{spec}: {frames} frame" in captured.err and "at least 5 frames" in captured.err, captured.err
    assert not (tmp_path / "work").exists()


def test_the_table_escapes_the_names_a_user_chose():
    """A --network name with a newline or a byte that is not UTF-8 split or corrupted the table."""
    import os

    from denoise.validate import table

    odd = os.fsdecode(b"net\xff")
    lines = table({"seq\nname": {"asvgf": [0.1] * 6, odd: [0.05] * 6, "a|b": [0.2] * 6}})
    assert len(lines) == 3 and all("\n" not in line for line in lines)
    assert "\\xff" in lines[0] and "a\\|b" in lines[0] and "| seq\\nname |" in lines[2]
    "\n".join(lines).encode()  # printable on any terminal: no lone surrogate


def test_a_folder_made_with_other_settings_names_no_flag_that_does_not_exist(tmp_path, capsys):
    """The refusal said "use --force to start over", a flag denoise.validate does not have."""
    from denoise.validate import main

    (tmp_path / "work" / "tiny5").mkdir(parents=True)
    (tmp_path / "work" / "tiny5" / "sequence.json").write_text("{}")
    assert main([str(tiny_spec(tmp_path, 5)), "--work", str(tmp_path / "work"), "--methods", "asvgf",
                 "--reference-spp", "2"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "made with other settings" in err and "--force" not in err, err
    assert "another --work" in err


def test_a_render_too_large_for_one_batch_names_no_flag_that_does_not_exist(tmp_path):
    """The export's remedy "lower --batch-spp" becomes the cache commands' own
    (denoise.validate, fit, train, the benchmarks render through render())."""
    from core.errors import SpecError
    from denoise.validate import render
    from export import Spec

    spec = Spec.from_dict({"scene": "lamps", "frames": 1, "size": [16384, 16384], "spp": 1, "reference_spp": 64})
    with pytest.raises(SpecError) as error:
        render([(spec, tmp_path / "work" / "big")])
    assert str(error.value).endswith("samples in one render; make the spec's size smaller"), error.value
    assert "--" not in str(error.value)
    assert not (tmp_path / "work").exists()


def test_a_sequence_too_large_for_the_memory_is_one_line_before_any_render(tmp_path, capsys):
    """judge() holds a sequence's frames and truth: a sequence beyond the memory is refused before rendering."""
    import json

    from denoise.validate import main

    spec = tiny_spec(tmp_path, 5)
    spec.write_text(json.dumps({**json.loads(spec.read_text()), "size": [16384, 16384]}))
    assert main([str(spec), "--work", str(tmp_path / "work"), "--methods", "asvgf", "--reference-spp", "2"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{spec}: judging its 5 frames of 16384x16384 needs about " in err, err
    assert "GiB is available; judge smaller frames or fewer of them" in err, err
    assert not (tmp_path / "work").exists()


def test_an_unusable_libllvm_is_named_not_a_scalar_fallback(tmp_path):
    """With the libLLVM unusable the command fell back to scalar_rgb in silence, then refused a work folder
    made under llvm_ad_rgb with a flag it does not have; it has no scalar form, so it says why in one line."""
    import os
    import subprocess
    import sys

    library = tmp_path / "libLLVM.so"
    library.write_text("not a library\n")
    done = subprocess.run([sys.executable, "-m", "denoise.validate", str(tiny_spec(tmp_path, 5)),
                           "--work", str(tmp_path / "work"), "--methods", "asvgf", "--reference-spp", "2"],
                          capture_output=True, text=True, timeout=300,
                          env={**os.environ, "DRJIT_LIBLLVM_PATH": str(library),
                               "XDG_CACHE_HOME": str(tmp_path / "cache")})
    lines = done.stderr.splitlines()
    assert done.returncode == 2 and len(lines) == 1 and "Traceback" not in done.stderr, done.stderr
    assert str(library) in lines[0] and "JIT variant" in lines[0] and "--force" not in lines[0], lines
    assert not (tmp_path / "work").exists()


def benchmark(argv: list[str]):
    """``python -m benchmarks.denoise ARGV`` (tests never import benchmarks/): returncode, out, err."""
    import subprocess
    import sys
    from pathlib import Path
    from types import SimpleNamespace

    done = subprocess.run([sys.executable, "-m", "benchmarks.denoise", *argv], capture_output=True, text=True,
                          timeout=300, cwd=Path(__file__).resolve().parents[1])
    return SimpleNamespace(returncode=done.returncode, out=done.stdout, err=done.stderr)


@pytest.mark.parametrize("argv, words", [
    (["--json", "{work}/dolly_lamps_96x54_16spp_quick/x.json", "--no-timing"],
     "is inside the input frame folder (--work) of dolly_lamps"),
    (["--json", "{work}/dolly_lamps_96x54_16spp_quick_reference/x.json", "--no-timing"],
     "is inside the input ground truth (--work) of dolly_lamps"),
    (["--json", "{work}/timing_dolly_lamps_160x90_3f_quick/x.json"], "is inside the input frame folder"),
    (["--json", "{work}/x.txt", "--no-timing"], "--json writes JSON: name it .json"),
    (["--no-timing"], "made with other settings"),
])
def test_the_benchmark_refuses_outputs_into_its_inputs_in_one_line(argv, words, tmp_path):
    """benchmarks.denoise wrote --json into a sequence's cached folder, took x.txt, and its refusal of a
    folder made with other settings named --force, which it does not have. (The folder of other settings
    is there in every case, so that the code before the fix refused there instead of rendering.)"""
    work = tmp_path / "work"
    (work / "dolly_lamps_96x54_16spp_quick").mkdir(parents=True)
    (work / "dolly_lamps_96x54_16spp_quick" / "sequence.json").write_text("{}")
    argv = [a.format(work=work) for a in argv]
    captured = benchmark(["--quick", "--work", str(work), "--sequences", "dolly_lamps", "--methods", "svgf", *argv])
    assert captured.returncode == 2 and captured.err.count("\n") == 1, captured.err
    assert words in captured.err and "--force" not in captured.err, captured.err
    assert captured.out == "" and sorted(p.name for p in work.rglob("*")) == ["dolly_lamps_96x54_16spp_quick",
                                                                              "sequence.json"]


def test_the_benchmark_refuses_an_empty_sequence_list():
    """``--sequences`` with no names ran every sequence."""
    captured = benchmark(["--quick", "--sequences", "--reference-spp", "3"])
    err = captured.err
    assert captured.returncode == 2
    assert "--sequences" in err and "--reference-spp" not in err and err.count("\n") == 1, err


def test_fit_evaluate_on_a_short_sequence_names_the_sequence_not_a_flag_never_given(tmp_path, capsys,
                                                                                     variant_vectorised_rgb):
    """``denoise.fit --evaluate`` on 4 frames said ``--switch-frame must be from 1 to 3 ..., got 4``."""
    from denoise.fit import main
    from export import Spec, export

    folder = tmp_path / "seq"
    export(Spec.load(tiny_spec(tmp_path, 4), reference_spp=2), folder, local=True)
    assert main(["--evaluate", str(folder)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{folder}: 4 frames" in err and "got 4" not in err, err
    assert main(["--evaluate", str(folder), "--switch-frame", "4"]) == 2
    assert "--switch-frame must be from 1 to 3" in capsys.readouterr().err


def test_fit_on_a_short_spec_names_the_spec(tmp_path, capsys):
    """The fit's own specs: the shortest is named where the default switch frame does not fit."""
    from denoise.fit import main

    spec = tiny_spec(tmp_path, 3)
    assert main([str(spec), "--work", str(tmp_path / "work"), "--steps", "1", "--out", str(tmp_path / "p.json")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{spec}: 3 frames" in err, err
    assert not (tmp_path / "work").exists()


def test_the_benchmark_with_raw_alone_reports_and_exits_0(tmp_path):
    """``--methods raw`` ran, printed its table and then failed ranking the denoisers
    for the reference check (``min() arg is an empty sequence``)."""
    captured = benchmark(["--quick", "--no-timing", "--work", str(tmp_path / "work"), "--sequences", "dolly_lamps",
                          "--methods", "raw"])
    assert captured.returncode == 0 and "Traceback" not in captured.err, captured.err
    assert "not judged: dolly_lamps: no method besides raw" in captured.out


@pytest.mark.parametrize("inside", ["seq", "seq_reference", "seq/deeper", "a file", "a file/deeper"])
@pytest.mark.parametrize("command", ["denoise.validate", "denoise.fit", "denoise.train", "benchmarks.denoise"])
def test_a_work_folder_inside_an_exports_frames_or_truth_is_one_line(command, inside, tmp_path, capsys):
    """Each command that exports its sequences into --work wrote new sequence folders (and a
    checkpoint) inside a frame folder or a ground truth given as --work. A --work that is a
    file (or lies inside one) was mkdir's "File exists", or an error naming a folder in it."""
    import importlib

    (tmp_path / "a file").write_text("not a folder")
    (tmp_path / "seq").mkdir()
    (tmp_path / "seq" / "sequence.json").write_text("{}")
    (tmp_path / "seq_reference").mkdir()
    (tmp_path / "seq_reference" / "ground_truth.json").write_text("{}")
    before = sorted(tmp_path.rglob("*"))
    work = tmp_path / inside
    argv = {"denoise.validate": [TINY_SPEC, "--work", str(work), "--methods", "asvgf"],
            "denoise.fit": [TINY_SPEC, "--work", str(work), "--steps", "1", "--out", str(tmp_path / "p.json")],
            "denoise.train": [TINY_SPEC, "--work", str(work), "--steps", "1", "--out", str(tmp_path / "w.json"),
                              "--plot", str(tmp_path / "w.png")],
            "benchmarks.denoise": ["--quick", "--no-timing", "--work", str(work), "--sequences", "dolly_lamps"],
            }[command]
    if command.startswith("benchmarks."):  # tests never import benchmarks/
        captured = benchmark(argv)
        code, err = captured.returncode, captured.err
    else:
        code, err = importlib.import_module(command).main(argv), capsys.readouterr().err
    words = "a file" if inside.startswith("a file") else "an input"
    assert code == 2 and err.count("\n") == 1 and f"--work {work}" in err and words in err, err
    assert sorted(tmp_path.rglob("*")) == before
