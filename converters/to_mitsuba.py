"""The scene description as a Mitsuba scene (the active variant's objects).

:func:`load_scene_dict` lowers the description (:func:`converters.lowering.lower`)
and hands the result to ``mi.load_dict``, translating only what a dict cannot
say by itself: a mesh file in memory becomes an ``mi.Mesh``, the ellipsoids'
data tensors, a 4x4 ``to_world`` a transform, and a ``ref`` to a material
the material object (an ``mi.Mesh`` takes its BSDF as an object).
"""
from __future__ import annotations

import mitsuba as mi
import numpy as np

from .lowering import EllipsoidData, MeshData, lower


def load_scene_dict(description: dict) -> mi.Scene:
    """The Mitsuba scene of a :func:`converters.description.scene_dict` description."""
    lowered = lower(description)
    materials = {key: mi.load_dict(node) for key, node in lowered.items()
                 if isinstance(node, dict) and node.get("type") == "phong"}
    final = {}
    for key, node in lowered.items():
        if key in materials:
            node = materials[key]
        elif isinstance(node, dict) and isinstance(node.get("bsdf"), dict) and node["bsdf"].get("type") == "ref":
            node = dict(node, bsdf=materials[node["bsdf"]["id"]])
            data = node.get("filename")
            if isinstance(data, MeshData):
                node = _to_mesh(key, data, node["bsdf"])
            elif isinstance(data, EllipsoidData):
                del node["filename"]
                node.update(centers=mi.TensorXf(data.centers), scales=mi.TensorXf(data.scales),
                            quaternions=mi.TensorXf(data.quaternions))
            elif isinstance(node.get("to_world"), np.ndarray):
                node["to_world"] = mi.ScalarTransform4f(node["to_world"].tolist())
        final[key] = node
    # optimize=False: merging would turn the plane tiles back into one imprecise mesh
    return mi.load_dict(final, optimize=False)


def _to_mesh(name: str, data: MeshData, bsdf: mi.BSDF) -> mi.Mesh:
    mesh = mi.Mesh(name, vertex_count=len(data.positions), face_count=len(data.faces),
                   has_vertex_normals=data.normals is not None, has_vertex_texcoords=False)
    params = mi.traverse(mesh)
    params["vertex_positions"] = np.ascontiguousarray(data.positions, np.float32).ravel()
    if data.normals is not None:
        params["vertex_normals"] = np.ascontiguousarray(data.normals, np.float32).ravel()
    params["faces"] = np.ascontiguousarray(data.faces, np.uint32).ravel()
    params.update()
    mesh.set_bsdf(bsdf)
    return mesh
