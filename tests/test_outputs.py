"""Generated files stay fresh; XML loads; image files are written whole or not at all."""
from __future__ import annotations

import re
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import mitsuba as mi
import numpy as np
import pytest
from helpers import MAX_BAD_FRACTION, bad_fraction, encode, render_layers

from converters.__main__ import main as convert_main
from converters.course_scene import load_scene
from converters.scene_flags import read_scene_flags
from imaging import image_io

ROOT = Path(__file__).resolve().parent.parent


#: relative tolerance for numbers in generated files: they come from float64
#: arithmetic whose last bits differ between CPUs (SIMD widths, libm), e.g.
#: ray_epsilon 0.01660695910169501 vs 0.016606959101695015, and some are
#: written with 9 significant digits (a last-digit flip is ~3e-9); a real
#: change (a wrong transform, a moved light) is far larger
RELATIVE = 1e-6
RELATIVE_F32 = 1e-6
_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


def _close(a: list[float], b: list[float], relative: float) -> bool:
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return a.shape == b.shape and bool(np.all(np.abs(a - b) <= relative * np.maximum(np.abs(a), np.abs(b))
                                              + 1e-300))


def _xml_differences(fresh: Path, committed: Path) -> list[str]:
    """Where two scene XMLs differ, comparing numbers within :data:`RELATIVE` and
    file names once made absolute (they are relative to each XML)."""
    differences = []

    def walk(a, b, where):
        if a.tag != b.tag or set(a.attrib) != set(b.attrib) or len(a) != len(b):
            differences.append(f"{where}: <{a.tag} {a.attrib}> vs <{b.tag} {b.attrib}>")
            return
        for key, value in a.attrib.items():
            other = b.attrib[key]
            if a.attrib.get("name") in ("filename", "folder") and key == "value":
                value = str((fresh.parent / value).resolve()).replace(str(fresh.parent), str(committed.parent))
                other = str((committed.parent / other).resolve())
                if value != other:
                    differences.append(f"{where}/{a.tag}[filename]: {value} vs {other}")
                continue
            numbers_a, numbers_b = _NUMBER.findall(value), _NUMBER.findall(other)
            if _NUMBER.sub("#", value) != _NUMBER.sub("#", other) or not _close(
                    [float(x) for x in numbers_a], [float(x) for x in numbers_b], RELATIVE):
                differences.append(f"{where}/{a.tag}[{key}]: {value!r} vs {other!r}")
        for k, (child_a, child_b) in enumerate(zip(a, b)):
            walk(child_a, child_b, f"{where}/{a.tag}[{k}]")

    walk(ElementTree.parse(fresh).getroot(), ElementTree.parse(committed).getroot(), fresh.name)
    return differences


def _ply_differences(fresh: Path, committed: Path) -> list[str]:
    """Headers and integer data equal, float32 vertex data within :data:`RELATIVE_F32`."""
    a, b = fresh.read_bytes(), committed.read_bytes()
    marker = b"end_header\n"
    header_a, body_a = a.split(marker, 1)
    header_b, body_b = b.split(marker, 1)
    if header_a != header_b or len(body_a) != len(body_b):
        return [f"{fresh.name}: header or size differs"]
    lines = header_a.decode().splitlines()
    vertices = int(next(line.split()[2] for line in lines if line.startswith("element vertex")))
    floats = vertices * sum(1 for line in lines if line.startswith("property float"))
    vertex_a, vertex_b = (np.frombuffer(body[: 4 * floats], "<f4") for body in (body_a, body_b))
    if not _close(vertex_a, vertex_b, RELATIVE_F32) or body_a[4 * floats:] != body_b[4 * floats:]:
        return [f"{fresh.name}: vertex or face data differs"]
    return []


def test_scenes_xml_is_fresh(variant_scalar_rgb, tmp_path, monkeypatch):
    """scenes_xml/ is what `python -m converters scenes/*.txt -o scenes_xml` writes (up to
    the last bits of numbers, which differ between CPUs)."""
    monkeypatch.chdir(ROOT)
    assert convert_main([*map(str, sorted(Path("scenes").glob("*.txt"))), "-o", str(tmp_path)]) == 0
    committed_root = ROOT / "scenes_xml"
    fresh = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*") if p.is_file())
    committed = sorted(p.relative_to(committed_root) for p in committed_root.rglob("*") if p.is_file())
    assert fresh == committed, "run: python -m converters scenes/*.txt -o scenes_xml"
    differences = []
    for name in fresh:
        compare = _xml_differences if name.suffix == ".xml" else _ply_differences
        differences += compare(tmp_path / name, committed_root / name)
    assert not differences, ("run: python -m converters scenes/*.txt -o scenes_xml", differences[:5])


def test_freshness_check_ignores_last_bits_but_not_changes(tmp_path):
    """The tolerant comparison: another CPU's last digit passes, a changed number,
    attribute or vertex fails."""
    committed = ROOT / "scenes_xml" / "lamps.xml"
    text = committed.read_text()
    values = re.search(r'name="ray_epsilons" value="([^"]+)"', text).group(1)
    value = values.split(",")[0]
    for replacement, same in ((f"{float(value) * (1 + 3e-9):.9g}", True), (repr(float(value) * 1.001), False)):
        fresh = tmp_path / "lamps.xml"
        fresh.write_text(text.replace(f'value="{values}"', f'value="{values.replace(value, replacement, 1)}"'))
        assert (not _xml_differences(fresh, committed)) == same, replacement
    fresh.write_text(text.replace('name="ray_epsilons"', 'name="ray_epsilons2"'))
    assert _xml_differences(fresh, committed)
    ply = next((ROOT / "scenes_xml").rglob("*.ply"))
    data = bytearray(ply.read_bytes())
    start = data.index(b"end_header\n") + len(b"end_header\n")
    (tmp_path / ply.name).write_bytes(bytes(data))
    assert not _ply_differences(tmp_path / ply.name, ply)
    data[start:start + 4] = np.float32(np.frombuffer(data[start:start + 4], "<f4")[0] + 0.5).tobytes()
    (tmp_path / ply.name).write_bytes(bytes(data))
    assert _ply_differences(tmp_path / ply.name, ply)


def test_xml_renders_like_the_dict(variant_llvm_ad_rgb):
    from conftest import SCALAR_FALLBACK

    from converters.description import RenderOptions, scene_dict

    for name in ("showcase", "transforms"):
        scene = load_scene(ROOT / "scenes" / f"{name}.txt")
        flags = read_scene_flags(ROOT / "scenes" / f"{name}.txt")  # the XML carries the scene's header flags
        xml_scene = mi.load_file(str(ROOT / "scenes_xml" / f"{name}.xml"), optimize=False)
        if SCALAR_FALLBACK:  # one Python call per ray: the XML's scene through a small camera
            ours = render_layers(scene, width=48, height=48, **flags)[""]
            camera = mi.load_dict(scene_dict(scene, RenderOptions(width=48, height=48))["sensor"])
            xml = np.array(mi.render(xml_scene, sensor=camera))
        else:
            ours = render_layers(scene, width=800, height=800, **flags)[""]
            xml = np.array(mi.render(xml_scene))
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


def test_video_of_odd_size_is_padded_not_resampled(tmp_path, capfd):
    """H.264 wants even sizes: a 5x3 frame becomes 6x4 by repeating its last
    column and row (no FFmpeg resampling, no warning on stderr)."""
    import imageio.v2 as imageio

    from imaging.image_io import write_video

    frame = np.zeros((3, 5, 3), np.uint8)
    frame[:, 4] = 255  # the last column white: it must stay at the right edge, twice
    write_video(tmp_path / "odd.mp4", [frame, frame], fps=2)
    assert "WARNING" not in capfd.readouterr().err
    frames = imageio.mimread(tmp_path / "odd.mp4")
    assert len(frames) == 2 and frames[0].shape == (4, 6, 3)
    assert frames[0][:, 4:].mean() > 200 and frames[0][:, :3].mean() < 60
