"""The course's 21 reference images, rendered with its own command lines."""
from __future__ import annotations

import re

import numpy as np
import pytest

from converters.course_scene import load_scene
from helpers import MAX_BAD_FRACTION, bad_fraction, encode, render_layers
from imaging.image_io import read_png
from renderer.cli import main

SCENES = ["scene01_plane", "scene02_cube", "scene03_sphere", "scene04_axes", "scene05_bunny_200",
          "scene06_bunny_1k", "scene07_arch"]
FLAGS = {"scene06_bunny_1k": dict(bounces=4), "scene07_arch": dict(bounces=4, shadows=True)}


def grading_lines(course) -> list[str]:
    """The command lines from the course's README, verbatim."""
    text = (course / "README.md").read_text()
    lines = [line.strip() for line in text.splitlines() if re.match(r"\s*a2 -size", line)]
    assert len(lines) == 7, "the course README should list seven a2 command lines"
    return lines


def test_course_reference_images(variant_llvm_ad_rgb, course, tmp_path, monkeypatch):
    batch = tmp_path / "grading.sh"
    out = tmp_path / "out"
    out.mkdir()
    # outputs into tmp_path, inputs from the course folder, as the course runs them
    lines = [re.sub(r"(-output|-normals) (\S+)", lambda m: f"{m.group(1)} {out / m.group(2)}", line)
             for line in grading_lines(course)]
    lines = [re.sub(r"(-depth \S+ \S+) (\S+)", lambda m: f"{m.group(1)} {out / m.group(2)}", line)
             for line in lines]
    batch.write_text("\n".join(lines) + "\n")
    monkeypatch.chdir(course)
    assert main(["--batch", str(batch), "--variant", variant_llvm_ad_rgb, "--quiet"]) == 0

    worst = {}
    for reference in sorted((course / "sample_out").glob("a0*.png")):
        ours = read_png(out / reference.name)
        worst[reference.name] = bad_fraction(ours, read_png(reference))
    assert len(worst) == 21
    failing = {name: round(f, 5) for name, f in worst.items() if f > MAX_BAD_FRACTION}
    assert not failing, failing


@pytest.mark.slow
@pytest.mark.parametrize("name", SCENES)
def test_scalar_matches_llvm(course, name):
    """scalar_rgb and llvm_ad_rgb give the same images at 200x200 (and the same AOVs)."""
    from conftest import _set

    scene = load_scene(course / "data" / f"{name}.txt")
    options = dict(width=200, height=200, aovs=("depth", "normal", "id"), **FLAGS.get(name, {}))
    layers = {}
    for variant in ("llvm_ad_rgb", "scalar_rgb"):
        _set(variant)
        layers[variant] = render_layers(scene, **options)
    a, b = layers["llvm_ad_rgb"], layers["scalar_rgb"]
    assert bad_fraction(encode(a[""]), encode(b[""])) <= MAX_BAD_FRACTION
    assert bad_fraction(encode((a["normal"] + 1) / 2), encode((b["normal"] + 1) / 2)) <= MAX_BAD_FRACTION
    assert np.mean(np.abs(a["depth"] - b["depth"]) > 1e-4 * np.maximum(1.0, np.abs(a["depth"]))) <= MAX_BAD_FRACTION
    assert np.mean(a["id"] != b["id"]) <= MAX_BAD_FRACTION
