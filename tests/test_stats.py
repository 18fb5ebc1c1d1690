"""render.py --stats: the integrator traces exactly what the scene and flags need."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from converters.course_scene import load_scene
from converters.description import scene_dict
from converters.render_flags import RenderJob
from renderer.job import render

ROOT = Path(__file__).resolve().parent.parent
OWN = sorted((ROOT / "scenes").glob("*.txt"))
COURSE = ["scene01_plane", "scene02_cube", "scene03_sphere", "scene04_axes", "scene05_bunny_200",
          "scene06_bunny_1k", "scene07_arch"]
FLAGS = [dict(bounces=0, shadows=False), dict(bounces=0, shadows=True), dict(bounces=3, shadows=False)]


def traced(path: Path, **flags):
    job = RenderJob(scene=path, width=48, height=36, stats=True, exr=Path("unused.exr"), **flags)
    return render(job)


def check(path: Path, flags: dict):
    scene = load_scene(path)
    result = traced(path, **flags)
    stats, ids = result.stats, result.layers["id"].astype(int)
    hits, misses = int((ids >= 0).sum()), int((ids < 0).sum())
    assert stats["camera"] == 48 * 36
    assert stats["aovs"] == ["depth", "normal", "position", "albedo", "id"]
    import drjit as dr
    import mitsuba as mi

    if dr.is_jit_v(mi.Float):  # scalar variants launch no kernels (the fallback runs these tests too)
        assert stats["kernels"] >= 1
    lights = len(scene.lights)
    if flags["shadows"]:
        assert stats["shadow"] >= hits * lights  # every hit, at every depth, asks every light
        if flags["bounces"] == 0:
            assert stats["shadow"] == hits * lights
    else:
        assert stats["shadow"] == 0
    reflective = np.array([scene.materials[o.material].reflective for o in scene.objects] + [False])
    mirrors = stats["mirror_by_depth"]
    if flags["bounces"] == 0 or not scene.has_reflective_objects:
        assert sum(mirrors) == 0
    else:
        assert mirrors[0] == int(reflective[ids].sum())  # one mirror ray per reflective camera hit
        assert all(a >= b for a, b in zip(mirrors, mirrors[1:]))
    environment = scene.background.cube_map is not None or any(scene.background.color)
    if not environment:
        assert stats["environment"] == 0 and stats["environment_kind"] is None
    else:
        assert stats["environment_kind"] == ("cube map" if scene.background.cube_map is not None else "colour")
        # every camera miss, plus mirror rays that escape
        assert misses <= stats["environment"] <= misses + sum(mirrors)
        if flags["bounces"] == 0:
            assert stats["environment"] == misses


@pytest.mark.parametrize("flags", FLAGS, ids=["cast", "shadows", "bounces3"])
@pytest.mark.parametrize("path", OWN, ids=lambda p: p.stem)
def test_own_scene_stats(variant_llvm_ad_rgb, path, flags):
    check(path, flags)


@pytest.mark.parametrize("flags", FLAGS, ids=["cast", "shadows", "bounces3"])
@pytest.mark.parametrize("name", COURSE)
def test_course_scene_stats(variant_llvm_ad_rgb, course, name, flags):
    check(course / "data" / f"{name}.txt", flags)


def test_no_aovs_unless_asked(variant_llvm_ad_rgb):
    result = render(RenderJob(scene=OWN[0], width=16, height=12, stats=True, output=Path("x.png")))
    assert result.stats["aovs"] == [] and set(result.layers) == {""}


def test_converter_writes_only_what_the_scene_uses(variant_llvm_ad_rgb, course):
    plain = scene_dict(load_scene(course / "data" / "scene02_cube.txt"))
    assert plain["background"]["type"] == "constant"
    assert [k for k in plain if k.startswith("material_")] == ["material_0"]
    assert "specular_reflectance" not in plain["material_0"]
    assert "aovs" not in plain["integrator"] and "stats" not in plain["integrator"]
    black = scene_dict(load_scene(course / "data" / "scene01_plane.txt"))
    assert "background" not in black  # black background: no emitter at all
    cube = scene_dict(load_scene(course / "data" / "scene06_bunny_1k.txt"))
    assert cube["background"]["type"] == "course_cubemap"


@pytest.mark.slow
def test_scalar_counts_the_same(course):
    from conftest import _set

    counts = []
    for variant in ("llvm_ad_rgb", "scalar_rgb"):
        _set(variant)
        stats = traced(course / "data" / "scene07_arch.txt", bounces=4, shadows=True).stats
        counts.append({k: stats[k] for k in ("camera", "shadow", "environment", "mirror_by_depth")})
    assert counts[0] == counts[1]
