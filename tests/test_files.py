"""Writing files (imaging.image_io.atomic_path): through links, long names,
read-only targets and folders, and SIGTERM while writing."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from core.errors import OutputError
from imaging import image_io
from imaging.image_io import atomic_path, read_png, write_image

ROOT = Path(__file__).resolve().parent.parent
PIXELS = np.arange(4 * 5 * 3, dtype=np.uint8).reshape(4, 5, 3)


def hidden(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def test_writing_through_a_link_replaces_its_target(tmp_path):
    (tmp_path / "real").mkdir()
    target = tmp_path / "real" / "a.png"
    target.write_bytes(b"old")
    link = tmp_path / "a.png"
    link.symlink_to("real/a.png")
    write_image(link, PIXELS)
    assert link.is_symlink() and os.readlink(link) == "real/a.png"
    np.testing.assert_array_equal(read_png(target), PIXELS)
    assert hidden(tmp_path) == [] and hidden(tmp_path / "real") == []


def test_a_chain_of_links_and_a_dangling_link(tmp_path):
    (tmp_path / "b.png").symlink_to("c.png")
    (tmp_path / "a.png").symlink_to("b.png")
    write_image(tmp_path / "a.png", PIXELS)  # c.png does not exist yet: it is created
    assert (tmp_path / "a.png").is_symlink() and (tmp_path / "b.png").is_symlink()
    np.testing.assert_array_equal(read_png(tmp_path / "c.png"), PIXELS)


def test_the_temporary_file_is_made_beside_the_target(tmp_path, monkeypatch):
    (tmp_path / "real").mkdir()
    (tmp_path / "link.exr").symlink_to(tmp_path / "real" / "x.exr")
    with atomic_path(tmp_path / "link.exr", ".exr") as tmp:
        assert tmp.parent == tmp_path / "real"
        tmp.write_bytes(b"data")
    assert (tmp_path / "real" / "x.exr").read_bytes() == b"data"


@pytest.mark.parametrize("name", ["n" * 251 + ".png", "é" * 125 + ".png", "x" * 255])
def test_a_name_of_255_bytes_can_be_written(tmp_path, name):
    assert len(os.fsencode(name)) in (254, 255)
    if name.endswith(".png"):
        write_image(tmp_path / name, PIXELS)
        np.testing.assert_array_equal(read_png(tmp_path / name), PIXELS)
    else:
        with atomic_path(tmp_path / name, ".tmp") as tmp:
            tmp.write_bytes(b"x")
        assert (tmp_path / name).read_bytes() == b"x"
    assert hidden(tmp_path) == []


def test_temporary_names_never_exceed_the_limit():
    for limit in (5, 16, 40, 255):
        for name in ("a.png", "é" * 200 + ".exr", "z" * 300):
            assert len(os.fsencode(image_io._temporary_name(name, ".png", limit))) <= limit


def test_a_read_only_target_is_an_output_error_naming_it(tmp_path):
    target = tmp_path / "a.png"
    target.write_bytes(b"keep me")
    target.chmod(0o444)
    with pytest.raises(OutputError, match="a.png.*read-only"):
        write_image(target, PIXELS)
    assert target.read_bytes() == b"keep me" and hidden(tmp_path) == []


@pytest.mark.skipif(os.geteuid() == 0, reason="root may write into a read-only folder")
def test_a_read_only_folder_is_an_output_error_naming_it(tmp_path):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o555)
    try:
        with pytest.raises(OutputError, match="ro"):
            write_image(folder / "a.png", PIXELS)
    finally:
        folder.chmod(0o755)


def test_a_folder_in_the_way_is_an_output_error(tmp_path):
    (tmp_path / "a.png").mkdir()
    with pytest.raises(OutputError, match="is a folder"):
        write_image(tmp_path / "a.png", PIXELS)
    (tmp_path / "file").write_text("x")
    with pytest.raises(OutputError, match="cannot create folder"):
        write_image(tmp_path / "file" / "a.png", PIXELS)
    with pytest.raises(OutputError, match="unknown image type"):
        write_image(tmp_path / "a.jpq", PIXELS)


def test_a_failed_write_leaves_no_temporary_file(tmp_path):
    with pytest.raises(RuntimeError):
        with atomic_path(tmp_path / "a.exr", ".exr") as tmp:
            tmp.write_bytes(b"half")
            raise RuntimeError("encoder failed")
    assert list(tmp_path.iterdir()) == []


#: render.py with a slow disk: the PNG encoder writes part of the file, then waits
SLOW_WRITE = """
import sys, time
sys.path.insert(0, {root!r})
import PIL.Image
save = PIL.Image.Image.save
def slow_save(self, fp, *args, **kwargs):
    with open(fp, "wb") as partial:
        partial.write(b"\\x89PNG partial")
    print("writing", flush=True)
    time.sleep({pause})
    return save(self, fp, *args, **kwargs)
PIL.Image.Image.save = slow_save
from renderer.cli import main
sys.exit(main(sys.argv[1:]))
"""


def test_sigterm_while_writing_leaves_no_temporary_file(tmp_path, pause=3):
    """A write in flight finishes (files are written in the background) or is
    removed; either way no hidden partial file stays, and the exit is 143."""
    scene = tmp_path / "s.txt"
    from validation.stress.scene import scene as scene_text

    scene.write_text(scene_text())
    out = tmp_path / "out"
    out.mkdir()
    (out / "a.png").write_bytes(b"the previous image")
    script = tmp_path / "slow.py"
    script.write_text(SLOW_WRITE.format(root=str(ROOT), pause=pause))
    process = subprocess.Popen([sys.executable, str(script), "-input", str(scene), "-size", "8", "6",
                                "-output", str(out / "a.png"), "--quiet"], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    try:
        assert process.stdout.readline().strip() == "writing"
        assert len(hidden(out)) == 1  # the partial temporary file
        process.send_signal(signal.SIGTERM)
        _, stderr = process.communicate(timeout=120)
    finally:
        process.kill()
    assert process.returncode == 128 + signal.SIGTERM, stderr
    assert stderr.strip().count("\n") == 0 and "interrupted" in stderr
    assert hidden(out) == []
    # the old image stays until a complete new one replaces it; never a partial one
    data = (out / "a.png").read_bytes()
    assert data == b"the previous image" or data.startswith(b"\x89PNG\r\n")
