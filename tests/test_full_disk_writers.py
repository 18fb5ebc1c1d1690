"""A full disk under the export, the scores, the fit and the shared writers.

Each writer meets a small tmpfs (or, without one, a file-size limit) that
is full or nearly so, and must print one ``PROG: error: FILE: ...`` line
naming the user's file (never a staging or temporary one), exit 2, leave
no temporary file and keep the previous file as it was. The export is run
with room for ever more of its files, so that the disk fills during each
kind of write (settings, frames, reference batches and halves, the
manifest); a rerun with room then ends with the bytes of an uninterrupted run.
"""
from __future__ import annotations

import json
import re

import numpy as np
import pytest

from core.entry import run
from imaging.image_io import exr_complete, write_image
from validation.stress.cases_system import OLD, one_error_line
from validation.stress.system import ROOT, full_disk, python, run_command, temporary_files

TINY = {"scene": "lamps", "frames": 2, "size": [32, 18], "spp": 1, "reference_spp": 8, "bounces": 1,
        "camera": {"dolly": 0.5}}
EXPORT = ["--local", "--batch-spp", 2]  # 4 reference batches a frame
#: room (4 KiB pages) left on the tmpfs: each stops the export at another kind of write
ROOMS = (0, 2, 4, 10, 12, 18, 20, 22)
KINDS = {"settings": r"sequence\.json", "frame": r"seq/\w+_\d\.exr", "batch": r"batch_\d\.npy",
         "reference half": r"half_[ab]_\d\.exr", "reference": r"seq_reference/beauty_\d\.exr",
         "manifest": r"dataset\.json"}


def tree(folder):
    """Every file's bytes by relative path, but the manifest (its timings differ from run to run)."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name not in ("dataset.json", "filler")}


def half_written(folder) -> list[str]:
    """Files under their final names that are not complete."""
    found = []
    for path in folder.rglob("*"):
        if path.suffix == ".exr" and not exr_complete(path, 16):
            found.append(path.name)
        elif path.suffix == ".json" and path.name != "filler":
            try:
                json.loads(path.read_text())
            except ValueError:
                found.append(path.name)
    return found


@pytest.fixture(scope="module")
def spec(tmp_path_factory):
    path = tmp_path_factory.mktemp("spec") / "seq.json"
    path.write_text(json.dumps(TINY))
    return path


def test_the_export_on_a_full_disk_resumes_to_the_same_bytes(spec, tmp_path):
    code, _, stderr = run_command(python("-m", "export", spec, tmp_path / "seq", *EXPORT))
    assert code == 0, stderr
    expected = tree(tmp_path)
    named = set()
    for room in ROOMS:
        with full_disk() as disk:
            disk.fill(room=room * 4096)
            argv = python("-m", "export", spec, disk.path / "seq", *EXPORT)
            code, _, stderr = run_command(argv, preexec=disk.limit)
            assert one_error_line(code, stderr, "python -m export", disk.expect) == [], (room, stderr)
            path = stderr.split(": error: ", 1)[1].split(": ")[0]
            assert not re.search(r"/\.[^/]*$", path), (room, stderr)  # the user's file, not a staging one
            named |= {kind for kind, pattern in KINDS.items() if re.search(pattern, path)}
            assert temporary_files(disk.path) == [], room
            assert half_written(disk.path) == [], room
            if disk.mounted:
                (disk.path / "filler").unlink()
            disk.room = 1 << 30
            code, _, stderr = run_command(argv, preexec=disk.limit)
            assert code == 0, (room, stderr)
            assert tree(disk.path) == {k: v for k, v in expected.items()}, room
    if disk.mounted:
        assert named == set(KINDS), named


@pytest.fixture(scope="module")
def denoised(spec, tmp_path_factory):
    """An exported tiny sequence and its denoised results."""
    folder = tmp_path_factory.mktemp("denoised")
    code, _, stderr = run_command(python("-m", "export", spec, folder / "seq", *EXPORT))
    assert code == 0, stderr
    code, _, stderr = run_command(python("-m", "denoise", folder / "seq", folder / "den"))
    assert code == 0, stderr
    return folder


def _on_a_full_disk(argv, previous: str, prog: str, cwd=ROOT, room: int = 0) -> None:
    """``argv`` (``{disk}`` in it: the disk's folder) writes ``previous`` onto a full disk."""
    with full_disk() as disk:
        (disk.path / previous).write_bytes(OLD)
        disk.fill(room=room)
        code, _, stderr = run_command([str(a).replace("{disk}", str(disk.path)) for a in argv], cwd=cwd,
                                      preexec=disk.limit)
        assert one_error_line(code, stderr, prog, disk.expect) == [], stderr
        assert (disk.path / previous).read_bytes() == OLD
        assert temporary_files(disk.path) == []


@pytest.mark.parametrize("flag", ["--json", "--plot"])
def test_denoise_score_on_a_full_disk(denoised, flag):
    name = "s.json" if flag == "--json" else "s.png"
    _on_a_full_disk(python("-m", "denoise.score", denoised / "den", "--reference", denoised / "seq_reference",
                           flag, f"{{disk}}/{name}"), name, "python -m denoise.score")


def test_course_score_on_a_full_disk(tmp_path):
    rng = np.random.default_rng(3)
    for folder in ("ref", "mine"):
        (tmp_path / folder).mkdir()
        write_image(tmp_path / folder / "a01.png", rng.integers(0, 256, (30, 40, 3), np.uint8))
    _on_a_full_disk(python("-m", "course.score", tmp_path / "mine", "--reference", tmp_path / "ref",
                           "--report", "{disk}/score.md"), "score.md", "python -m course.score")


def test_the_fit_keeps_the_previous_parameter_file_on_a_full_disk(spec, tmp_path):
    _on_a_full_disk(python("-m", "denoise.fit", spec, "--work", tmp_path, "--steps", 1, "--switch-frame", 1,
                           "--quiet", "--out", "{disk}/p.json"), "p.json", "python -m denoise.fit")


def _notebook(path):
    import nbformat  # noqa: PLC0415  only this writer's check needs it

    from notebooks.build import write  # noqa: PLC0415  only this writer's check needs it

    write(nbformat.v4.new_notebook(cells=[nbformat.v4.new_markdown_cell("x" * 20000)]), path, "quick")


def write_json(path, data):
    """What benchmarks.records.write_json does (tests run benchmarks only by their commands)."""
    from imaging.image_io import atomic_path  # noqa: PLC0415  only this writer's check needs it

    with atomic_path(path, ".json") as tmp:
        tmp.write_text(json.dumps(data, indent=2) + "\n")


def _json(path):
    write_json(path, {"numbers": list(range(5000))})


def _section(path):
    from core.markdown import replace_section  # noqa: PLC0415  only this writer's check needs it

    replace_section(path, "results", "| a | b |\n" * 3000)


#: The writers every benchmark's --json and --docs and notebooks.build call, by the file they write
WRITERS = {"atomic_path (benchmarks.records.write_json)": ("r.json", _json),
           "core.markdown.replace_section": ("page.md", _section), "notebooks.build.write": ("n.ipynb", _notebook)}


@pytest.mark.parametrize("writer", WRITERS)
def test_each_shared_writer_on_a_full_disk(writer, capsys):
    name, write = WRITERS[writer]
    with full_disk() as disk:
        if disk.limit is not None:
            pytest.skip("no tmpfs here: a file-size limit would stop this process")
        (disk.path / name).write_bytes(OLD)
        disk.fill(room=4096)
        assert run("prog", lambda: write(disk.path / name)) == 2
        assert (disk.path / name).read_bytes() == OLD
        assert temporary_files(disk.path) == []
    err = capsys.readouterr().err
    assert one_error_line(2, err, "prog", f"{disk.path / name}: no space left on device") == [], err


def test_a_folder_where_a_json_file_goes_is_not_called_an_image(tmp_path, capsys):
    """The shared writer names what is in the way: a folder, not 'an image file' (a JSON here)."""
    (tmp_path / "r.json").mkdir()
    assert run("prog", lambda: write_json(tmp_path / "r.json", {})) == 2
    assert capsys.readouterr().err == f"prog: error: {tmp_path / 'r.json'}: is a folder, not a file\n"
