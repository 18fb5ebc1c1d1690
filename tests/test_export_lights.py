"""Lights that change in sequence specs: a point light moves, a directional
light turns, a colour scales, over the sequence or between two frames; and
the specs that ask for something a light cannot do are refused before any work."""
from __future__ import annotations

import json

import numpy as np
import pytest
from test_export import BATCH_SPP, TINY, rgb

from core.errors import SpecError


def course_scene(name: str):
    from course import data_dir, resolve_scene
    from export.tasks import course_scene

    return course_scene(str(resolve_scene(name, data_dir(None)).resolve()))


def lights_at(scene_name: str, lights: dict, frame: int, frames: int = 8):
    from export.animation import animate
    from export.spec import Spec

    spec = Spec.from_dict({"scene": scene_name, "frames": frames, "lights": lights})
    return animate(course_scene(scene_name), spec, frame / (frames - 1)).lights


def test_point_light_moves_linearly_over_the_sequence():
    start = np.asarray(course_scene("lamps").lights[1].position)
    for frame in range(8):
        moved = lights_at("lamps", {"1": {"translate": [7, 0, -3.5]}}, frame)
        assert np.allclose(moved[1].position, start + np.asarray([7, 0, -3.5]) * frame / 7, atol=1e-12)
        assert moved[0] == course_scene("lamps").lights[0]  # the others stay


def test_switch_between_two_frames_is_one_step():
    colour = np.asarray(course_scene("lamps").lights[0].color)
    factors = [np.asarray(lights_at("lamps", {"0": {"scale": 0.2, "frames": [5, 6]}}, f)[0].color) / colour
               for f in range(8)]
    assert np.allclose(factors, [[1] * 3] * 6 + [[0.2] * 3] * 2, atol=1e-12)
    # over frames 2..6: a quarter of the way per frame
    halfway = lights_at("lamps", {"0": {"scale": 0.2, "frames": [2, 6]}}, 4)[0].color
    assert np.allclose(np.asarray(halfway) / colour, 0.6, atol=1e-12)


def test_directional_light_turns_about_its_axis():
    from converters import transforms

    direction = np.asarray(course_scene("transforms").lights[0].direction)
    turned = lights_at("transforms", {"0": {"rotate": {"axis": [0, 1, 0], "degrees": 90}}}, 7)[0].direction
    assert np.allclose(turned, transforms.rotate_y(90)[:3, :3] @ direction, atol=1e-12)
    assert not np.allclose(turned, direction)
    halfway = lights_at("transforms", {"0": {"rotate": {"axis": [0, 1, 0], "degrees": 90}}}, 3, frames=7)[0].direction
    assert np.allclose(halfway, transforms.rotate_y(45)[:3, :3] @ direction, atol=1e-12)


def test_a_switched_off_light_renders_dark(tmp_path):
    """End to end: every lamp scaled to 0 on the last frame leaves it black
    (the path tracer has no ambient term), the first frame lit."""
    from export import Spec, export, reference_folder
    from renderer import variants

    variants.set_variant(None, quiet=True)  # llvm_ad_rgb where usable
    off = {str(k): {"scale": 0} for k in range(3)}
    target = tmp_path / "seq"
    export(Spec.from_dict(dict(TINY, lights=off)), target, batch_spp=BATCH_SPP)
    for folder in (target, reference_folder(target)):
        assert rgb(folder / "beauty_0.exr").max() > 0.01
        assert rgb(folder / "beauty_1.exr").max() == 0


def test_specs_without_lights_keep_their_seeds():
    """``lights`` is left out of the recorded spec when empty: the folders made
    before lights could change keep their key (and so their bytes)."""
    from export import Spec

    assert "lights" not in Spec.from_dict(dict(TINY)).as_json()
    assert Spec.from_dict(dict(TINY, lights={"0": {"scale": 2}})).as_json()["lights"] == {"0": {"scale": 2}}


@pytest.mark.parametrize("lights, message", [
    ([], "lights: expected an object"),
    ({"x": {}}, "lights.x: expected a light index"),
    ({"0": {"dim": 1}}, 'lights.0: unknown keys "dim"'),
    ({"0": {"translate": [1, 0]}}, "lights.0.translate: expected [x, y, z]"),
    ({"0": {"scale": -1}}, "lights.0.scale: expected a factor >= 0"),
    ({"0": {"scale": "half"}}, "lights.0.scale: expected a finite number"),
    ({"0": {"rotate": {"axis": [0, 0, 0], "degrees": 3}}}, "lights.0.rotate.axis: expected an axis of length"),
    ({"0": {"rotate": {"axis": [1e-320, 0, 0], "degrees": 3}}}, "lights.0.rotate.axis: expected an axis of length"),
    ({"0": {"rotate": {"axis": [1e-170, 0, 0], "degrees": 3}}}, "lights.0.rotate.axis: expected an axis of length"),
    ({"0": {"rotate": {"degrees": 3}}}, "lights.0.rotate: expected \"axis\" and \"degrees\""),
    ({"0": {"scale": 0.2, "frames": [5]}}, "lights.0.frames: expected [first, last]"),
    ({"0": {"scale": 0.2, "frames": [1, 2]}}, "lights.0.frames[1]: expected 0..1, found 2"),
    ({"0": {"scale": 0.2, "frames": [1, 1]}}, "lights.0.frames: expected a first frame before the last"),
    ({"0": {"scale": 0.2, "frames": [0.5, 1]}}, "lights.0.frames[0]: expected an integer"),
    ({"0": {"scale": 0.5}, "00": {"scale": 2}}, "lights.00: expected a light index"),  # light 0 named twice
    ({"0": {}}, "lights.0: changes nothing"),
    ({"0": {"frames": [0, 1]}}, "lights.0: changes nothing"),
    ({"0": {"translate": [1e308, 0, 0]}}, "lights.0.translate[0]: expected a finite number of magnitude at most"),
])
def test_bad_light_changes_are_refused(lights, message):
    from export import Spec

    with pytest.raises(SpecError, match=message.replace("[", r"\[").replace("]", r"\]")):
        Spec.from_dict(dict(TINY, lights=lights), "spec.json")


@pytest.mark.parametrize("scene, lights, message", [
    ("lamps", {"3": {"scale": 0.5}}, "lights.3: light 3 does not exist (the scene has 3: 0..2)"),
    ("transforms", {"0": {"translate": [1, 0, 0]}}, "lights.0.translate: light 0 is a directional light"),
    ("lamps", {"1": {"rotate": {"axis": [0, 1, 0], "degrees": 9}}}, "lights.1.rotate: light 1 is a point light"),
])
def test_lights_the_scene_lacks_are_refused_before_anything_is_written(tmp_path, capsys, scene, lights, message):
    from export import main

    spec = tmp_path / "spec.json"
    spec.write_text(json.dumps(dict(TINY, scene=scene, objects={}, lights=lights)))
    assert main([str(spec), str(tmp_path / "out"), "--local"]) == 2
    err = capsys.readouterr().err
    # the spec named by its file, as every other spec error names it
    assert err.count("\n") == 1 and err.startswith(f"python -m export: error: {spec}: ") and message in err, err
    assert not (tmp_path / "out").exists()


def test_a_scene_the_spec_names_wrongly_is_refused_naming_the_spec(tmp_path, capsys):
    from export import main

    spec = tmp_path / "spec.json"
    spec.write_text(json.dumps(dict(TINY, scene="no_such_scene")))
    assert main([str(spec), str(tmp_path / "out"), "--local"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"python -m export: error: {spec}: scene: no scene "), err
