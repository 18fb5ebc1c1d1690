"""Writes a :func:`converters.description.scene_dict` description as Mitsuba XML.

The description is lowered first (:func:`converters.lowering.lower`), as for
:func:`converters.to_mitsuba.load_scene_dict`; this module only writes the
lowered nodes as text. Files held in memory (meshes, ellipsoids) become
binary PLY files in ``<stem>_meshes/`` beside the XML. Load the
result with the project's plugins registered and merging off (merging would
fuse the plane's tiles into one imprecise mesh)::

    import mitsuba as mi, mi_plugins
    mi.set_variant("llvm_ad_rgb"); mi_plugins.register()
    scene = mi.load_file("scenes_xml/showcase.xml", optimize=False)
"""
from __future__ import annotations

import os
from contextlib import ExitStack
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from imaging.image_io import atomic_path

from .lowering import EllipsoidData, MeshData, lower

#: XML tag of each plugin type the converter writes
TAGS = {
    "whitted": "integrator", "course_camera": "sensor", "hdrfilm": "film", "box": "rfilter",
    "independent": "sampler", "phong": "bsdf", "point": "emitter", "directional": "emitter",
    "constant": "emitter", "course_cubemap": "emitter", "sphere": "shape", "rectangle": "shape",
    "ellipsoids": "shape", "ply": "shape", "path": "integrator",
}


def _comment_text(text: str) -> str:
    """``text`` made legal inside an XML comment, which may not hold ``--`` (a
    ``--spp`` flag, a file named ``a--b.txt``) nor end in ``-``."""
    while "--" in text:
        text = text.replace("--", "- -")
    return text.rstrip("-")


def _number(value: float) -> str:
    text = repr(float(value))  # shortest round-trip form
    return text[:-2] if text.endswith(".0") else text


def _numbers(values) -> str:
    return ", ".join(_number(v) for v in values)


class _Writer:
    def __init__(self, path: Path):
        self.path = path
        # Mitsuba resolves a relative path from the folder of the XML as it is
        # loaded, and the system follows links before it takes a "..": so a
        # path is made relative to that folder's real location, never to its
        # spelling (through a link, "../x" names another folder)
        self.folder = os.path.realpath(path.parent)
        self.mesh_dir = path.parent / f"{path.stem}_meshes"
        self.files: list[Path] = []
        self.payloads: list[bytes] = []
        self.lines: list[str] = []

    def emit(self, depth: int, text: str) -> None:
        self.lines.append("    " * depth + text)

    def value(self, depth: int, name: str, value, owner: str = "") -> None:
        """One parameter; ``owner``: the key of the plugin it belongs to (names its file)."""
        attr = f"name={quoteattr(name)}"
        if isinstance(value, (MeshData, EllipsoidData)):  # a file's content: written beside the XML
            self.value(depth, name, self.write_file(f"{owner}.ply", value.ply_bytes()))
        elif isinstance(value, bool):
            self.emit(depth, f'<boolean {attr} value="{str(value).lower()}"/>')
        elif isinstance(value, int):
            self.emit(depth, f'<integer {attr} value="{value}"/>')
        elif isinstance(value, float):
            self.emit(depth, f'<float {attr} value="{_number(value)}"/>')
        elif isinstance(value, str):
            if name in ("filename", "folder") and Path(value).is_absolute():
                value = os.path.relpath(os.path.realpath(value), self.folder)  # portable: relative to the XML
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
        tag = TAGS[kind]
        # ids as load_dict gives them (its keys), so that mi.traverse names the
        # parameters alike (``sensor.fov``, not ``object_<address>.fov``)
        named = tag in ("shape", "bsdf", "emitter") or (depth == 1 and tag in ("sensor", "integrator"))
        identity = spec.get("id", key if named else None)
        id_attr = f" id={quoteattr(identity)}" if identity else ""
        self.emit(depth, f"<{tag} type={quoteattr(kind)}{id_attr}>")
        for name, value in spec.items():
            if name not in ("type", "id"):
                self.value(depth + 1, name, value, owner=key)
        self.emit(depth, f"</{tag}>")

    def write_file(self, name: str, data: bytes) -> str:
        """Keeps ``data`` for the mesh folder (written with the XML); returns its path relative to the XML."""
        path = self.mesh_dir / name
        self.files.append(path)
        self.payloads.append(data)
        return f"{self.mesh_dir.name}/{name}"


def write_xml(description: dict, path: str | Path, source: str | None = None, note: str | None = None) -> list[Path]:
    """Writes ``description`` (lowered) to ``path`` (plus mesh files); returns every file written.

    ``note`` (e.g. the render flags) goes into the header comment. Mesh files
    left in ``<stem>_meshes/`` by an earlier conversion are removed, so the
    folder holds exactly what the XML refers to. The new files replace the
    previous ones together, or (a write failed) not at all.
    """
    path = Path(path)
    writer = _Writer(path)
    writer.emit(0, '<scene version="3.0.0">')
    if source:
        made = f" {note}" if note else ""
        text = _comment_text(f"Converted from {source} by converters/{made}; load with optimize=False")
        writer.emit(1, f"<!-- {text} -->")
    for key, value in lower(description).items():
        if key == "type":
            continue
        writer.value(1, key, value)
    writer.emit(0, "</scene>")
    # every file is written to its temporary name before any replaces the previous one: a
    # conversion that fails (a full disk) leaves the previous XML and its meshes as they were
    with ExitStack() as files:
        for mesh, data in zip(writer.files, writer.payloads):
            files.enter_context(atomic_path(mesh, ".ply")).write_bytes(data)
        files.enter_context(atomic_path(path, ".xml")).write_text("\n".join(writer.lines) + "\n")
    if writer.mesh_dir.is_dir():
        for stale in set(writer.mesh_dir.glob("*.ply")) - set(writer.files):
            stale.unlink()
    return [path] + writer.files
