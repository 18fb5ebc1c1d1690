"""Generated files stay fresh; XML loads; image files are written whole or not at all."""
from __future__ import annotations

import filecmp
import re
from pathlib import Path

import mitsuba as mi
import numpy as np
import pytest

from converters.__main__ import main as convert_main
from converters.course_scene import load_scene
from helpers import MAX_BAD_FRACTION, bad_fraction, encode, render_layers
from imaging import image_io
from renderer.scene_flags import read_scene_flags

ROOT = Path(__file__).resolve().parent.parent


def _resolved_xml(path: Path) -> str:
    """XML text with every file name made absolute (they are relative to the XML)."""
    return re.sub(r'(name="filename" value=")([^"]+)"',
                  lambda m: f'{m.group(1)}{(path.parent / m.group(2)).resolve()}"', path.read_text())


def test_scenes_xml_is_fresh(variant_scalar_rgb, tmp_path, monkeypatch):
    """scenes_xml/ is what `python -m converters scenes/*.txt -o scenes_xml` writes."""
    monkeypatch.chdir(ROOT)
    assert convert_main([*map(str, sorted(Path("scenes").glob("*.txt"))), "-o", str(tmp_path)]) == 0
    committed_root = ROOT / "scenes_xml"
    fresh = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*") if p.is_file())
    committed = sorted(p.relative_to(committed_root) for p in committed_root.rglob("*") if p.is_file())
    assert fresh == committed, "run: python -m converters scenes/*.txt -o scenes_xml"
    for name in fresh:
        if name.suffix == ".xml":
            assert _resolved_xml(tmp_path / name).replace(str(tmp_path), str(committed_root)) \
                == _resolved_xml(committed_root / name), name
        else:
            assert filecmp.cmp(tmp_path / name, committed_root / name, shallow=False), name


def test_xml_renders_like_the_dict(variant_llvm_ad_rgb):
    for name in ("showcase", "transforms"):
        scene = load_scene(ROOT / "scenes" / f"{name}.txt")
        flags = read_scene_flags(ROOT / "scenes" / f"{name}.txt")  # the XML carries the scene's header flags
        ours = render_layers(scene, width=800, height=800, **flags)[""]
        xml = np.array(mi.render(mi.load_file(str(ROOT / "scenes_xml" / f"{name}.xml"), optimize=False)))
        assert bad_fraction(encode(ours), encode(xml)) <= MAX_BAD_FRACTION


def test_generated_assets_are_fresh(tmp_path, monkeypatch):
    from scenes import generate_assets

    monkeypatch.setattr(generate_assets, "ROOT", tmp_path)
    generate_assets.main()
    for mesh in ("torus.obj", "gem.obj"):
        assert (tmp_path / "meshes" / mesh).read_text() == (ROOT / "scenes" / "meshes" / mesh).read_text()
    for face in generate_assets.FACES:
        fresh = image_io.read_png(tmp_path / "tex" / "sky" / f"{face}.png")
        assert np.array_equal(fresh, image_io.read_png(ROOT / "scenes" / "tex" / "sky" / f"{face}.png"))


def test_multilayer_exr_round_trip(tmp_path):
    h, w = 5, 7
    layers = {"": np.random.rand(h, w, 3).astype(np.float32), "depth": np.random.rand(h, w).astype(np.float32),
              "normal": np.random.rand(h, w, 3).astype(np.float32), "id": np.full((h, w), -1, np.float32)}
    image_io.write_exr(tmp_path / "x.exr", layers)
    channels = image_io.read_exr(tmp_path / "x.exr")
    assert {"R", "G", "B", "depth.Y", "normal.X", "normal.Y", "normal.Z", "id.Y"} <= set(channels)
    assert np.array_equal(channels["G"], layers[""][..., 1])
    assert np.array_equal(channels["normal.Z"], layers["normal"][..., 2])


def test_failed_write_keeps_the_earlier_file(tmp_path):
    target = tmp_path / "a.png"
    good = np.full((4, 4, 3), 200, np.uint8)
    image_io.write_image(target, good)
    with pytest.raises(TypeError):
        image_io.write_image(target, np.zeros((4, 4, 3), np.float32))
    with pytest.raises(RuntimeError):
        with image_io.atomic_path(target, ".png") as tmp:
            tmp.write_bytes(b"\x89PNG truncated")
            raise RuntimeError("interrupted")
    assert np.array_equal(image_io.read_png(target), good)
    assert [p.name for p in tmp_path.iterdir()] == ["a.png"]  # no temporary files left
