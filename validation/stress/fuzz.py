"""The stress suite's fuzzers over the scene grammar and ``render.py``'s command line.

:func:`fuzz` fuzzes the parser and converter with hypothesis (mutated scenes,
token soup, raw bytes as scene and as OBJ files: only :class:`SceneError`,
with ``file:line:col``, may come out) and :func:`fuzz_cli` the command line.
``python -m benchmarks.stress`` runs them all and reports.
"""
from __future__ import annotations

import os
import re
import tempfile
from pathlib import Path

from converters.course_scene import load_scene, parse_scene
from converters.description import scene_dict
from core.errors import SceneError
from imaging.image_io import CUBE_FACES
from validation.stress.cases_inputs import contract_problems, run_render_cli
from validation.stress.scene import DEFAULTS, LOCATED, scene as base_scene

# -- fuzzing ---------------------------------------------------------------------
VOCABULARY = ["{", "}", "PerspectiveCamera", "Lights", "Background", "Materials", "Group", "Transform",
              "Sphere", "Plane", "Triangle", "TriangleMesh", "Material", "PhongMaterial", "PointLight",
              "DirectionalLight", "MaterialIndex", "numObjects", "numLights", "numMaterials", "center", "radius",
              "normal", "offset", "vertex0", "vertex1", "vertex2", "obj_file", "cubeMap", "color", "ambientLight",
              "diffuseColor", "specularColor", "shininess", "direction", "up", "angle", "position", "falloff",
              "Scale", "UniformScale", "Translate", "XRotate", "YRotate", "ZRotate", "Rotate", "Matrix4f",
              "0", "1", "-1", "2", "0.5", "1e-30", "1e30", "1e400", "nan", "inf", "-inf", "-0", "3",
              "mesh.obj", "sky", "#", "\n", "\x00", "é", "1e", "--1", ".", "0x10"]


def fuzz(examples: int, seed: int = 0) -> int:
    """Runs the three fuzzers; returns how many inputs were tried. Raises on the first escape."""
    from hypothesis import HealthCheck, given, settings, strategies as st  # noqa: PLC0415  hypothesis loads on use: --help and the paths without it stay quick

    count = 0
    folder = Path(tempfile.mkdtemp(prefix="stress-fuzz-"))
    (folder / "mesh.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    for face in CUBE_FACES:
        (folder / "sky").mkdir(exist_ok=True)
        (folder / "sky" / f"{face}.png").write_bytes(b"not a png")
    valid = base_scene(num_objects=4,
                       objects=DEFAULTS["objects"] + " MaterialIndex 0 TriangleMesh { obj_file mesh.obj }")
    valid_tokens = re.findall(r"[{}]|[^\s{}]+", valid)

    def check(text: str) -> None:
        nonlocal count
        count += 1
        try:
            scene_dict(parse_scene(text, folder / "fuzz.txt"))
        except SceneError as error:
            assert LOCATED.match(str(error)), str(error)

    common = settings(max_examples=examples, deadline=None, database=None, derandomize=True,
                      suppress_health_check=list(HealthCheck))

    @common
    @given(st.lists(st.tuples(st.integers(0, len(valid_tokens)), st.sampled_from(["replace", "delete", "insert"]),
                              st.sampled_from(VOCABULARY)), min_size=1, max_size=6))
    def mutated(edits):
        tokens = list(valid_tokens)
        for position, action, token in edits:
            position = min(position, len(tokens) - 1)
            if action == "replace":
                tokens[position] = token
            elif action == "delete" and len(tokens) > 1:
                del tokens[position]
            else:
                tokens.insert(position, token)
        check(" ".join(tokens))

    @common
    @given(st.lists(st.sampled_from(VOCABULARY), max_size=80))
    def soup(tokens):
        check(" ".join(tokens))

    @common
    @given(st.binary(max_size=600), st.booleans())
    def raw(data, as_obj):
        nonlocal count
        count += 1
        target = folder / ("mesh.obj" if as_obj else "fuzz.txt")
        target.write_bytes(data)
        try:
            scene_dict(load_scene(folder / "fuzz.txt") if not as_obj else parse_scene(valid, folder / "fuzz.txt"))
        except SceneError as error:
            assert LOCATED.match(str(error)), str(error)
        finally:
            (folder / "mesh.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")

    mutated()
    soup()
    raw()
    return count


#: Words the command-line fuzzer draws from: every flag, numbers that are fine, odd or absurd,
#: and paths that are fine, missing, duplicated, of unknown format, read-only or through links
CLI_VOCABULARY = ["-input", "-size", "-output", "-normals", "-depth", "-bounces", "-shadows", "-jitter", "-filter",
                  "--exr", "--png", "--spp", "--out", "--stats", "--data", "--variant", "--batch",
                  "0", "1", "2", "3", "7", "-1", "1e3", "nan", "x", "", "1000000000", "4294967296", "300000",
                  "s.txt", "bad.txt", "missing.txt", "missing/s.txt", "showcase", "a.png", "a.png", "b.exr",
                  "c.jpg", "dir", "dir/x.png", "new/y.bmp", "ro.png", "link.png", "notes.txt/x.png", "b.sh",
                  "nope_rgb", "scalar_spectral", "é.png", "-", "--", "-size=4", "empty.sh", "linkdir/x.png",
                  "dangling.png", "-bounces", "1000"]
SHELL_VOCABULARY = ["-h", "--help", "a2", "${BIN}", "python3", "render.py", "clear", "echo", "mkdir", "-p", "cd", "#",
                    "\\", "'", '"', ";", "&&", "|"]


def fuzz_cli(examples: int, seed: int = 0) -> int:
    """Random ``render.py`` argument lists and ``--batch`` files, run in-process
    in a scratch folder: each must end in exit 0, or exit 2 with one
    ``render.py: error:`` line (per bad batch line), never a traceback or another
    exception. Returns how many inputs were tried; raises on the first escape."""
    from hypothesis import HealthCheck, given, settings, strategies as st  # noqa: PLC0415  hypothesis loads on use: --help and the paths without it stay quick


    folder = Path(tempfile.mkdtemp(prefix="stress-cli-"))
    (folder / "s.txt").write_text(base_scene())
    (folder / "bad.txt").write_text("PerspectiveCamera { center 0 0 1 }")
    (folder / "dir").mkdir()
    (folder / "notes.txt").write_text("x")
    (folder / "ro.png").write_text("old")
    (folder / "ro.png").chmod(0o444)
    os.symlink("a.png", folder / "link.png")
    (folder / "b.sh").write_text("a2 -input s.txt -size 4 3 -output batch.png\nclear\n")
    (folder / "empty.sh").write_text("# nothing to render\n")
    (folder / "real" / "deep").mkdir(parents=True)
    os.symlink("real/deep", folder / "linkdir")
    os.symlink("gone/d.png", folder / "dangling.png")
    count = 0

    def check(argv: list[str], batch: bool) -> None:
        nonlocal count
        count += 1
        try:
            code, text = run_render_cli(folder, argv)
        except SystemExit as stop:  # argparse's own exits (none expected: its errors are UsageErrors)
            code, text = stop.code, ""
        problems = contract_problems(code, text, batch or "--batch" in argv)
        assert not problems, f"{argv}: {problems}: {text[-500:]}"

    common = settings(max_examples=examples, deadline=None, database=None, derandomize=True,
                      suppress_health_check=list(HealthCheck))

    @common
    @given(st.lists(st.sampled_from(CLI_VOCABULARY), max_size=10))
    def arguments(words):
        # a small default size first, so that what renders renders fast; later words may override it
        check(["-size", "6", "4", "--quiet", *words], batch=False)

    @common
    @given(st.lists(st.lists(st.sampled_from(CLI_VOCABULARY + SHELL_VOCABULARY), max_size=8), min_size=1, max_size=4))
    def batches(lines):
        text = "\n".join(" ".join(["-size", "5", "3", *words] if words and words[0] == "-input" else words)
                         for words in lines)
        (folder / "fuzz.sh").write_text(text + "\n")
        check(["--batch", "fuzz.sh", "--quiet"], batch=True)

    arguments()
    batches()
    return count
