"""Frame folders in the course framework's layout.

Per frame ``i``: ``beauty_i.exr`` (RGB), ``normal_i.exr`` (RGB, unit world
normal), ``position_i.exr`` (RGB, world position), ``depth_i.exr`` and
``ID_i.exr`` (one channel ``Y``; ID is the object index, -1 for background),
and ``matrix_i.mat``: little-endian int32 N, then N + 2 float32 4x4 matrices,
row-major, for column vectors: object-to-world of objects 0..N-1, then
world-to-camera, then world-to-screen. EXRs are float32 with channels stored
B, G, R (OpenEXR's order), which the course's tinyexr reader takes. Results
are ``result_i.exr``. An optional ``albedo_i.exr`` (RGB) is an extra beside
the course's layout (OIDN and albedo demodulation use it).

The matrix convention is the course framework's (as in its example frames,
``../shared/games202/box/``):

- world-to-camera maps a world point to camera coordinates whose ``z`` is the
  depth along the view direction (positive in front of the camera);
- world-to-screen is a perspective projection of those: for a visible point,
  ``x/w, y/w`` are its pixel coordinates (pixel ``(i, j)``'s centre at
  ``(i + 0.5, j + 0.5)``, row 0 at the top), ``w`` is its camera depth, and
  ``z/w`` lies in (0, 1): ``z/w = f (d - n) / ((f - n) d)`` for depth ``d``
  with near and far planes ``n < f`` (:func:`depth_range` takes them from the
  points the frame sees). The course's reference solutions reject reprojected
  points whose ``z/w`` is outside (0, 1).

Every problem with a folder (a missing, damaged or inconsistent file) is a
:class:`core.errors.FrameError` that names the file.
"""
from __future__ import annotations

import os
import re
import sys
import tempfile
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from core.errors import FrameError
from core.inputs import NotAnInputFile, read_input
from imaging.image_io import atomic_path, read_exr, write_exr
from mi_plugins.camera_basis import course_camera_basis

BUFFERS = ("beauty", "normal", "position", "depth", "ID")


@dataclass
class FrameData:
    """One frame as NumPy arrays, as stored in its folder; the denoiser uploads
    it once per step into :class:`denoise.filters.FrameArrays`."""
    beauty: np.ndarray    # (H, W, 3)
    normal: np.ndarray    # (H, W, 3)
    position: np.ndarray  # (H, W, 3)
    depth: np.ndarray     # (H, W)
    ids: np.ndarray       # (H, W), -1 for background
    object_to_world: list[np.ndarray]
    world_to_camera: np.ndarray
    world_to_screen: np.ndarray
    albedo: np.ndarray | None = None  # (H, W, 3), optional albedo_i.exr (an extra beside the layout)


#: the longest frame number read, in digits (a frame index is an int64)
MAX_INDEX_DIGITS = 18


def frame_indices(folder: Path) -> list[int]:
    """Indices of the frames in ``folder`` (by their beauty files), sorted."""
    found = [m for m in (re.fullmatch(r"beauty_(\d+)\.exr", p.name) for p in folder.iterdir()) if m]
    for m in found:
        if len(m.group(1)) > MAX_INDEX_DIGITS:
            raise FrameError(f"{folder / m.group(0)}: a frame number of {len(m.group(1))} digits "
                             f"(at most {MAX_INDEX_DIGITS})")
    return sorted(int(m.group(1)) for m in found)


def missing_between(indices: list[int]) -> tuple[int, int] | None:
    """(the first missing index, how many are missing) between the first and
    the last of the sorted ``indices``, or None when they are consecutive.
    Counted from neighbours, never listed: indices may be far apart."""
    first, count = None, 0
    for a, b in zip(indices, indices[1:]):
        if b > a + 1:
            first = a + 1 if first is None else first
            count += b - a - 1
    return None if first is None else (first, count)



def same_size(path: Path, shape: tuple, other: Path, other_shape: tuple) -> None:
    """Raises :class:`FrameError` naming both files and their sizes unless two
    images (shapes ``(H, W, ...)``) have one size: checked before any arithmetic."""
    if tuple(shape[:2]) != tuple(other_shape[:2]):
        raise FrameError(f"{path}: {shape[1]}x{shape[0]} pixels, but {other} has {other_shape[1]}x{other_shape[0]}")


#: the largest matrix file read: a million objects' matrices
MAX_MATRIX_BYTES = 4 + (1_000_000 + 2) * 64


def read_matrices(path: Path) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    try:
        data = read_input(path, MAX_MATRIX_BYTES)  # a regular file: a pipe would block the read
    except NotAnInputFile as error:
        raise FrameError(f"{path}: {error}") from None
    if len(data) < 4:
        raise FrameError(f"{path}: expected an int32 object count, found {len(data)} bytes")
    count = int(np.frombuffer(data[:4], "<i4")[0])
    expected = 4 + (count + 2) * 64
    if count < 0 or expected > MAX_MATRIX_BYTES:  # not a count at all: text, or another file
        raise FrameError(f"{path}: not a matrix file (its first 4 bytes give {count} objects; "
                         f"a frame's matrix file holds an int32 count, then 4x4 float matrices)")
    if len(data) != expected:
        raise FrameError(f"{path}: expected {expected} bytes for {count} objects, found {len(data)}")
    matrices = np.frombuffer(data[4:], "<f4").reshape(count + 2, 4, 4).astype(np.float64)
    if not np.all(np.isfinite(matrices)):
        raise FrameError(f"{path}: expected finite matrices, found NaN or inf")
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
    raise FrameError(f"{path}: expected one channel Y, found {', '.join(channels)}")


def _rgb(channels: dict, path: Path) -> np.ndarray:
    if not {"R", "G", "B"} <= set(channels):
        raise FrameError(f"{path}: expected channels R, G, B, found {', '.join(channels)}")
    return np.stack([channels["R"], channels["G"], channels["B"]], -1)


@contextmanager
def _quiet_stderr():
    """OpenEXR's C++ core and its binding print their own lines about damaged
    files on file descriptors 1 and 2; they are held back (the FrameError
    says it in one line)."""
    sys.stdout.flush()
    sys.stderr.flush()
    try:
        saved = [os.dup(1), os.dup(2)]
    except OSError:
        yield
        return
    with tempfile.TemporaryFile() as sink:
        os.dup2(sink.fileno(), 1)
        os.dup2(sink.fileno(), 2)
        try:
            yield
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            for fd, copy in zip((1, 2), saved):
                os.dup2(copy, fd)
                os.close(copy)


def _read_exr(path: Path) -> dict:
    """The EXR's channels; a damaged file is a FrameError naming it."""
    try:
        with _quiet_stderr():
            channels = read_exr(path)
    except (FileNotFoundError, FrameError):
        raise
    except Exception as error:  # OpenEXR reports damage as RuntimeError/OSError without the name
        reason = " ".join(str(error).split()) or type(error).__name__
        raise FrameError(f"{path}: not a readable EXR ({reason})") from None
    if not channels:
        raise FrameError(f"{path}: the EXR has no channels")
    return channels


def missing_files(folder: Path, index: int) -> list[str]:
    """The names of frame ``index``'s required files that ``folder`` lacks."""
    required = [folder / f"{name}_{index}.exr" for name in BUFFERS] + [folder / f"matrix_{index}.mat"]
    return [p.name for p in required if not p.exists()]


def read_frame(folder: Path, index: int) -> FrameData:
    """Frame ``index`` of ``folder``, checked: every buffer the same size, ids
    that are whole numbers naming an object of ``matrix_i.mat`` (or -1)."""
    paths = {name: folder / f"{name}_{index}.exr" for name in BUFFERS}
    missing = missing_files(folder, index)
    if missing:
        raise FrameError(f"{folder}: frame {index} lacks {', '.join(missing)}")
    rgb = {n: _rgb(_read_exr(paths[n]), paths[n]) for n in ("beauty", "normal", "position")}
    single = {n: _single(_read_exr(paths[n]), paths[n]) for n in ("depth", "ID")}
    albedo_path = folder / f"albedo_{index}.exr"
    albedo = _rgb(_read_exr(albedo_path), albedo_path) if albedo_path.exists() else None
    sizes = {paths.get(n, albedo_path): a.shape[:2] for n, a in [*rgb.items(), *single.items(), ("albedo", albedo)]
             if a is not None}
    expected = sizes[paths["beauty"]]
    for path, shape in sizes.items():
        if shape != expected:
            raise FrameError(f"{path}: {shape[1]}x{shape[0]} pixels, but {paths['beauty'].name} has "
                             f"{expected[1]}x{expected[0]}")
    matrix_path = folder / f"matrix_{index}.mat"
    objects, camera, screen = read_matrices(matrix_path)
    ids = check_ids(single["ID"], paths["ID"], matrix_path, len(objects))
    return FrameData(rgb["beauty"], rgb["normal"], rgb["position"], single["depth"],
                     ids, objects, camera, screen, albedo)


def check_ids(raw_ids: np.ndarray, path: Path, matrix_path: Path, objects: int) -> np.ndarray:
    """The ID buffer as int32, checked in floating point before the cast (a
    cast of 1e30 is undefined and warns): finite whole numbers -1..objects-1."""
    if not np.isfinite(raw_ids).all():
        raise FrameError(f"{path}: NaN or inf object ids")
    rounded = np.rint(raw_ids.astype(np.float64))
    fractional = np.abs(raw_ids - rounded) > 1e-3
    if fractional.any():
        raise FrameError(f"{path}: object ids must be whole numbers, found {raw_ids[fractional][0]:g}")
    if rounded.size and (rounded.min() < -1 or rounded.max() >= objects):
        bad = rounded.max() if rounded.max() >= objects else rounded.min()
        raise FrameError(f"{path}: object id {bad:.15g}, but {matrix_path.name} has matrices for "
                         f"{objects} objects (ids -1 to {objects - 1})")
    return rounded.astype(np.int32)


def write_frame(folder: Path, index: int, frame: FrameData) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for name, data in (("beauty", frame.beauty), ("normal", frame.normal), ("position", frame.position),
                       ("depth", frame.depth), ("ID", frame.ids.astype(np.float32))):
        write_exr(folder / f"{name}_{index}.exr", {"": data})
    if frame.albedo is not None:
        write_exr(folder / f"albedo_{index}.exr", {"": frame.albedo})
    write_matrices(folder / f"matrix_{index}.mat", frame.object_to_world, frame.world_to_camera,
                   frame.world_to_screen)


def depth_range(camera, points: np.ndarray) -> tuple[float, float]:
    """Near and far planes for a frame whose visible world points are ``points``
    ((N, 3), e.g. the position buffer where an object was hit): half the
    smallest and twice the largest depth along the view direction, so that the
    frame's points and points that moved moderately map to z/w in (0, 1)."""
    direction = np.asarray(camera.direction, np.float64)
    direction = direction / np.linalg.norm(direction)
    centre = np.asarray(camera.center, np.float64)
    points = np.asarray(points).reshape(-1, 3)
    # (points - centre) @ direction in float64, a component at a time: no (N, 3) float64 copy
    depth = (points[:, 0] - centre[0]) * direction[0]
    for axis in (1, 2):
        depth += (points[:, axis] - centre[axis]) * direction[axis]
    depth = depth[np.isfinite(depth) & (depth > 0)]
    if depth.size == 0:
        return 1e-2, 1e3  # nothing visible: the course framework's own planes
    far = 2.0 * float(depth.max())
    return max(0.5 * float(depth.min()), 1e-6 * far), far


def camera_matrices(camera, width: int, height: int, near: float, far: float) -> tuple[np.ndarray, np.ndarray]:
    """(world-to-camera, world-to-screen) of the course camera, in the course
    framework's convention (see the module docstring).

    The course's camera shoots rays ``α F + β H + γ U`` with F = unit direction
    / tan(angle/2), H = normalize(F × up), U = up as given; camera coordinates
    are ``(β, γ, α) / tan(angle/2)``, so ``z`` is the depth along the view
    direction (when ``up`` is perpendicular to it, as in our scenes) and
    ``(x/z, y/z)`` are NDC. The screen maps pixel (i, j)'s centre to
    (i + 0.5, j + 0.5), row 0 at the top, and depth ``near``..``far`` to z/w
    in 0..1.
    """
    if not 0.0 < near < far:
        raise ValueError(f"camera_matrices: expected 0 < near < far, found near {near}, far {far}")
    basis = course_camera_basis(camera.direction, camera.up, camera.angle)
    world_to_camera = np.eye(4)
    world_to_camera[:3, :3] = (np.linalg.inv(np.column_stack([basis.horizontal, basis.up, basis.forward]))
                               / basis.tan_half_fov)
    world_to_camera[:3, 3] = -world_to_camera[:3, :3] @ np.asarray(camera.center, np.float64)
    sx, sy = (width - 1) / 2.0, (height - 1) / 2.0
    a, b = far / (far - near), -far * near / (far - near)  # z/w = a + b / depth
    projection = np.array([[sx, 0, sx + 0.5, 0], [0, -sy, sy + 0.5, 0], [0, 0, a, b], [0, 0, 1, 0]], np.float64)
    return world_to_camera, projection @ world_to_camera
