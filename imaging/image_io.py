"""Image files: the one place that reads and writes PNG and EXR.

Every writer writes to a temporary name in the destination folder and renames
it into place when complete, so an interrupted run never leaves a truncated
image and never replaces a good earlier one with a broken file.
"""
from __future__ import annotations

import functools
import os
import tempfile
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, Mapping

import numpy as np
from PIL import Image

from core.errors import SceneError


@contextmanager
def atomic_path(path: str | Path, suffix: str) -> Iterator[Path]:
    """Yields a temporary path beside ``path``; renames it to ``path`` on success."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=suffix, dir=path.parent)
    os.close(fd)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; finished files get the usual mode
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_image(path: str | Path, pixels: np.ndarray) -> None:
    """Writes an 8-bit RGB (H, W, 3) or grey (H, W) array; the suffix picks the
    format (.png, .bmp, .tga, ... as Pillow knows them)."""
    pixels = np.asarray(pixels)
    if pixels.dtype != np.uint8:
        raise TypeError(f"write_image wants uint8 pixels, got {pixels.dtype}")
    path = Path(path)
    image_format = Image.registered_extensions().get(path.suffix.lower())
    if image_format is None:
        raise ValueError(f"{path}: unknown image type {path.suffix!r} (use .png, .bmp, .tga or .exr)")
    with atomic_path(path, path.suffix) as tmp:
        # zlib level 1: a fifth of the default's time, files ~1.3x larger
        options = {"compress_level": 1} if image_format == "PNG" else {}
        Image.fromarray(pixels).save(tmp, format=image_format, **options)




def read_png(path: str | Path) -> np.ndarray:
    """Reads a PNG as uint8 RGB (H, W, 3)."""
    with Image.open(path) as image:
        return np.asarray(image.convert("RGB"))


#: The six face files of a course cube map folder, in the order they are stored
CUBE_FACES = ("left", "right", "up", "down", "front", "back")


def read_cube_map(folder: Path, faces: tuple[str, ...] = CUBE_FACES) -> np.ndarray:
    """Reads the six faces ``folder/<face>.png`` as uint8 RGBX (6, N, N, 4), X
    being padding so that a texel is one aligned 32-bit word, decoding
    them in parallel (the PNG decoder releases the GIL). Scenes that share a
    cube map in one process decode it once (until a face file changes)."""
    stamps = []
    for face in faces:
        try:
            stat = (folder / f"{face}.png").stat()
            stamps.append((stat.st_mtime_ns, stat.st_size))
        except OSError:
            stamps.append(None)
    return _read_cube_map(folder.resolve(), faces, tuple(stamps))


@functools.lru_cache(maxsize=4)
def _read_cube_map(folder: Path, faces: tuple[str, ...], stamps: tuple) -> np.ndarray:
    def read_face(face: str) -> np.ndarray:
        path = folder / f"{face}.png"
        try:
            with Image.open(path) as image:
                return np.asarray(image.convert("RGBX"))
        except FileNotFoundError:
            raise SceneError(path, 1, 1, "expected a cube-map face image, found no file") from None
        except OSError as error:
            raise SceneError(path, 1, 1, f"expected a PNG image, found unreadable data ({error})") from None

    if not folder.is_dir():
        raise SceneError(folder, 1, 1, "expected a cube-map folder, found none")
    with ThreadPoolExecutor(max_workers=min(len(faces), os.cpu_count() or 1)) as pool:
        images = list(pool.map(read_face, faces))
    for face, image in zip(faces, images):
        if image.shape[0] != image.shape[1] or image.shape != images[0].shape:
            raise SceneError(folder / f"{face}.png", 1, 1,
                             f"expected a square face of the same size as {faces[0]}.png, "
                             f"found {image.shape[1]}x{image.shape[0]}")
    cube = np.stack(images)
    cube.flags.writeable = False  # shared between scenes
    return cube


def write_exr(path: str | Path, layers: Mapping[str, np.ndarray]) -> None:
    """Writes one multilayer float32 EXR.

    ``layers`` maps a layer name to an (H, W, C) or (H, W) array. The layer
    ``""`` holds the beauty as plain ``R, G, B``; others become ``name.R`` ...
    (3 channels), ``name.X/Y/Z`` for vectors named normal/position, or
    ``name.Y`` (1 channel), which tev, Blender and Nuke list as layers.
    """
    channels = {}
    for name, data in layers.items():
        data = np.asarray(data, np.float32)
        if data.ndim == 2:
            data = data[..., None]
        suffixes = {1: ("Y",), 3: ("X", "Y", "Z") if name in ("normal", "position") else ("R", "G", "B"),
                    4: ("R", "G", "B", "A")}[data.shape[-1]]
        for k, suffix in enumerate(suffixes):
            key = f"{name}.{suffix}" if name else suffix
            channels[key] = np.ascontiguousarray(data[..., k])
    import OpenEXR  # imported on use: it adds a sixth of a second to start-up

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with atomic_path(path, ".exr") as tmp:
        with OpenEXR.File(header, channels) as exr:
            exr.write(str(tmp))


def read_exr(path: str | Path) -> dict[str, np.ndarray]:
    """Reads every channel of an EXR as float32 (H, W) arrays, keyed by channel name."""
    import OpenEXR

    with OpenEXR.File(str(path), separate_channels=True) as exr:
        return {name: np.asarray(channel.pixels, np.float32) for name, channel in exr.channels().items()}
