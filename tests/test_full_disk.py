"""A full disk under every writer is one line and exit 2, and loses nothing.

A small tmpfs (where mounting works; else a file-size limit) holds the
previous file and is then filled: render.py (PNG, EXR, the --png preview),
``python -m converters``, ``python -m denoise`` (EXR, PNG, MP4) and a
benchmark's ``--json`` must print one ``PROG: error: FILE: no space left on
device`` line, exit 2, leave no temporary file and keep the previous file.
A disk that fills between two frames of ``python -m denoise`` stops it with
the frames before kept complete.
"""
from __future__ import annotations

import numpy as np
import pytest

from core.entry import run
from imaging import image_io
from validation.stress.cases_system import OLD, SHOWCASE, one_error_line, system_cases
from validation.stress.system import ROOT, full_disk, python, run_command, temporary_files

CASES = [case for case in system_cases() if case.name.startswith("full disk")]


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.name)
def test_a_command_on_a_full_disk(case):
    passed, detail = case.check()
    assert passed, detail


def _frames():
    rng = np.random.default_rng(1)
    return [rng.integers(0, 256, (40, 64, 3), np.uint8) for _ in range(6)]


WRITERS = {  # python -m denoise's writers, as it calls them
    "exr": ("result_0.exr", lambda path: image_io.write_exr(path, {"": np.ones((40, 64, 3), np.float32)})),
    "png": ("result_0.png", lambda path: image_io.write_image(path, _frames()[0])),
    "mp4": ("video.mp4", lambda path: image_io.write_video(path, _frames())),
}


@pytest.mark.parametrize("kind", WRITERS)
def test_each_image_writer_on_a_full_disk(kind, capsys):
    name, write = WRITERS[kind]
    with full_disk() as disk:
        if disk.limit is not None:
            pytest.skip("no tmpfs here: the file-size limit applies to subprocesses (the cases above)")
        (disk.path / name).write_bytes(OLD)
        disk.fill()
        assert run("python -m denoise", lambda: write(disk.path / name)) == 2
        assert (disk.path / name).read_bytes() == OLD
        assert temporary_files(disk.path) == []
    err = capsys.readouterr().err
    assert one_error_line(2, err, "python -m denoise", f"{name}: no space left on device") == [], err


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    """A tiny exported sequence, and the size of one denoised frame."""
    folder = tmp_path_factory.mktemp("seq")
    code, _, stderr = run_command(python("-m", "export", ROOT / "scenes/sequences/dolly_lamps.json",
                                         folder / "seq", "--frames", 2, "--size", 32, 18))
    assert code == 0, stderr
    code, _, stderr = run_command(python("-m", "denoise", folder / "seq", folder / "den"))
    assert code == 0, stderr
    return folder / "seq", (folder / "den" / "result_0.exr").stat().st_size


def test_denoise_on_a_full_disk(sequence):
    source, _ = sequence
    with full_disk() as disk:
        target = disk.path / "den"
        target.mkdir()
        (target / "result_0.exr").write_bytes(OLD)
        disk.fill()
        code, _, stderr = run_command(python("-m", "denoise", source, target, "--png"), preexec=disk.limit)
        assert one_error_line(code, stderr, "python -m denoise", disk.expect) == [], stderr
        assert (target / "result_0.exr").read_bytes() == OLD
        assert temporary_files(disk.path) == []


def test_a_disk_that_fills_between_two_frames(sequence):
    """Room for the first result only: the error names the second and what was written, the first is complete."""
    source, frame_bytes = sequence
    with full_disk() as disk:
        if disk.limit is not None:
            pytest.skip("a file-size limit cannot fill between files")
        target = disk.path / "den"
        target.mkdir()
        disk.fill(room=frame_bytes + 1)
        code, _, stderr = run_command(python("-m", "denoise", source, target))
        assert one_error_line(code, stderr, "python -m denoise", "result_1.exr: no space left on device") == [], \
            stderr
        assert f"(the result of frame 0 was written to {target}; none from frame 1 on)" in stderr, stderr
        assert image_io.read_exr_rgb(target / "result_0.exr").shape == (18, 32, 3)
        assert not (target / "result_1.exr").exists()
        assert temporary_files(disk.path) == []


def test_the_xml_converter_keeps_the_previous_xml_and_meshes(tmp_path):
    """Another scene converted onto the first one's XML, the disk filling
    while its meshes are written: the first XML and its meshes stay as they were."""
    with full_disk() as disk:
        code, _, stderr = run_command(python("-m", "converters", SHOWCASE, "-o", disk.path / "s.xml"))
        assert code == 0, stderr
        before = {path: path.read_bytes() for path in disk.path.rglob("*") if path.is_file()}
        assert len(before) > 2  # the XML and its meshes
        disk.fill(room=3 * 4096)  # room for a mesh or two, not for all of them
        code, _, stderr = run_command(python("-m", "converters", ROOT / "scenes" / "lamps.txt", "-o",
                                             disk.path / "s.xml"), preexec=disk.limit)
        assert one_error_line(code, stderr, "python -m converters", disk.expect) == [], stderr
        assert {path: path.read_bytes() for path in before} == before
        assert temporary_files(disk.path) == []
