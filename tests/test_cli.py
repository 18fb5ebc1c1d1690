"""render.py as users run it: course flags, named scenes, errors, the LLVM fallback."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from course import resolve_scene
from imaging.image_io import read_exr, read_png
from renderer.cli import build_parser, jobs_from_args, main

ROOT = Path(__file__).resolve().parent.parent


def run(*args: str, env: dict | None = None, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(ROOT / "render.py"), *args], cwd=cwd, capture_output=True,
                          text=True, env={**os.environ, **(env or {})}, timeout=300)


def test_course_flags_parse_verbatim(tmp_path):
    args = build_parser().parse_args(["-size", "320", "180", "-input", "x.txt", "-output", "a.png", "-normals",
                                      "n.png", "-depth", "8", "18", "d.png", "-bounces", "4", "-shadows",
                                      "-jitter", "-filter"])
    (job,) = jobs_from_args(args)
    assert (job.width, job.height, job.bounces, job.shadows, job.jitter, job.filter) == (320, 180, 4, True, True, True)
    assert job.depth.near == 8 and job.depth.far == 18 and str(job.depth.path) == "d.png"
    assert job.aovs == ("depth", "normal")
    options = job.options()
    assert (options.width, options.height, options.spp) == (960, 540, 16)


def test_scene_names(course):
    assert resolve_scene("scene06", course / "data").name == "scene06_bunny_1k.txt"
    assert resolve_scene("showcase", course / "data") == ROOT / "scenes" / "showcase.txt"


def test_named_scene_with_exr(variant_llvm_ad_rgb, tmp_path):
    assert main(["showcase", "-size", "64", "48", "--exr", "--out", str(tmp_path), "--quiet"]) == 0
    assert read_png(tmp_path / "showcase.png").shape == (48, 64, 3)
    channels = read_exr(tmp_path / "showcase.exr")
    assert {"R", "G", "B", "depth.Y", "normal.X", "position.Z", "albedo.R", "id.Y"} <= set(channels)
    ids = channels["id.Y"]
    assert set(np.unique(ids)) == {-1, 0, 1, 2, 3, 4}  # sky and the five objects
    assert np.all(np.isfinite(np.stack(list(channels.values()))))


def test_jitter_and_filter_antialias(variant_llvm_ad_rgb, tmp_path):
    images = {}
    for flags in ([], ["-jitter"], ["-filter"]):
        out = tmp_path / f"{len(images)}.png"
        assert main(["-input", str(ROOT / "scenes" / "transforms.txt"), "-size", "60", "40",
                     "-output", str(out), "--quiet", *flags]) == 0
        images[" ".join(flags)] = read_png(out).astype(int)
    plain = images[""]
    for name in ("-jitter", "-filter"):
        assert images[name].shape == plain.shape
        # smoother: the mean gradient is lower, but the image is the same scene
        assert np.abs(np.diff(images[name], axis=1)).mean() < np.abs(np.diff(plain, axis=1)).mean()
        assert np.abs(images[name] - plain).mean() < 12


def test_bad_scene_is_one_line_and_exit_2(tmp_path):
    bad = tmp_path / "bad.txt"
    bad.write_text("PerspectiveCamera {\n  center 0 0 1\n  direction 0 0 -1 up 0 1 0 angle thirty }\n")
    result = run("-input", str(bad), "-size", "8", "8", "-output", str(tmp_path / "x.png"))
    assert result.returncode == 2
    # one line (besides the note that a missing LLVM makes render.py print first)
    assert len([line for line in result.stderr.splitlines() if "using scalar_rgb instead" not in line]) == 1
    assert f"{bad}:3:35: expected a number, found 'thirty'" in result.stderr
    assert not (tmp_path / "x.png").exists()


def test_usage_errors(tmp_path):
    result = run("-input", "x.txt")
    assert result.returncode == 2 and "needs at least one of -output" in result.stderr
    result = run("no_such_scene", "--data", str(tmp_path))
    assert result.returncode == 2 and "no scene 'no_such_scene'" in result.stderr


def test_a_data_folder_that_cannot_hold_the_scene_says_why(tmp_path):
    """--data missing, a file, or a folder without scene files: the message says which."""
    from core.errors import UsageError
    from course import resolve_scene

    (tmp_path / "empty").mkdir()
    (tmp_path / "file.txt").write_text("x")
    for data, why in ((tmp_path / "missing", "missing does not exist; --data chose it"),
                      (tmp_path / "file.txt", "file.txt is a file, not a folder; --data chose it"),
                      (tmp_path / "empty", "empty holds no scene files (*.txt); --data chose it")):
        with pytest.raises(UsageError, match=re.escape(why)):
            resolve_scene("no_such_scene", data)


@pytest.mark.parametrize("flags, message", [
    (["-size", "８", "８"], "argument -size: invalid int value: '８'"),
    (["--spp", "1_000"], "argument --spp: invalid int value: '1_000'"),
    (["-bounces", "٢"], "argument -bounces: invalid int value: '٢'"),
])
def test_numbers_are_ascii_decimal(tmp_path, flags, message):
    """Python's int() also reads 1_000 and other scripts' digits; a course command line has neither."""
    result = run("showcase", "--out", str(tmp_path), *flags)
    assert result.returncode == 2 and message in result.stderr, result.stderr
    assert len([line for line in result.stderr.splitlines() if "using scalar_rgb instead" not in line]) == 1


def test_devices_are_not_scene_or_batch_files(tmp_path):
    """/dev/zero never ends: reading it whole ran the machine out of memory."""
    result = run("-input", "/dev/zero", "-size", "8", "8", "-output", str(tmp_path / "x.png"))
    assert result.returncode == 2 and "scene file /dev/zero: not a regular file" in result.stderr
    result = run("--batch", "/dev/zero")
    assert result.returncode == 2 and "--batch /dev/zero: cannot read it: a device, not a regular file" in result.stderr


def test_falls_back_to_scalar_without_a_usable_llvm(tmp_path):
    old_llvm = "/usr/lib/x86_64-linux-gnu/libLLVM-15.so"
    result = run("-input", str(ROOT / "scenes" / "mirrors.txt"), "-size", "12", "8", "-output",
                 str(tmp_path / "m.png"), env={"DRJIT_LIBLLVM_PATH": old_llvm})
    assert result.returncode == 0, result.stderr
    notes = [line for line in result.stderr.splitlines() if "scalar_rgb" in line]
    assert len(notes) == 1 and "is not LLVM >= 17" in notes[0]
    assert "scalar_rgb" in result.stdout
    assert read_png(tmp_path / "m.png").shape == (8, 12, 3)


@pytest.mark.parametrize("text", ["", "# only a comment\n\n", "mkdir -p results\necho grading\n"],
                         ids=["empty", "comments", "shell lines"])
def test_a_batch_without_command_lines_is_one_line(tmp_path, text):
    batch = tmp_path / "empty.sh"
    batch.write_text(text)
    result = run("--batch", str(batch), cwd=tmp_path)
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2 and len(lines) == 1, result.stderr
    assert "no course command lines" in lines[0] and "bad" not in lines[0]


def test_converter_output_through_a_link_loads(variant_rgb, tmp_path):
    """A link in -o's folder: the cube map's and the meshes' relative paths are
    relative to the folder's real location (Mitsuba, as the system, follows the link)."""
    import shutil

    import mitsuba as mi

    from converters.__main__ import main as convert

    source = tmp_path / "src"  # near the output: a relative path from the link's spelling stays short
    for folder in ("tex", "meshes"):
        shutil.copytree(ROOT / "scenes" / folder, source / folder)
    for name in ("mirrors", "showcase"):
        shutil.copy(ROOT / "scenes" / f"{name}.txt", source)
    real = tmp_path / "real" / "deep" / "er"
    real.mkdir(parents=True)
    (tmp_path / "link").symlink_to(real)
    for name in ("mirrors", "showcase"):
        target = tmp_path / "link" / f"{name}.xml"
        assert convert([str(source / f"{name}.txt"), "-o", str(target), "-size", "8", "6"]) == 0
        for path in (target, real / f"{name}.xml"):  # through the link, and by its real path
            image = np.array(mi.render(mi.load_file(str(path), optimize=False)), np.float32)
            assert image.shape[:2] == (6, 8) and np.isfinite(image).all()


def test_stdout_closed_by_its_reader_is_one_line(tmp_path):
    """``render.py ... | head -0``: one line, exit 2, the image written; no 'Exception ignored' at exit."""
    read, write = os.pipe()
    os.close(read)  # the reader has gone before the first line
    result = subprocess.run([sys.executable, str(ROOT / "render.py"), "-input", str(ROOT / "scenes" / "showcase.txt"),
                             "-size", "8", "6", "-output", str(tmp_path / "a.png")], stdout=write,
                            stderr=subprocess.PIPE, text=True, timeout=300)
    os.close(write)
    assert result.returncode == 2 and result.stderr.splitlines() == [
        "render.py: error: standard output was closed by its reader (broken pipe)"], result.stderr
    assert read_png(tmp_path / "a.png").shape == (6, 8, 3)
