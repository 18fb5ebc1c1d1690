"""Our own scenes, which the course binary never saw, against the NumPy reference."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from helpers import MAX_BAD_FRACTION, bad_fraction, encode, render_layers

from converters.course_scene import load_scene
from imaging.colour import depth_to_grey, normals_to_rgb
from validation.reference_tracer import ReferenceTracer

SCENES = sorted((Path(__file__).resolve().parent.parent / "scenes").glob("*.txt"))
FLAGS = dict(bounces=3, shadows=True)


def test_there_are_own_scenes():
    assert len(SCENES) >= 4


@pytest.mark.parametrize("path", SCENES, ids=lambda p: p.stem)
@pytest.mark.parametrize("size", [(96, 64), (40, 90)], ids=["wide", "tall"])
def test_own_scene_matches_reference(variant_llvm_ad_rgb, path, size):
    scene = load_scene(path)
    width, height = size
    beauty, depth, normal = ReferenceTracer(scene).render(width, height, **FLAGS)
    ours = render_layers(scene, width=width, height=height, aovs=("depth", "normal"), **FLAGS)
    assert ours[""].shape == (height, width, 3)
    assert bad_fraction(encode(ours[""]), encode(beauty)) <= MAX_BAD_FRACTION
    assert bad_fraction(encode(normals_to_rgb(ours["normal"])), encode(normals_to_rgb(normal))) <= MAX_BAD_FRACTION
    assert bad_fraction(encode(depth_to_grey(ours["depth"], 0, 30)), encode(depth_to_grey(depth, 0, 30))) \
        <= MAX_BAD_FRACTION


@pytest.mark.parametrize("bounces, shadows", [(0, False), (1, True), (4, False)])
def test_flags_change_the_image_as_the_reference_does(variant_llvm_ad_rgb, bounces, shadows):
    scene = load_scene(SCENES[0].parent / "mirrors.txt")
    beauty, _, _ = ReferenceTracer(scene).render(64, 48, bounces, shadows)
    ours = render_layers(scene, width=64, height=48, bounces=bounces, shadows=shadows)
    assert bad_fraction(encode(ours[""]), encode(beauty)) <= MAX_BAD_FRACTION


@pytest.mark.parametrize("path", SCENES, ids=lambda p: p.stem)
def test_scalar_matches_llvm_on_own_scenes(path):
    from conftest import _set

    scene = load_scene(path)
    images = []
    for variant in ("llvm_ad_rgb", "scalar_rgb"):
        _set(variant)
        images.append(render_layers(scene, width=36, height=24, aovs=("id",), **FLAGS))
    assert bad_fraction(encode(images[0][""]), encode(images[1][""])) <= MAX_BAD_FRACTION
    assert np.array_equal(images[0]["id"], images[1]["id"])
