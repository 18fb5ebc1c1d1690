"""Lowering: the scene description's own node types as Mitsuba plugins.

:func:`lower` is the one place that expands what
:func:`converters.description.scene_dict` keeps as one node per course object:

- ``"mesh_data"`` becomes Mitsuba's ``"ply"`` shape whose ``filename`` is a
  :class:`MeshData`, the file's content in memory;
- ``"plane_tiles"`` becomes one ``"rectangle"`` per tile (``KEY``, ``KEY_part1``, ...);
- ``"ellipsoids"`` keeps its type; its arrays become the ``filename`` of the
  shape, an :class:`EllipsoidData`.

Every node of the result is a Mitsuba plugin. Its values are what XML can
say (numbers, strings, 3-vectors, ``rgb``, ``ref``, nested plugins), a 4x4
``to_world`` matrix, or an in-memory file. The two readers of the result only
translate: :func:`converters.to_mitsuba.load_scene_dict` builds the objects
(an in-memory file becomes an ``mi.Mesh`` or the ellipsoids' tensors), and
:func:`converters.xml_writer.write_xml` writes the text (an in-memory file
becomes a PLY file beside the XML, via :meth:`ply_bytes`).

Pure data, like the description: no Mitsuba import here.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: The description's node types that are not Mitsuba plugins; none is left
#: after lower() (nor an "ellipsoids" node with arrays that XML cannot hold)
DESCRIPTION_ONLY_TYPES = ("mesh_data", "plane_tiles")


@dataclass(frozen=True, eq=False)
class MeshData:
    """A triangle mesh's PLY file, in memory: world-space ``positions`` (N, 3),
    ``faces`` (M, 3) uint32 and, for smooth shading, per-vertex ``normals`` (N, 3)."""
    positions: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None = None

    def ply_bytes(self) -> bytes:
        """A binary little-endian PLY file, as Mitsuba's ``ply`` shape reads it (float32 vertices)."""
        positions = np.asarray(self.positions, np.float32)
        faces = np.asarray(self.faces, np.uint32)
        normals = self.normals
        vertex_fields = ["x", "y", "z"] + (["nx", "ny", "nz"] if normals is not None else [])
        vertices = positions if normals is None else np.hstack([positions, np.asarray(normals, np.float32)])
        header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(vertices)}"]
        header += [f"property float {f}" for f in vertex_fields]
        header += [f"element face {len(faces)}", "property list uchar uint vertex_indices", "end_header"]
        face_records = np.zeros(len(faces), dtype=[("n", "u1"), ("v", "<u4", 3)])
        face_records["n"], face_records["v"] = 3, faces
        return ("\n".join(header) + "\n").encode() + vertices.astype("<f4").tobytes() + face_records.tobytes()


@dataclass(frozen=True, eq=False)
class EllipsoidData:
    """The ``ellipsoids`` shape's data, in memory: ``centers`` (N, 3), ``scales``
    (N, 3, the semi-axes) and unit ``quaternions`` (N, 4, x y z w), float32."""
    centers: np.ndarray
    scales: np.ndarray
    quaternions: np.ndarray

    def ply_bytes(self) -> bytes:
        """Mitsuba's ellipsoid PLY: x y z nx ny nz <extras> scale_0..2 (log) rot_0..3 (w x y z)."""
        fields = ["x", "y", "z", "nx", "ny", "nz", "opacity", "scale_0", "scale_1", "scale_2",
                  "rot_0", "rot_1", "rot_2", "rot_3"]
        rows = []
        for center, scale, (x, y, z, w) in zip(np.asarray(self.centers, np.float64),
                                               np.asarray(self.scales, np.float64),
                                               np.asarray(self.quaternions, np.float64)):
            rows.append([*center, 0.0, 0.0, 0.0, 1.0, *np.log(scale), w, x, y, z])
        header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(rows)}"]
        header += [f"property float {f}" for f in fields] + ["end_header"]
        return ("\n".join(header) + "\n").encode() + np.asarray(rows, "<f4").tobytes()


def lower(description: dict) -> dict:
    """``description`` with every node in Mitsuba plugins (see the module's
    docstring); a new dict, the input is left as it is. Keys keep their order,
    a plane's tiles take its place. A lowered dict lowers to itself."""
    lowered: dict = {}
    for key, node in description.items():
        kind = node.get("type") if isinstance(node, dict) else None
        if kind == "mesh_data":
            normals = node.get("normals")
            lowered[key] = {"type": "ply", "filename": MeshData(node["positions"], node["faces"], normals),
                            "face_normals": normals is None, "bsdf": node["bsdf"]}
        elif kind == "plane_tiles":
            for part, to_world in enumerate(node["to_world"]):
                lowered[key if part == 0 else f"{key}_part{part}"] = {
                    "type": "rectangle", "to_world": np.asarray(to_world, np.float64), "bsdf": node["bsdf"]}
        elif kind == "ellipsoids" and "centers" in node:
            data = EllipsoidData(node["centers"], node["scales"], node["quaternions"])
            lowered[key] = {"type": "ellipsoids", "filename": data, "extent": float(node["extent"]),
                            "bsdf": node["bsdf"]}
        else:
            lowered[key] = node
    return lowered
