"""Writes a :func:`converters.to_mitsuba.scene_dict` description as Mitsuba XML.

Meshes become binary PLY files in ``<stem>_meshes/`` beside the XML. Load the
result with the project's plugins registered and merging off (merging would
fuse the plane's tiles into one imprecise mesh)::

    import mitsuba as mi, mi_plugins
    mi.set_variant("llvm_ad_rgb"); mi_plugins.register()
    scene = mi.load_file("scenes_xml/showcase.xml", optimize=False)
"""
from __future__ import annotations

import os
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from imaging.image_io import atomic_path

#: XML tag of each plugin type the converter writes
TAGS = {
    "whitted": "integrator", "course_camera": "sensor", "hdrfilm": "film", "box": "rfilter",
    "independent": "sampler", "phong": "bsdf", "point": "emitter", "directional": "emitter",
    "constant": "emitter", "course_cubemap": "emitter", "sphere": "shape", "rectangle": "shape",
    "ellipsoids": "shape", "ply": "shape",
}


def _number(value: float) -> str:
    text = repr(float(value))  # shortest round-trip form
    return text[:-2] if text.endswith(".0") else text


def _numbers(values) -> str:
    return ", ".join(_number(v) for v in values)


class _Writer:
    def __init__(self, path: Path):
        self.path = path
        self.mesh_dir = path.parent / f"{path.stem}_meshes"
        self.files: list[Path] = []
        self.lines: list[str] = []

    def emit(self, depth: int, text: str) -> None:
        self.lines.append("    " * depth + text)

    def value(self, depth: int, name: str, value) -> None:
        attr = f"name={quoteattr(name)}"
        if isinstance(value, bool):
            self.emit(depth, f'<boolean {attr} value="{str(value).lower()}"/>')
        elif isinstance(value, int):
            self.emit(depth, f'<integer {attr} value="{value}"/>')
        elif isinstance(value, float):
            self.emit(depth, f'<float {attr} value="{_number(value)}"/>')
        elif isinstance(value, str):
            if name in ("filename", "folder") and Path(value).is_absolute():
                value = os.path.relpath(value, self.path.parent)  # portable: relative to the XML
            self.emit(depth, f"<string {attr} value={quoteattr(value)}/>")
        elif isinstance(value, (list, tuple)) and len(value) == 3:
            tag = "point" if name in ("origin", "center", "position") else "vector"
            self.emit(depth, f'<{tag} {attr} value="{_numbers(value)}"/>')
        elif isinstance(value, np.ndarray) and value.shape == (4, 4):  # a to_world matrix
            matrix = value.ravel()
            self.emit(depth, f"<transform {attr}>")
            self.emit(depth + 1, f'<matrix value="{" ".join(_number(v) for v in matrix)}"/>')
            self.emit(depth, "</transform>")
        elif isinstance(value, dict) and value.get("type") == "rgb":
            self.emit(depth, f'<rgb {attr} value="{_numbers(value["value"])}"/>')
        elif isinstance(value, dict) and value.get("type") == "ref":
            self.emit(depth, f'<ref id={quoteattr(value["id"])}/>')
        elif isinstance(value, dict):
            self.plugin(depth, name, value)
        else:
            raise TypeError(f"xml_writer: cannot write {name!r} of type {type(value).__name__}")

    def plugin(self, depth: int, key: str, spec: dict) -> None:
        kind = spec["type"]
        if kind == "mesh_data":
            filename = self.write_mesh_ply(key, spec)
            spec = {"type": "ply", "filename": filename, "face_normals": "normals" not in spec,
                    "bsdf": spec["bsdf"]}
            kind = "ply"
        elif kind == "ellipsoids":
            spec = {"type": "ellipsoids", "filename": self.write_ellipsoid_ply(key, spec), "extent": 1.0,
                    "bsdf": spec["bsdf"]}
        elif kind == "plane_tiles":
            for part, to_world in enumerate(spec["to_world"]):
                self.plugin(depth, key if part == 0 else f"{key}_part{part}",
                            {"type": "rectangle", "to_world": to_world, "bsdf": spec["bsdf"]})
            return
        tag = TAGS[kind]
        identity = spec.get("id", key if tag in ("shape", "bsdf", "emitter") else None)
        id_attr = f" id={quoteattr(identity)}" if identity else ""
        self.emit(depth, f"<{tag} type={quoteattr(kind)}{id_attr}>")
        for name, value in spec.items():
            if name not in ("type", "id"):
                self.value(depth + 1, name, value)
        self.emit(depth, f"</{tag}>")

    def write_mesh_ply(self, key: str, spec: dict) -> str:
        positions = np.asarray(spec["positions"], np.float32)
        faces = np.asarray(spec["faces"], np.uint32)
        normals = spec.get("normals")
        vertex_fields = ["x", "y", "z"] + (["nx", "ny", "nz"] if normals is not None else [])
        vertices = positions if normals is None else np.hstack([positions, np.asarray(normals, np.float32)])
        header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(vertices)}"]
        header += [f"property float {f}" for f in vertex_fields]
        header += [f"element face {len(faces)}", "property list uchar uint vertex_indices", "end_header"]
        face_records = np.zeros(len(faces), dtype=[("n", "u1"), ("v", "<u4", 3)])
        face_records["n"], face_records["v"] = 3, faces
        body = vertices.astype("<f4").tobytes() + face_records.tobytes()
        return self.write_file(f"{key}.ply", ("\n".join(header) + "\n").encode() + body)

    def write_ellipsoid_ply(self, key: str, spec: dict) -> str:
        # Mitsuba's ellipsoid PLY: x y z nx ny nz <extras> scale_0..2 (log) rot_0..3 (w x y z)
        center = np.asarray(spec["centers"], np.float64)[0]
        scales = np.log(np.asarray(spec["scales"], np.float64)[0])
        x, y, z, w = np.asarray(spec["quaternions"], np.float64)[0]
        fields = ["x", "y", "z", "nx", "ny", "nz", "opacity", "scale_0", "scale_1", "scale_2",
                  "rot_0", "rot_1", "rot_2", "rot_3"]
        values = [*center, 0.0, 0.0, 0.0, 1.0, *scales, w, x, y, z]
        header = ["ply", "format binary_little_endian 1.0", "element vertex 1"]
        header += [f"property float {f}" for f in fields] + ["end_header"]
        return self.write_file(f"{key}.ply", ("\n".join(header) + "\n").encode()
                               + np.asarray(values, "<f4").tobytes())

    def write_file(self, name: str, data: bytes) -> str:
        path = self.mesh_dir / name
        with atomic_path(path, ".ply") as tmp:
            tmp.write_bytes(data)
        self.files.append(path)
        return f"{self.mesh_dir.name}/{name}"


def write_xml(description: dict, path: str | Path, source: str | None = None, note: str | None = None) -> list[Path]:
    """Writes ``description`` to ``path`` (plus mesh files); returns every file written.

    ``note`` (e.g. the render flags) goes into the header comment. Mesh files
    left in ``<stem>_meshes/`` by an earlier conversion are removed, so the
    folder holds exactly what the XML refers to.
    """
    path = Path(path)
    writer = _Writer(path)
    writer.emit(0, '<scene version="3.0.0">')
    if source:
        made = f" {note}" if note else ""
        writer.emit(1, f"<!-- Converted from {source} by converters/{made}; load with optimize=False -->")
    for key, value in description.items():
        if key == "type":
            continue
        writer.value(1, key, value)
    writer.emit(0, "</scene>")
    with atomic_path(path, ".xml") as tmp:
        tmp.write_text("\n".join(writer.lines) + "\n")
    if writer.mesh_dir.is_dir():
        for stale in set(writer.mesh_dir.glob("*.ply")) - set(writer.files):
            stale.unlink()
    return [path] + writer.files
