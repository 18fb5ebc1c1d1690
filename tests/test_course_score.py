"""python -m course.score: a student's images against the course's sample_out.

The command is run in-process through its ``main`` (the error contract
included); the images are the course's own, copied and altered."""
from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from course import ENVIRONMENT
from course.score import main
from imaging.image_io import read_png, write_image

ROOT = Path(__file__).resolve().parent.parent
#: a few reference images, for the checks that need not read all 21
SUBSET = ("a01.png", "a02n.png", "a03.png", "a05d.png")


def copy_of(folder: Path, target: Path, names=None) -> Path:
    target.mkdir(parents=True, exist_ok=True)
    for path in sorted(folder.glob("*.png")):
        if names is None or path.name in names:
            shutil.copyfile(path, target / path.name)
    return target


def altered(path: Path, pixels: int, by: int = 3) -> None:
    """Adds ``by`` to the red channel of the first ``pixels`` pixels (row by row)."""
    image = read_png(path).astype(int)
    flat = image.reshape(-1, 3)
    flat[:pixels, 0] = np.where(flat[:pixels, 0] + by <= 255, flat[:pixels, 0] + by, flat[:pixels, 0] - by)
    write_image(path, flat.reshape(image.shape).astype(np.uint8))


@pytest.fixture
def subset(course, tmp_path) -> tuple[Path, Path]:
    """(a reference folder of :data:`SUBSET`, a copy of it to score)."""
    reference = copy_of(course / "sample_out", tmp_path / "reference", SUBSET)
    return reference, copy_of(reference, tmp_path / "mine")


def score(capsys, *arguments) -> tuple[int, str, str]:
    status = main([str(a) for a in arguments])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def verdict_line(out: str) -> str:
    return next(line for line in out.splitlines() if "meet the course's bar" in line)


def test_sample_out_itself_meets_the_bar(course, tmp_path, capsys):
    status, out, err = score(capsys, course / "sample_out", "--report", tmp_path / "report.md")
    assert status == 0 and err == ""
    assert verdict_line(out) == "21 of 21 images meet the course's bar (at most 0.5 % of pixels more than 2/255 off)"
    report = (tmp_path / "report.md").read_text()
    assert report.count("| meets |") == 21 and "![yours](report/a07n_yours.png)" in report
    assert not list((tmp_path / "report").glob("*_flip.png"))


def test_one_altered_image_is_reported_and_fails(course, tmp_path, capsys):
    mine = copy_of(course / "sample_out", tmp_path / "mine")
    pixels = read_png(mine / "a03.png").shape[0] * read_png(mine / "a03.png").shape[1]
    altered(mine / "a03.png", int(0.005 * pixels) + 1)  # one pixel over the course's 0.5 %
    status, out, err = score(capsys, mine)
    assert status == 1 and err == ""
    assert verdict_line(out).endswith("20 of 21 images meet the course's bar (at most 0.5 % of pixels more than "
                                      "2/255 off); failing: a03.png")
    assert [line.split(" | ")[0] for line in out.splitlines() if line.endswith("| fails |")] == ["| a03.png"]
    heat_maps = sorted(p.name for p in (mine / "score").glob("*_flip.png"))
    assert heat_maps == ["a03_flip.png"]
    heat_map = read_png(mine / "score" / "a03_flip.png")
    assert heat_map.shape == read_png(mine / "a03.png").shape and heat_map.std() > 0
    report = (mine / "score.md").read_text()
    assert "| a03.png | 3201 (0.500 %) |" in report and report.count("**fails**") == 1
    assert "[![FLIP](score/a03_flip_small.png)](score/a03_flip.png)" in report


def test_the_bar_is_the_courses(subset, capsys):
    """Off by exactly 2/255 everywhere is within the tolerance; 0.5 % of the pixels off by
    3/255 meets the bar, one pixel more fails it."""
    reference, mine = subset
    altered(mine / "a01.png", 800 * 800, by=2)
    altered(mine / "a03.png", 3200)
    status, out, _ = score(capsys, mine, "--reference", reference)
    assert status == 0, out
    assert "| a01.png | 0 | 0.000 % |" in out and "| a03.png | 3200 | 0.500 % |" in out
    altered(mine / "a05d.png", 3201)
    status, out, _ = score(capsys, mine, "--reference", reference)
    assert status == 1 and verdict_line(out).endswith("; failing: a05d.png")


def test_a_missing_image_is_listed_and_fails(subset, capsys):
    reference, mine = subset
    (mine / "a02n.png").unlink()
    status, out, _ = score(capsys, mine, "--reference", reference)
    assert status == 1
    assert verdict_line(out) == ("3 of 4 images meet the course's bar (at most 0.5 % of pixels more than 2/255 off); "
                                 "missing: a02n.png")
    assert "| a02n.png | missing | | | fails |" in out
    assert "| a02n.png | missing | | fails |" in (mine / "score.md").read_text()


def damage(path: Path) -> None:
    path.write_bytes(path.read_bytes()[:200])


@pytest.mark.parametrize("case, expected", [
    ("damaged", r"a03\.png: not a readable PNG \("),
    ("damaged reference", r"reference/a01\.png: not a readable PNG \("),
    ("smaller", r"mine/a03\.png: 400x400 pixels, but .*reference/a03\.png has 800x800"),
    ("no folder", r"nowhere: not a folder"),
    ("no reference", r"--reference .*nothing: not a folder"),
    ("empty reference", r"--reference .*empty: no PNG images to compare with"),
])
def test_bad_inputs_are_one_line_and_exit_2(subset, tmp_path, capsys, case, expected):
    reference, mine = subset
    arguments = [mine, "--reference", reference]
    if case == "damaged":
        damage(mine / "a03.png")
    elif case == "damaged reference":
        damage(reference / "a01.png")
    elif case == "smaller":
        write_image(mine / "a03.png", read_png(mine / "a03.png")[::2, ::2])
    elif case == "no folder":
        arguments[0] = tmp_path / "nowhere"
    elif case == "no reference":
        arguments[2] = tmp_path / "nothing"
    elif case == "empty reference":
        (tmp_path / "empty").mkdir()
        arguments[2] = tmp_path / "empty"
    status, out, err = score(capsys, *arguments)
    assert status == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith("python -m course.score: error: "), err
    assert re.search(expected, err), err


def test_without_the_course_the_default_reference_is_named(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv(ENVIRONMENT, str(tmp_path / "no_course"))
    (tmp_path / "mine").mkdir()
    status, out, err = score(capsys, tmp_path / "mine")
    assert status == 2 and err.count("\n") == 1
    assert f"the course's sample_out is not at {tmp_path / 'no_course' / 'sample_out'}: set $COURSE_ROOT" in err


def test_runs_as_a_module(subset):
    """``python -m course.score`` is the command (stderr empty when it is not a terminal)."""
    reference, mine = subset
    done = subprocess.run([sys.executable, "-m", "course.score", str(mine), "--reference", str(reference)],
                          cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stderr == "", done.stderr
    assert "4 of 4 images meet the course's bar" in done.stdout


@pytest.mark.parametrize("name", ["a01.png", "notes.txt"])
def test_a_report_that_is_not_markdown_is_refused_before_anything_is_written(course, tmp_path, capsys, name):
    """``--report`` onto a scored image would have replaced it with the Markdown."""
    folder = copy_of(course / "sample_out", tmp_path / "mine")
    before = (folder / "a01.png").read_bytes()
    status, _, err = score(capsys, folder, "--reference", course / "sample_out", "--report", folder / name)
    assert status == 2
    assert err.count("\n") == 1 and "--report writes Markdown: name it .md" in err
    assert (folder / "a01.png").read_bytes() == before and not (folder / "a01").exists()


@pytest.mark.parametrize("where", ["r.md", "sub/r.md", "sub/deeper/r.md"])
def test_a_report_never_goes_into_the_reference(course, tmp_path, capsys, where):
    """The report and its images folder, at any depth of --reference: one line, nothing written."""
    names = ["a01.png", "a01n.png"]
    reference = copy_of(course / "sample_out", tmp_path / "ref", names)
    mine = copy_of(course / "sample_out", tmp_path / "mine", names)
    before = sorted(reference.rglob("*"))
    status, _, err = score(capsys, mine, "--reference", reference, "--report", reference / where)
    assert status == 2 and err.count("\n") == 1 and "is inside the input folder --reference" in err, err
    assert sorted(reference.rglob("*")) == before
