"""render.py from the outside: inputs checked before any work, one line and exit 2
for every refusal, batches that report FILE:LINE and go on, the libLLVM probe,
--help and --png, and a fuzzer over argument lists and batch files."""
from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from validation.stress.scene import scene

ROOT = Path(__file__).resolve().parent.parent
LIBLLVM19 = "/usr/lib/x86_64-linux-gnu/libLLVM-19.so"

#: folders whose scripts are not the project's commands (docs/experiments: scripts for a Python with PyTorch)
NOT_COMMANDS = (".venv", "tests", "docs")


def run(*args: str, cwd: Path, env: dict | None = None, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(ROOT / "render.py"), *args], cwd=cwd, capture_output=True,
                          text=True, env={**os.environ, **(env or {})}, timeout=timeout)


def one_error_line(result: subprocess.CompletedProcess) -> str:
    assert result.returncode == 2, (result.returncode, result.stderr[-2000:])
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("render.py: error: "), result.stderr[-2000:]
    return lines[0]


@pytest.fixture
def scene_file(tmp_path) -> Path:
    path = tmp_path / "s.txt"
    path.write_text(scene())
    return path


def test_help_states_every_option_with_its_default_and_an_example(tmp_path):
    result = run("--help", cwd=tmp_path, timeout=60)
    assert result.returncode == 0 and result.stderr == ""
    text = result.stdout
    assert "-size W H" in text and "(default: 800 800)" in text
    assert "example:" in text and "-input" in text.split("example:")[1]
    from renderer.cli import build_parser

    for action in build_parser()._actions:
        if action.dest not in ("help", "scenes"):
            assert action.help and "default" in action.help, action.dest


def test_limits_are_refused_at_once_with_the_limit_named(tmp_path, scene_file):
    cases = {("-size", "5600", "5600", "-jitter", "-filter"): "4,294,967,295",  # > 2^32 samples
             ("-size", "60000", "60000", "--exr", "a.exr"): "memory",
             ("-size", "8", "8", "-bounces", "1000000000"): "0..1000",
             ("-size", "8", "8", "--spp", "5000000000"): "--spp"}
    for flags, named in cases.items():
        start = time.perf_counter()
        line = one_error_line(run("-input", str(scene_file), "-output", "a.png", *flags, cwd=tmp_path))
        assert named in line, line
        assert time.perf_counter() - start < 30  # found before rendering, not after
    assert not (tmp_path / "a.png").exists() and not (tmp_path / "a.exr").exists()


def test_memory_estimate_against_a_small_machine(scene_file):
    """check_limits with 1 GiB available refuses 4000x4000 with every AOV, accepts 400x400."""
    from converters.render_flags import RenderJob
    from core.errors import LimitError
    from renderer import checks

    big = RenderJob(scene=scene_file, width=4000, height=4000, exr=Path("a.exr"))
    with pytest.raises(LimitError, match="memory"):
        checks.check_limits(big, memory=2**30)
    checks.check_limits(RenderJob(scene=scene_file, width=400, height=400, exr=Path("a.exr")), memory=2**30)
    # the estimate covers what a render really holds: 106 bytes per pixel measured for the beauty alone
    film = checks.render_memory(RenderJob(scene=scene_file, width=1000, height=1000)) - checks.BASELINE_BYTES
    assert film >= 106e6


def test_outputs_are_checked_before_the_variant_is_set(tmp_path, scene_file, monkeypatch):
    """No render starts (nor is the variant even set) when an output cannot be written."""
    import renderer.cli as cli
    import renderer.variants as variants

    def no_work(*args, **kwargs):
        raise AssertionError("work started before the outputs were checked")

    monkeypatch.setattr(variants, "set_variant", no_work)
    monkeypatch.setattr(cli, "set_variant", no_work, raising=False)
    monkeypatch.setattr(cli, "render", no_work, raising=False)
    (tmp_path / "folder.png").mkdir()
    (tmp_path / "notes").write_text("x")
    monkeypatch.chdir(tmp_path)
    bad = [["-output", "a.png", "-normals", "a.png"], ["-output", "a.jpg"], ["-output", "folder.png"],
           ["-output", "notes/a.png"], ["--exr", "a.png"]]
    for outputs in bad:
        assert cli.main(["-input", str(scene_file), "-size", "4", "4", "--quiet", *outputs]) == 2, outputs


def test_an_output_on_a_file_the_render_reads_is_refused(tmp_path, capsys, monkeypatch):
    """The scene file (also through a link or a hard link), a mesh or a cube-map
    face given as an output would be overwritten by the render: refused, and the
    file is unchanged."""
    import shutil

    import renderer.cli as cli

    monkeypatch.chdir(tmp_path)
    shutil.copytree(ROOT / "scenes" / "tex" / "sky", tmp_path / "sky")
    (tmp_path / "m.png").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")  # an OBJ under an image name
    text = scene(background="cubeMap sky", num_objects=4,
                 objects="MaterialIndex 0 Sphere { center 0 0 0 radius 1 } "
                         "MaterialIndex 0 Sphere { center 2 0 0 radius 1 } "
                         "MaterialIndex 0 Sphere { center -2 0 0 radius 1 } "
                         "MaterialIndex 0 TriangleMesh { obj_file m.png }")
    (tmp_path / "in.png").write_text(text)
    (tmp_path / "link.png").symlink_to(tmp_path / "in.png")
    os.link(tmp_path / "in.png", tmp_path / "hard.png")
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    for flags, named in [(["-output", "in.png"], "the scene"), (["-output", "./sub/../in.png"], "the scene"),
                         (["-output", "link.png"], "the scene"), (["-depth", "0", "9", "hard.png"], "the scene"),
                         (["-normals", "m.png"], "m.png"), (["-output", "sky/up.png"], "up.png")]:
        (tmp_path / "sub").mkdir(exist_ok=True)
        assert cli.main(["-input", "in.png", "-size", "4", "4", "--quiet", *flags]) == 2, flags
        line = capsys.readouterr().err.strip()
        assert "\n" not in line and named in line and "reads" in line, (flags, line)
    assert {p: p.read_bytes() for p in before} == before
    # a named scene's own folder is fine when the names differ
    assert cli.main(["-input", "in.png", "-size", "4", "4", "--quiet", "-output", "out.png",
                     "--variant", "scalar_rgb"]) == 0, capsys.readouterr().err


def test_a_repeated_or_empty_single_value_flag_is_refused(tmp_path, scene_file, capsys, monkeypatch):
    """``-output a.png -output b.png`` used to render b.png only, silently."""
    import renderer.cli as cli

    monkeypatch.chdir(tmp_path)
    scene = str(scene_file)
    cases = [(["-input", scene, "-output", "a.png", "-output", "b.png"], "-output"),
             (["-input", scene, "-input", scene, "-output", "a.png"], "-input"),
             (["-input", scene, "-depth", "0", "1", "a.png", "-depth", "0", "2", "b.png"], "-depth"),
             (["-input", scene, "-output", "a.png", "-size", "4", "4", "-size", "8", "8"], "-size"),
             (["-input", scene, "-output", "a.png", "-bounces", "1", "-bounces", "2"], "-bounces"),
             (["-input", scene, "-output", "a.png", "--exr", "a.exr", "--exr", "b.exr"], "--exr"),
             (["--batch", "a.sh", "--batch", "b.sh"], "--batch"),
             (["-input", scene, "-output", "a.png", "--variant", ""], "--variant"),
             (["-input", scene, "-output", ""], "-output")]
    for argv, named in cases:
        assert cli.main(argv) == 2, argv
        line = capsys.readouterr().err.strip()
        assert "\n" not in line and named in line, (argv, line)
    assert not list(tmp_path.glob("*.png"))


def test_entry_point_errors_are_one_line(tmp_path, scene_file):
    assert "/no/such/folder/s.txt" in one_error_line(run("/no/such/folder/s.txt", "-size", "4", "4",
                                                         cwd=tmp_path))
    assert "--variant" in one_error_line(run("-input", str(scene_file), "-output", "a.png", "-size", "4", "4",
                                             "--variant", "llvm_ad_rbg", cwd=tmp_path))
    assert "-size" in one_error_line(run("-input", str(scene_file), "-output", "a.png", "-size", "4",
                                         cwd=tmp_path))
    (tmp_path / "ro.png").write_text("old")
    (tmp_path / "ro.png").chmod(0o444)
    assert "ro.png" in one_error_line(run("-input", str(scene_file), "-output", "ro.png", "-size", "4", "4",
                                          cwd=tmp_path))
    assert (tmp_path / "ro.png").read_text() == "old"


def test_batch_reports_bad_lines_renders_good_ones_and_fails_at_the_end(tmp_path, scene_file):
    batch = tmp_path / "grading.sh"
    batch.write_text("#!/bin/sh\n"
                     "mkdir -p results\n"
                     "echo rendering the course scenes\n"
                     "a2 -size 8 6 -input s.txt \\\n"
                     "   -output results/a.png -normals results/an.png   # a continued line\n"
                     "a2 -size 8 6 -input s.txt -output results/b.png -bounces lots\n"
                     "clear\n"
                     "${BIN} -size 8 6 -input s.txt -depth 0 9 results/c.png\n")
    result = run("--batch", str(batch), "--quiet", cwd=tmp_path)
    assert result.returncode == 2
    errors = result.stderr.strip().splitlines()
    assert f"{batch}:6: " in errors[0] and "-bounces" in errors[0]
    assert f"{batch}:7: expected a course command line" in errors[1] and "'clear'" in errors[1]
    assert len(errors) == 3  # and one summary line
    for name in ("a.png", "an.png", "c.png"):
        assert (tmp_path / "results" / name).is_file(), name
    assert not (tmp_path / "results" / "b.png").exists()
    assert not (tmp_path / "out").exists()  # 'clear' rendered nothing


def test_a_batch_of_only_good_lines_exits_0(tmp_path, scene_file):
    batch = tmp_path / "b.sh"
    batch.write_text("\n# comment\npython3 render.py -input s.txt -size 4 3 -output 'x y.png'\n\n")
    result = run("--batch", str(batch), "--quiet", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "x y.png").is_file()


def test_a_stray_word_in_a_batch_renders_nothing(tmp_path):
    (tmp_path / "b.sh").write_text("clear\n")
    result = run("--batch", "b.sh", cwd=tmp_path)
    assert result.returncode == 2 and "b.sh:1: expected a course command line" in result.stderr
    assert not (tmp_path / "out").exists()


def test_exr_with_png_preview(tmp_path, scene_file):
    result = run("-input", str(scene_file), "-size", "12", "8", "--exr", "a.exr", "--png", "--quiet",
                 cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    from imaging.colour import to_srgb_8bit
    from imaging.image_io import read_exr, read_png

    channels = read_exr(tmp_path / "a.exr")
    beauty = np.stack([channels[c] for c in "RGB"], axis=-1)
    np.testing.assert_array_equal(read_png(tmp_path / "a.png"), to_srgb_8bit(beauty))


# -- the libLLVM probe ---------------------------------------------------------------
@pytest.fixture
def damaged_llvm(tmp_path) -> Path:
    if not os.path.exists(LIBLLVM19):
        pytest.skip(f"no {LIBLLVM19} to damage")
    path = tmp_path / "libLLVM-19.so"
    with open(LIBLLVM19, "rb") as source:
        path.write_bytes(source.read(2_000_000))  # a truncated copy: mapping it gives SIGBUS
    return path


def test_damaged_libllvm_falls_back_to_scalar_with_one_line(tmp_path, damaged_llvm, scene_file):
    env = {"DRJIT_LIBLLVM_PATH": str(damaged_llvm), "XDG_CACHE_HOME": str(tmp_path / "cache")}
    result = run("-input", str(scene_file), "-size", "6", "4", "-output", "a.png", cwd=tmp_path, env=env)
    assert result.returncode == 0, result.stderr[-2000:]
    notes = [line for line in result.stderr.splitlines() if "scalar_rgb" in line]
    assert len(notes) == 1 and "damaged" in notes[0] and str(damaged_llvm) in notes[0]
    assert (tmp_path / "a.png").is_file()


def test_a_garbage_libllvm_in_a_searched_folder_is_passed_over(tmp_path, monkeypatch, damaged_llvm):
    from core import libllvm

    if libllvm.find_libllvm() is None:
        pytest.skip("no working libLLVM to prefer")
    garbage = tmp_path / "libLLVM-99.so"  # newest by name: the one picked without a probe
    garbage.write_bytes(os.urandom(4096))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH", raising=False)
    monkeypatch.setattr(libllvm, "SEARCH", (str(tmp_path / "libLLVM*.so*"), *libllvm.SEARCH))
    library, notes = libllvm.choose_libllvm()
    assert library is not None and Path(library).resolve() != garbage.resolve()
    assert any(str(garbage) in note and "damaged" in note for note in notes)
    assert libllvm.find_libllvm() == library


def test_probe_verdicts_are_cached(tmp_path, monkeypatch, damaged_llvm):
    from core import libllvm

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    first = libllvm.probe_libllvm(str(damaged_llvm))
    assert first is not None and ("SIG" in first or "cannot" in first)

    def no_probe(*args, **kwargs):
        raise AssertionError("probed again")

    monkeypatch.setattr(libllvm.subprocess, "run", no_probe)
    assert libllvm.probe_libllvm(str(damaged_llvm)) == first
    with open(damaged_llvm, "ab") as library:  # another file: probed again
        library.write(b"\0")
    with pytest.raises(AssertionError, match="probed again"):
        libllvm.probe_libllvm(str(damaged_llvm))


# -- the fuzzer ------------------------------------------------------------------------
def test_random_argument_lists_and_batches_keep_the_contract(variant_llvm_ad_rgb):
    from validation.stress.fuzz import fuzz_cli

    assert fuzz_cli(examples=60) == 120


def test_the_contract_check_can_fail():
    from validation.stress.cases_inputs import contract_problems

    assert contract_problems(1, "Traceback (most recent call last):\n  ...\nKeyError: 'x'\n", batch=False)
    assert contract_problems(2, "usage: render.py [-h]\nrender.py: error: bad\n", batch=False)
    assert contract_problems(-11, "", batch=False)
    assert contract_problems(0, "render.py: error: x\n", batch=False)
    assert not contract_problems(2, "render.py: error: x\n", batch=False)
    assert not contract_problems(2, "render.py: error: b:1: x\nrender.py: error: b: 1 bad\n", batch=True)


def test_cli_cases_and_the_fuzzer_can_fail(variant_llvm_ad_rgb, monkeypatch):
    """A case whose command line is fine but expects a refusal fails, so does one
    expecting a file that is not written; the fuzzer stops on an escaping exception."""
    from validation.stress.cases_inputs import SCENE, CliCase
    from validation.stress.fuzz import fuzz_cli

    files = {"s.txt": SCENE}
    assert not CliCase("not an error", ("-input", "s.txt", "-size", "4", "3", "-output", "a.png", "--quiet"), 2,
                       files=files).check()[0]
    assert not CliCase("nothing written", ("-input", "s.txt", "-size", "4", "3", "-output", "a.png", "--quiet"), 0,
                       files=files, written=("b.png",)).check()[0]
    import renderer.checks as checks

    def crash(*args, **kwargs):
        raise KeyError("mirror_by_depth")  # a bug, as a user would meet it

    monkeypatch.setattr(checks, "check_limits", crash)
    with pytest.raises(Exception, match="traceback|escaped|mirror_by_depth"):
        fuzz_cli(examples=5)


def test_a_scene_file_with_a_byte_order_mark_is_read(tmp_path):
    """Windows editors start UTF-8 files with U+FEFF; batch files accepted it, scenes did not."""
    from converters.course_scene import load_scene

    (tmp_path / "s.txt").write_bytes(b"\xef\xbb\xbf" + scene().encode())
    assert len(load_scene(tmp_path / "s.txt").objects) == 3


def test_a_libllvm_that_is_not_a_library_is_named_in_a_whole_sentence(tmp_path):
    """The fallback line used to end mid-sentence ('...("libLLVM.so") could; using scalar_rgb')."""
    garbage = tmp_path / "libLLVM-19.so"
    garbage.write_text("not a library\n")
    (tmp_path / "s.txt").write_text(scene())
    env = {"DRJIT_LIBLLVM_PATH": str(garbage), "XDG_CACHE_HOME": str(tmp_path / "cache")}
    result = run("-input", "s.txt", "-size", "6", "4", "-output", "a.png", cwd=tmp_path, env=env)
    assert result.returncode == 0, result.stderr[-2000:]
    notes = [line for line in result.stderr.splitlines() if "scalar_rgb" in line]
    assert len(notes) == 1, result.stderr
    reason = notes[0].split("Dr.Jit cannot use it (")[1].split(");")[0]
    assert reason.endswith("could not be found"), notes[0]


#: every benchmark command (a module of benchmarks/ with a __main__ guard): one added later is checked too
BENCHMARKS = sorted(p.stem for p in (ROOT / "benchmarks").glob("*.py") if 'if __name__ == "__main__"' in p.read_text())
#: the benchmarks that write their numbers with --json
WITH_JSON = ("crossval", "denoise", "denoise_profile", "error_vs_time", "render_speed", "roofline", "scaleout",
             "stress")


@pytest.mark.parametrize("name", BENCHMARKS)
def test_benchmarks_keep_the_error_contract(name):
    """Every benchmark command: an unknown flag, and a --json that cannot be
    written, are one line and exit 2 before any measurement (some take hours)."""
    import subprocess
    import sys

    def run(*argv):
        finished = subprocess.run([sys.executable, "-m", f"benchmarks.{name}", *argv], cwd=ROOT,
                                  capture_output=True, text=True, timeout=120)
        return finished.returncode, finished.stderr

    code, err = run("--bogus")
    assert code == 2 and err.count("\n") == 1 and "unrecognized arguments: --bogus" in err, err
    if name in WITH_JSON:
        code, err = run("--json", "docs")
        assert code == 2 and err.count("\n") == 1 and "--json docs: a folder" in err, err
        code, err = run("--json", "/proc/no/such.json")
        assert code == 2 and err.count("\n") == 1 and "/proc/no" in err, err


def test_every_entry_point_ends_through_finish():
    """A command ends with ``core.entry.finish`` (stop signals ignored in the
    teardown): ``sys.exit`` after ``run`` left a signal during the interpreter's
    teardown to end the process by the signal, without a word."""
    guard = 'if __name__ == "__main__":'
    missing = []
    for path in sorted(ROOT.rglob("*.py")):
        relative = path.relative_to(ROOT)
        if relative.parts[0] in NOT_COMMANDS or guard not in (text := path.read_text()):
            continue
        last = text.rsplit(guard, 1)[1]
        if "finish(" not in last:
            missing.append(relative.as_posix())
    assert missing == []


@pytest.mark.parametrize("text", ["result_\x00.exr: missing", "out/\x1b[31mred\x1b[0m.mp4: exists", "a\nb\tc"])
def test_an_error_line_shows_control_characters_escaped(text):
    """A NUL from a format spec or an escape sequence in a file name reaches no terminal raw."""
    from core.entry import one_line

    line = one_line(ValueError(text))
    assert line.isprintable() and "\n" not in line
