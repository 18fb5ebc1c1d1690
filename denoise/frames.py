"""Frame folders in the course framework's layout.

Per frame ``i``: ``beauty_i.exr`` (RGB), ``normal_i.exr`` (RGB, unit world
normal), ``position_i.exr`` (RGB, world position), ``depth_i.exr`` and
``ID_i.exr`` (one channel ``Y``; ID is the object index, -1 for background),
and ``matrix_i.mat``: little-endian int32 N, then N + 2 float32 4x4 matrices,
row-major, for column vectors: object-to-world of objects 0..N-1, then
world-to-camera, then world-to-screen (pixel coordinates, row 0 at the top).
EXRs are float32 with channels stored B, G, R (OpenEXR's order), which the
course's tinyexr reader takes. Results are ``result_i.exr``.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from imaging.image_io import atomic_path, read_exr, write_exr

BUFFERS = ("beauty", "normal", "position", "depth", "ID")


@dataclass
class FrameData:
    beauty: np.ndarray    # (H, W, 3)
    normal: np.ndarray    # (H, W, 3)
    position: np.ndarray  # (H, W, 3)
    depth: np.ndarray     # (H, W)
    ids: np.ndarray       # (H, W), -1 for background
    object_to_world: list[np.ndarray]
    world_to_camera: np.ndarray
    world_to_screen: np.ndarray
    albedo: np.ndarray | None = None  # (H, W, 3), optional albedo_i.exr (an extra beside the layout)


def frame_indices(folder: Path) -> list[int]:
    """Indices of the frames in ``folder`` (by their beauty files), sorted."""
    found = (re.fullmatch(r"beauty_(\d+)\.exr", p.name) for p in folder.iterdir())
    return sorted(int(m.group(1)) for m in found if m)


def read_matrices(path: Path) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    data = path.read_bytes()
    if len(data) < 4:
        raise ValueError(f"{path}: expected an int32 object count, found {len(data)} bytes")
    count = int(np.frombuffer(data[:4], "<i4")[0])
    expected = 4 + (count + 2) * 64
    if count < 0 or len(data) != expected:
        raise ValueError(f"{path}: expected {expected} bytes for {count} objects, found {len(data)}")
    matrices = np.frombuffer(data[4:], "<f4").reshape(count + 2, 4, 4).astype(np.float64)
    if not np.all(np.isfinite(matrices)):
        raise ValueError(f"{path}: expected finite matrices, found NaN or inf")
    return list(matrices[:count]), matrices[count], matrices[count + 1]


def write_matrices(path: Path, object_to_world, world_to_camera, world_to_screen) -> None:
    matrices = np.stack(list(object_to_world) + [world_to_camera, world_to_screen]).astype("<f4")
    with atomic_path(path, ".mat") as tmp:
        tmp.write_bytes(np.array([len(object_to_world)], "<i4").tobytes() + matrices.tobytes())


def _single(channels: dict, path: Path) -> np.ndarray:
    if "Y" in channels:
        return channels["Y"]
    if len(channels) == 1:
        return next(iter(channels.values()))
    if "R" in channels:
        return channels["R"]
    raise ValueError(f"{path}: expected one channel Y, found {', '.join(channels)}")


def _rgb(channels: dict, path: Path) -> np.ndarray:
    if not {"R", "G", "B"} <= set(channels):
        raise ValueError(f"{path}: expected channels R, G, B, found {', '.join(channels)}")
    return np.stack([channels["R"], channels["G"], channels["B"]], -1)


def read_frame(folder: Path, index: int) -> FrameData:
    paths = {name: folder / f"{name}_{index}.exr" for name in BUFFERS}
    missing = [str(p.name) for p in list(paths.values()) + [folder / f"matrix_{index}.mat"] if not p.exists()]
    if missing:
        raise FileNotFoundError(f"{folder}: frame {index} lacks {', '.join(missing)}")
    rgb = {n: _rgb(read_exr(paths[n]), paths[n]) for n in ("beauty", "normal", "position")}
    single = {n: _single(read_exr(paths[n]), paths[n]) for n in ("depth", "ID")}
    shapes = {a.shape[:2] for a in list(rgb.values()) + list(single.values())}
    if len(shapes) != 1:
        raise ValueError(f"{folder}: frame {index}'s buffers differ in size: {sorted(shapes)}")
    objects, camera, screen = read_matrices(folder / f"matrix_{index}.mat")
    albedo_path = folder / f"albedo_{index}.exr"
    albedo = _rgb(read_exr(albedo_path), albedo_path) if albedo_path.exists() else None
    return FrameData(rgb["beauty"], rgb["normal"], rgb["position"], single["depth"],
                     np.rint(single["ID"]).astype(np.int32), objects, camera, screen, albedo)


def write_frame(folder: Path, index: int, frame: FrameData) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for name, data in (("beauty", frame.beauty), ("normal", frame.normal), ("position", frame.position),
                       ("depth", frame.depth), ("ID", frame.ids.astype(np.float32))):
        write_exr(folder / f"{name}_{index}.exr", {"": data})
    if frame.albedo is not None:
        write_exr(folder / f"albedo_{index}.exr", {"": frame.albedo})
    write_matrices(folder / f"matrix_{index}.mat", frame.object_to_world, frame.world_to_camera,
                   frame.world_to_screen)


def camera_matrices(camera, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """(world-to-camera, world-to-screen) of the course camera.

    Camera coordinates are (β, γ, α) with ``p - center = α F + β H + γ U``
    (F = unit direction / tan(angle/2), H = normalize(F × up), U = up as
    given, as the course's camera shoots rays), so NDC are (β/α, γ/α); the
    screen maps pixel (i, j)'s centre to (i + 0.5, j + 0.5), row 0 at the top.
    """
    direction = np.asarray(camera.direction, np.float64)
    direction /= np.linalg.norm(direction)
    up = np.asarray(camera.up, np.float64)
    horizontal = np.cross(direction, up)
    horizontal /= np.linalg.norm(horizontal)
    forward = direction / np.tan(np.radians(camera.angle) / 2)
    basis = np.column_stack([horizontal, up, forward])
    world_to_camera = np.eye(4)
    world_to_camera[:3, :3] = np.linalg.inv(basis)
    world_to_camera[:3, 3] = -world_to_camera[:3, :3] @ np.asarray(camera.center, np.float64)
    sx, sy = (width - 1) / 2.0, (height - 1) / 2.0
    projection = np.array([[sx, 0, sx + 0.5, 0], [0, -sy, sy + 0.5, 0], [0, 0, 1, 0], [0, 0, 1, 0]], np.float64)
    return world_to_camera, projection @ world_to_camera
