"""A file's name echoed on stdout is one printable line: a newline, an escape sequence or a byte
that is not UTF-8 in a path the user chose is shown escaped (``\\n``, ``\\x1b``, ``\\xff``), as the
error lines already do, never sent to the terminal raw (where it splits a line a script reads,
or recolours and moves the cursor)."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from core.entry import printable

ROOT = Path(__file__).resolve().parent.parent
#: a name with a newline, an escape sequence and a byte that is not UTF-8
ODD = os.fsdecode(b"x\ny\x1b[31m\xff")
SHOWN = "x\\ny\\x1b[31m\\xff"


def test_printable_escapes_what_the_terminal_would_act_on():
    assert printable(Path("/a") / ODD) == f"/a/{SHOWN}"
    assert printable("plain name, with spaces and \u00e4") == "plain name, with spaces and \u00e4"
    assert printable("tab\there\u2028") == "tab\\there\\u2028"


def frames(folder: Path) -> Path:
    from export.frames import FrameData, write_frame

    rgb = np.full((4, 6, 3), 0.5, np.float32)
    for index in range(2):
        write_frame(folder, index, FrameData(rgb, rgb, rgb, rgb[..., 0] + 1, np.zeros((4, 6), np.int32),
                                             [np.eye(4)], np.eye(4), np.eye(4)))
    return folder


def run_course_score(tmp_path: Path) -> list[str]:
    from course.score import main

    for folder in ("mine", "ref"):
        (tmp_path / folder).mkdir()
        Image.fromarray(np.zeros((4, 6, 3), np.uint8)).save(tmp_path / folder / f"a{ODD}.png")
    assert main([str(tmp_path / "mine"), "--reference", str(tmp_path / "ref"), "--report",
                 str(tmp_path / f"{ODD}.md")]) == 0
    return [f"| a{SHOWN}.png | 0 |", f"report: {tmp_path}/{SHOWN}.md"]


def run_converters(tmp_path: Path) -> list[str]:
    from converters.__main__ import main

    assert main([str(ROOT / "scenes" / "mirrors.txt"), "-o", str(tmp_path / ODD / "mirrors.xml")]) == 0
    return [f"{tmp_path}/{SHOWN}/mirrors.xml"]


def run_export(tmp_path: Path) -> list[str]:
    from export.cli import main

    spec = tmp_path / "tiny.json"
    spec.write_text(json.dumps({"scene": "mirrors", "frames": 1, "size": [8, 6], "spp": 1, "reference_spp": 2}))
    assert main([str(spec), str(tmp_path / ODD), "--local"]) == 0
    return [f"rendered into {tmp_path}/{SHOWN} (ground truth in {tmp_path}/{SHOWN}_reference)",
            f"manifest: {tmp_path}/{SHOWN}/dataset.json"]


def run_denoise(tmp_path: Path) -> list[str]:
    from denoise.__main__ import main

    assert main([str(frames(tmp_path / "seq")), str(tmp_path / ODD), "--method", "svgf"]) == 0
    return [f"2 frames -> {tmp_path}/{SHOWN}"]


COMMANDS = {"course.score": run_course_score, "converters": run_converters, "export": run_export,
            "denoise": run_denoise}


@pytest.mark.parametrize("command", COMMANDS)
def test_paths_on_stdout_are_shown_escaped(variant_llvm_ad_rgb, tmp_path, capsys, command):
    expected = COMMANDS[command](tmp_path)
    out = capsys.readouterr().out
    for line in out.splitlines():
        assert line.isprintable(), repr(line)
    for words in expected:
        assert words in out, out


def test_render_py_shows_its_output_path_escaped(tmp_path):
    """render.py's line a scene (through its own process: the line is the progress reporter's)."""
    target = os.fsencode(tmp_path / f"{ODD}.png")
    done = subprocess.run([sys.executable, b"render.py", b"scene03", b"-size", b"8", b"8", b"-output", target,
                           b"--variant", b"scalar_rgb"], cwd=ROOT, capture_output=True, timeout=120)
    assert done.returncode == 0 and done.stderr == b"", done.stderr
    out = done.stdout.decode()
    assert out.count("\n") == 1 and out.rstrip("\n").isprintable(), out
    assert out.rstrip("\n").endswith(f"-> {tmp_path}/{SHOWN}.png")


@pytest.mark.parametrize("name", ["x\ny", "x\x1b[31m", os.fsdecode(b"x\xff")])
def test_the_converter_refuses_an_xml_name_that_xml_cannot_hold(tmp_path, capsys, name):
    """Its meshes folder is named after it inside the XML: a newline there is read back as a space,
    a byte that is not UTF-8 cannot be written (it was a UnicodeEncodeError traceback)."""
    from converters.__main__ import main

    assert main([str(ROOT / "scenes" / "mirrors.txt"), "-o", str(tmp_path / f"{name}.xml")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "an XML file cannot hold a control character" in err, err
    assert err.rstrip("\n").isprintable() and list(tmp_path.iterdir()) == []
