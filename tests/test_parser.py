"""The course scene format: every token, the transform semantics, one-line errors."""
from __future__ import annotations

import numpy as np
import pytest

from converters import transforms
from converters.course_scene import load_scene, parse_scene
from converters.model import DirectionalLight, Plane, PointLight, Sphere, Triangle, TriangleMesh
from converters.obj import read_obj
from core.errors import SceneError

HEADER = """
PerspectiveCamera { center 0 0 10 direction 0 0 -1 up 0 1 0 angle 30 }
Lights { numLights 1 DirectionalLight { direction 0 -1 0 color 1 1 1 } }
Materials { numMaterials 2 Material { diffuseColor 1 0 0 } PhongMaterial { specularColor 1 1 1 shininess 20} }
"""


def parse(body: str, path="test.txt"):
    return parse_scene(HEADER + body, path)


def test_course_scenes_parse(course):
    expected = {"scene01_plane": (6, 1, 4), "scene02_cube": (1, 1, 1), "scene03_sphere": (1, 1, 1),
                "scene04_axes": (4, 1, 4), "scene05_bunny_200": (1, 2, 1), "scene06_bunny_1k": (2, 1, 1),
                "scene07_arch": (4, 2, 4)}
    for name, (objects, lights, materials) in expected.items():
        scene = load_scene(course / "data" / f"{name}.txt")
        assert (len(scene.objects), len(scene.lights), len(scene.materials)) == (objects, lights, materials)
    arch = load_scene(course / "data" / "scene07_arch.txt")
    assert isinstance(arch.lights[1], PointLight) and arch.lights[1].falloff == 0.7
    assert arch.background.cube_map == course / "data" / "tex" / "church"
    bunny = load_scene(course / "data" / "scene06_bunny_1k.txt").objects[0]
    assert isinstance(bunny, TriangleMesh) and bunny.faces.shape[1] == 3 and len(bunny.positions) > 400


def test_first_listed_transform_is_applied_last():
    scene = parse("Group { numObjects 1 MaterialIndex 0 Transform { Translate 1 0 0 Scale 2 2 2 "
                  "Sphere { center 1 0 0 radius 1 } } }")
    m = scene.objects[0].to_world
    # scale first (1 -> 2), then translate (2 -> 3)
    assert np.allclose(m @ [1, 0, 0, 1], [3, 0, 0, 1])


def test_every_transform_kind_matches_its_matrix():
    scene = parse("Group { numObjects 1 MaterialIndex 0 Transform { XRotate 10 YRotate 20 ZRotate 30 "
                  "Rotate { 1 1 0 40 } UniformScale 2 Scale 1 2 3 Translate 4 5 6 "
                  "Sphere { center 0 0 0 radius 1 } } }")
    expected = (transforms.rotate_x(10) @ transforms.rotate_y(20) @ transforms.rotate_z(30)
                @ transforms.rotate((1, 1, 0), 40) @ transforms.uniform_scale(2)
                @ transforms.scale((1, 2, 3)) @ transforms.translate((4, 5, 6)))
    assert np.allclose(scene.objects[0].to_world, expected)
    # right-handed rotations
    assert np.allclose(transforms.rotate_z(90) @ [1, 0, 0, 1], [0, 1, 0, 1])
    assert np.allclose(transforms.rotate_x(90) @ [0, 1, 0, 1], [0, 0, 1, 1])
    assert np.allclose(transforms.rotate_y(90) @ [0, 0, 1, 1], [1, 0, 0, 1])


def test_matrix4f_is_read_by_columns_and_multiplies_on_the_left():
    scene = parse("Group { numObjects 1 MaterialIndex 0 Transform { Scale 2 2 2 "
                  "Matrix4f { 1 0 0 0  0 1 0 0  0 0 1 0  5 6 7 1 } Sphere { center 0 0 0 radius 1 } } }")
    m = scene.objects[0].to_world
    # the 4th column is the translation; it applies after the scale listed before it
    assert np.allclose(m @ [1, 1, 1, 1], [7, 8, 9, 1])


def test_nested_transforms_compose_and_material_index_ignores_groups():
    scene = parse("""Group { numObjects 3
        MaterialIndex 0
        Group { numObjects 1 MaterialIndex 1 Triangle { vertex0 0 0 0 vertex1 1 0 0 vertex2 0 1 0 } }
        Plane { normal 0 1 0 offset -1 }
        Transform { Translate 1 0 0 Transform { Translate 0 2 0 Sphere { center 0 0 0 radius 1 } } } }""")
    assert [type(o) for o in scene.objects] == [Triangle, Plane, Sphere]
    assert [o.material for o in scene.objects] == [1, 1, 1]
    assert np.allclose(scene.objects[2].to_world[:3, 3], [1, 2, 0])


def test_defaults_and_attached_braces():
    scene = parse_scene(HEADER + "Background { color 0.1 0.2 0.3 }", "x.txt")
    assert scene.materials[0].specular == (0, 0, 0) and scene.materials[1].shininess == 20
    assert scene.materials[1].diffuse == (1, 1, 1)
    assert scene.background.ambient == (0, 0, 0) and scene.background.cube_map is None
    assert isinstance(scene.lights[0], DirectionalLight)


@pytest.mark.parametrize("body, where, expected", [
    ("Group { numObjects 1 MaterialIndex 5 Sphere { center 0 0 0 radius 1 } }", "5:", "material index in 0..1"),
    ("Group { numObjects 2 MaterialIndex 0 Sphere { center 0 0 0 radius 1 } }", "5:", "2 objects"),
    ("Group { numObjects 1 MaterialIndex 0 Sphere { center 0 0 radius 1 } }", "5:",
     "expected a number, found 'radius'"),
    ("Group { numObjects 1 MaterialIndex 0 Sphere { center 0 0 nan radius 1 } }", "5:", "finite number"),
    ("Group { numObjects 1 MaterialIndex 0 Cone { } }", "5:", "expected an object"),
    ("Group { numObjects 1 Sphere { center 0 0 0 radius 1 } }", "5:", "MaterialIndex before"),
    ("Group { numObjects 1 MaterialIndex 0 Sphere { center 0 0 0 radius -1 } }", "5:", "radius > 0"),
    ("Group { numObjects 1 MaterialIndex 0 TriangleMesh { obj_file missing.obj } }", "missing.obj:1:1",
     "cannot read mesh"),
    ("Fog { }", "5:1", "expected a section"),
    ("Group { numObjects 1 MaterialIndex 0 Sphere { center 0 0 0 radius 1 }", "5:1", "found end of file"),
])
def test_errors_are_one_located_line(body, where, expected):
    with pytest.raises(SceneError) as info:
        parse(body, "bad.txt")
    message = str(info.value)
    assert "\n" not in message
    assert where in message and expected in message, message


def test_wrong_light_count_and_bad_camera():
    with pytest.raises(SceneError, match=r"bad.txt:2:\d+: expected 2 items \(numLights 2\) but found 1"):
        parse_scene("PerspectiveCamera { center 0 0 1 direction 0 0 -1 up 0 1 0 angle 30 }\n"
                    "Lights { numLights 2 PointLight { position 0 0 0 color 1 1 1 falloff 1 } }", "bad.txt")
    with pytest.raises(SceneError, match="not parallel"):
        parse_scene("PerspectiveCamera { center 0 0 1 direction 0 1 0 up 0 2 0 angle 30 }", "bad.txt")
    with pytest.raises(SceneError, match=r"angle in \(0, 180\)"):
        parse_scene("PerspectiveCamera { center 0 0 1 direction 0 0 -1 up 0 1 0 angle 180 }", "bad.txt")


def test_obj_reader(tmp_path):
    path = tmp_path / "m.obj"
    path.write_text("# comment\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 0 1\n"
                    "f 1/1 2/2 3/3\nf -3 -1 -2\ng part\nf 1 2 4 3\n")
    positions, faces = read_obj(path)
    assert positions.shape == (4, 3)
    assert faces.tolist() == [[0, 1, 2], [1, 3, 2], [0, 1, 3], [0, 3, 2]]
    path.write_text("v 0 0 0\nv 1 0 0\nf 1 2 7\n")
    with pytest.raises(SceneError, match=r"m.obj:3:7: expected a vertex index in 1..2, found 7"):
        read_obj(path)
    path.write_text("v 0 0\n")
    with pytest.raises(SceneError, match=r"m.obj:1:6: expected 3 numbers after 'v', found 2"):
        read_obj(path)
    path.write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe")
    with pytest.raises(SceneError, match="binary data"):
        read_obj(path)
