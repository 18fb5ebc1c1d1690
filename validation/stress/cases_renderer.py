"""Named stress cases for the renderer: stiff inputs and bad inputs.

Every case states what must happen:

- ``render``: the image is finite, and (``match``) equals the well-conditioned
  equivalent within the course's tolerance, or (``reference``) matches the
  NumPy reference tracer of the course's semantics;
- ``error``: exactly one :class:`SceneError` whose message is one line
  ``file:line:col: ...`` containing ``expect``.

:func:`validation.stress.suite.all_cases` gathers them with the other tables.
"""
from __future__ import annotations

from imaging.image_io import CUBE_FACES
from validation.stress.scene import DEFAULTS, Case, material, scene


def render_cases() -> list[Case]:
    cases = []
    for s in ("0", "0.5", "1e4", "1e6"):
        cases.append(Case(f"shininess {s}", scene(materials=material(shininess=s)), "render", reference=True))
    cases += [
        Case("light at grazing incidence", scene(lights="DirectionalLight { direction 1 0 0 color 1 1 1 } "
                                                        "DirectionalLight { direction 1 -1e-7 0 color 1 1 1 }"),
             "render", reference=True),
        Case("point light on the plane", scene(lights="PointLight { position 0 0 0 color 1 1 1 falloff 1 } "
                                                      "PointLight { position 0.3 0 1 color 1 1 1 falloff 1 }"),
             "render"),
        Case("point light inside a sphere", scene(lights="PointLight { position -0.8 0.8 0 color 1 1 1 falloff 0.1 } "
                                                         "DirectionalLight { direction 0 -1 0 color 0.2 0.2 0.2 }"),
             "render", reference=True),
        Case("colours 0", scene(materials=material(diffuse="0 0 0", specular="0 0 0")), "render", reference=True),
        Case("colours 1e6", scene(materials=material(diffuse="1e6 1e6 1e6", specular="1e6 0 0")), "render",
             reference=True),
        Case("light intensity 0", scene(lights="PointLight { position 1 3 2 color 0 0 0 falloff 1 } "
                                               "DirectionalLight { direction 0 -1 0 color 0 0 0 }"),
             "render", reference=True),
        Case("light intensity 1e6", scene(lights="PointLight { position 1 3 2 color 1e6 1e6 1e6 falloff 1 } "
                                                 "DirectionalLight { direction 0 -1 0 color 1e6 1e6 1e6 }"),
             "render", reference=True),
        Case("falloff 1e-30", scene(lights="PointLight { position 1 3 2 color 1 1 1 falloff 1e-30 } "
                                           "DirectionalLight { direction 0 -1 0 color 0.2 0.2 0.2 }"),
             "render", reference=True),
        Case("zero-area triangle", scene(num_objects=4, objects=DEFAULTS["objects"] +
                                         " Triangle { vertex0 0 1 0 vertex1 1 2 0 vertex2 2 3 0 }"),
             "render", match=scene()),
        Case("triangle with repeated vertices", scene(num_objects=4, objects=DEFAULTS["objects"] +
                                                      " Triangle { vertex0 0 1 0 vertex1 0 1 0 vertex2 1 1 1 }"),
             "render", match=scene()),
        Case("mesh with degenerate faces", scene(num_objects=4, objects=DEFAULTS["objects"] +
                                                 " TriangleMesh { obj_file degenerate.obj }"),
             "render", reference=True, files={"degenerate.obj": b"v 0 1 0\nv 1 1 0\nv 0 2 0\nv 2 2 0\n"
                                                                b"f 1 2 3\nf 1 1 2\nf 1 2 4\nf 2 4 2\n"}),
        Case("sphere flattened by Scale 1 0.001 1", scene(objects=DEFAULTS["objects"].replace(
            "Scale 0.6 0.6 0.6", "Scale 0.6 0.001 0.6")), "render", reference=True),
        Case("camera up not orthogonal and not unit", scene(up="0.3 5 0.1"), "render", reference=True),
        Case("angle 179", scene(angle="179"), "render", reference=True),
        Case("angle 1e-3", scene(angle="1e-3"), "render", reference=True),
        Case("1x1 image", scene(), "render", reference=True, flags=dict(bounces=1, shadows=True, size=(1, 1))),
    ]
    for scale, offset in ((1e-4, 0.0), (1e5, 0.0), (1.0, 1e5), (1e-4, 1.0), (1e5, 1e7)):
        name = f"scene scaled by {scale:g}" + (f" and moved {offset:g} away" if offset else "")
        # 1e5 scene sizes away, float32 coordinates are 1e-3 of the scene apart: edges and normals
        # move by that much, so a few pixels may differ; acne or leaks would differ by far more
        far = offset >= 1e4 * scale
        cases.append(Case(name, scene(), "render", match=scene(), scale=scale, offset=offset,
                          tolerance=0.01 if far else 0.005, max_difference=64 if far else 255))
    return cases


def error_cases() -> list[Case]:
    s = scene()
    return [
        Case("sphere radius 0", scene(objects="MaterialIndex 0 Sphere { center 0 0 0 radius 0 }", num_objects=1),
             "error", expect="radius > 0"),
        Case("negative sphere radius", scene(objects="MaterialIndex 0 Sphere { center 0 0 0 radius -1 }",
                                             num_objects=1), "error", expect="radius > 0"),
        Case("Scale 0", scene(objects="MaterialIndex 0 Transform { Scale 0 1 1 Sphere { center 0 0 0 radius 1 } }",
                              num_objects=1), "error", expect="invertible transform"),
        Case("UniformScale 0", scene(objects="MaterialIndex 0 Transform { UniformScale 0 Plane { normal 0 1 0 "
                                             "offset 0 } }", num_objects=1), "error", expect="invertible transform"),
        Case("Matrix4f singular", scene(objects="MaterialIndex 0 Transform { Matrix4f { 1 0 0 0 1 0 0 0 0 0 1 0 "
                                                "0 0 0 1 } Sphere { center 0 0 0 radius 1 } }", num_objects=1),
             "error", expect="invertible transform"),
        Case("Matrix4f with a zero last row", scene(objects="MaterialIndex 0 Transform { Matrix4f { 1 0 0 0 "
                                                            "0 1 0 0 0 0 1 0 0 0 0 0 } Sphere { center 0 0 0 "
                                                            "radius 1 } }", num_objects=1),
             "error", expect="expected an affine Matrix4f, whose last row (the 4th number of each column) is "
                             "0 0 0 1, found 0 0 0 0"),
        Case("Matrix4f with a projective last row", scene(objects="MaterialIndex 0 Transform { Matrix4f { 1 0 0 0.5 "
                                                                  "0 1 0 0 0 0 1 0 0 0 0 2 } Sphere { center 0 0 0 "
                                                                  "radius 1 } }", num_objects=1),
             "error", expect="found 0.5 0 0 2"),
        Case("Rotate about a zero axis", scene(objects="MaterialIndex 0 Transform { Rotate { 0 0 0 45 } "
                                                       "Sphere { center 0 0 0 radius 1 } }", num_objects=1),
             "error", expect="non-zero rotation axis"),
        Case("falloff 0", scene(lights="PointLight { position 0 1 0 color 1 1 1 falloff 0 } "
                                       "DirectionalLight { direction 0 -1 0 color 1 1 1 }"),
             "error", expect="falloff > 0"),
        Case("negative falloff", scene(lights="PointLight { position 0 1 0 color 1 1 1 falloff -2 } "
                                              "DirectionalLight { direction 0 -1 0 color 1 1 1 }"),
             "error", expect="falloff > 0"),
        Case("zero light direction", scene(lights="DirectionalLight { direction 0 0 0 color 1 1 1 } "
                                                  "DirectionalLight { direction 0 -1 0 color 1 1 1 }"),
             "error", expect="non-zero light direction"),
        Case("zero plane normal", scene(objects="MaterialIndex 0 Plane { normal 0 0 0 offset 1 }", num_objects=1),
             "error", expect="non-zero plane normal"),
        Case("camera up parallel to direction", scene(up="0 -0.2 -2"), "error", expect="not parallel"),
        Case("camera zero direction", scene(direction="0 0 0"), "error", expect="non-zero camera direction"),
        Case("angle 0", scene(angle="0"), "error", expect="angle in (0, 180)"),
        Case("angle negative", scene(angle="-30"), "error", expect="angle in (0, 180)"),
        Case("angle 180", scene(angle="180"), "error", expect="angle in (0, 180)"),
        Case("NaN number", scene(center="0 nan 6"), "error", expect="expected a finite number, found 'nan'"),
        Case("inf number", scene(angle="inf"), "error", expect="expected a finite number, found 'inf'"),
        Case("overflowing number", scene(center="0 1e400 6"), "error", expect="finite number"),
        Case("missing number", scene(center="0 1"), "error", expect="expected a number, found 'direction'"),
        Case("unknown token", s.replace("Background {", "Background { fog 1"), "error",
             expect="expected one of ambientLight, color, cubeMap"),
        Case("unknown section", s + "\nFog { }", "error", expect="expected a section"),
        Case("numLights too large", scene(num_lights=3), "error", expect="expected 3 items (numLights 3)"),
        Case("numLights too small", scene(num_lights=1), "error", expect="after 1 items (numLights 1)"),
        Case("numMaterials wrong", scene(num_materials=5), "error", expect="numMaterials 5"),
        Case("numObjects too large", scene(num_objects=4), "error", expect="4 objects (numObjects 4)"),
        Case("numObjects too small", scene(num_objects=1), "error", expect="after 1 objects"),
        Case("negative count", scene(num_lights=-1), "error", expect="an integer >= 0"),
        Case("count not an integer", scene(num_objects="2.5"), "error", expect="expected an integer"),
        Case("MaterialIndex out of range", scene(objects="MaterialIndex 7 Plane { normal 0 1 0 offset 0 }",
                                                 num_objects=1), "error", expect="material index in 0..1"),
        Case("object before MaterialIndex", scene(objects="Plane { normal 0 1 0 offset 0 }", num_objects=1),
             "error", expect="MaterialIndex before the first object"),
        Case("missing OBJ file", scene(objects="MaterialIndex 0 TriangleMesh { obj_file nowhere.obj }",
                                       num_objects=1), "error", expect="cannot read mesh"),
        Case("missing cube-map face", scene(background="cubeMap sky"), "error", expect="up.png",
             files={f"sky/{f}.png": b"" for f in CUBE_FACES if f != "up"}),
        Case("malformed OBJ vertex", scene(objects="MaterialIndex 0 TriangleMesh { obj_file bad.obj }",
                                           num_objects=1), "error", expect="bad.obj:2:5: expected a number",
             files={"bad.obj": b"v 0 0 0\nv 1 x 0\nv 0 1 0\nf 1 2 3\n"}),
        Case("OBJ face index out of range", scene(objects="MaterialIndex 0 TriangleMesh { obj_file bad.obj }",
                                                  num_objects=1), "error", expect="bad.obj:2:7: expected a vertex",
             files={"bad.obj": b"v 0 0 0\nf 1 1 9\n"}),
        Case("OBJ unknown statement", scene(objects="MaterialIndex 0 TriangleMesh { obj_file bad.obj }",
                                            num_objects=1), "error", expect="expected an OBJ statement",
             files={"bad.obj": b"v 0 0 0\nwhat 1 2\n"}),
        Case("a device as mesh (never ends)", scene(objects="MaterialIndex 0 TriangleMesh { obj_file /dev/zero }",
                                                    num_objects=1), "error", expect="a device, not a regular file"),
        Case("a number with an underscore", scene(objects="MaterialIndex 0 Sphere { center 0 0 0 radius 1_0 }",
                                                  num_objects=1), "error", expect="a number in ASCII decimal digits"),
        Case("a number in other scripts' digits", scene(objects="MaterialIndex 0 Sphere { center 0 0 0 radius ٣ }",
                                                        num_objects=1), "error",
             expect="a number in ASCII decimal digits, found '٣'"),
        Case("MaterialIndex without materials", scene(num_materials=0, materials="",
                                                      objects="MaterialIndex 0 Sphere { center 0 0 0 radius 1 }",
                                                      num_objects=1), "error",
             expect="the scene declares no materials"),
        Case("OBJ without faces", scene(objects="MaterialIndex 0 TriangleMesh { obj_file bad.obj }",
                                        num_objects=1), "error", expect="at least one face",
             files={"bad.obj": b"v 0 0 0\nv 1 0 0\n"}),
        Case("empty file", "", "error", expect="expected a PerspectiveCamera section, found end of file"),
        Case("only comments", "# nothing here\n\n   # still nothing\n", "error",
             expect="PerspectiveCamera section"),
        Case("binary garbage", "\x00\x89PNG\r\n\x1a\n\xff\xfe\x00", "error", expect="binary data"),
        Case("unclosed brace", s.rstrip().rstrip("}"), "error", expect="found end of file"),
        Case("repeated key", scene(center="0 1 6 center 0 1 6"), "error", expect="repeated"),
        Case("repeated section", s + s.splitlines()[0], "error", expect="repeated"),
    ]
