"""The procedural training scenes (scenes/procedural.py): the same files on every
machine, scenes the converter reads, specs whose motions the scenes have."""
from __future__ import annotations

import pytest

from converters.course_scene import load_scene
from export import Spec
from scenes.procedural import write_sequences

COUNT = 48


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    return write_sequences(tmp_path_factory.mktemp("procedural"), COUNT)


def test_the_same_seed_writes_the_same_files_and_another_seed_others(written, tmp_path):
    again = write_sequences(tmp_path / "again", COUNT)
    for first, second in zip(written, again, strict=True):
        assert first.with_suffix(".txt").read_text() == second.with_suffix(".txt").read_text()
        assert Spec.load(first).as_json() | {"scene": ""} == Spec.load(second).as_json() | {"scene": ""}
    other = write_sequences(tmp_path / "other", 2, seed=2)
    assert other[0].with_suffix(".txt").read_text() != written[0].with_suffix(".txt").read_text()


def test_a_rerun_leaves_the_files_as_they_are(written):
    before = {p: p.stat().st_mtime_ns for p in written}
    write_sequences(written[0].parent, COUNT)
    assert {p: p.stat().st_mtime_ns for p in written} == before


@pytest.mark.parametrize("index", range(COUNT))
def test_every_scene_loads_and_its_sequence_moves_what_it_has(written, index):
    spec = Spec.load(written[index])
    scene = load_scene(written[index].with_suffix(".txt"))
    spec.check_scene(scene, str(written[index]))
    assert 3 <= len(scene.objects) <= 10 and 1 <= len(scene.lights) <= 3
    assert spec.camera or spec.objects or spec.lights
