"""Image files: the one place that reads and writes PNG and EXR.

Every writer writes to a temporary name in the destination folder and renames
it into place when complete, so an interrupted run never leaves a truncated
image and never replaces a good earlier one with a broken file. A write that
fails (a full disk, a file-size limit, an I/O error), however the encoding
library reports it, is one :class:`OutputError` naming the file the user
asked for, never the temporary one, which is removed.
"""
from __future__ import annotations

import errno
import functools
import io
import os
import stat
import struct
import subprocess
import warnings
import zlib
from collections.abc import Iterator, Mapping
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path

import numpy as np
from PIL import Image

from core.entry import TEMPORARY
from core.errors import NO_ROOM, FrameError, OutputError, SceneError, write_failure  # noqa: F401 (NO_ROOM re-exported)

#: Longest file name (bytes) where the folder's file system does not say
DEFAULT_NAME_MAX = 255


def _name_max(folder: Path) -> int:
    try:
        return os.pathconf(folder, "PC_NAME_MAX")
    except (OSError, ValueError):
        return DEFAULT_NAME_MAX


def _temporary_name(name: str, suffix: str, limit: int) -> str:
    """``.{name}.{random}{suffix}``, the name cut short so that the whole is
    at most ``limit`` bytes: the temporary file fits wherever the final one does."""
    random = os.urandom(4).hex()
    fixed = len(os.fsencode(f"..{random}{suffix}"))
    if fixed >= limit:
        return f".{random}"[:limit]
    room = limit - fixed
    stem = name
    while len(os.fsencode(stem)) > room:
        stem = stem[:-1]
    return f".{stem}.{random}{suffix}"


def is_read_only(path: Path) -> bool:
    """An existing file we may not, or should not, replace: no write permission
    for us, or no write bit at all (which root could override, but the user
    marked the file as one to keep)."""
    try:
        mode = path.stat().st_mode
    except OSError:
        return False
    return not os.access(path, os.W_OK) or not mode & 0o222


def output_target(path: str | Path) -> Path:
    """The file that writing ``path`` replaces: ``path``, or the file a
    symbolic link (or a chain of them) points at, so that the link survives.
    Raises :class:`OutputError` where that is a folder."""
    path = Path(path)
    target = Path(os.path.realpath(path)) if path.is_symlink() else path
    if target.is_dir():
        raise OutputError(f"{path}: is a folder, not a file")
    if target.exists() and not target.is_file():  # a device or a pipe: replacing it would destroy it
        raise OutputError(f"{path}: is not a regular file (a device or a pipe?)")
    return target


@contextmanager
def atomic_path(path: str | Path, suffix: str) -> Iterator[Path]:
    """Yields a temporary path beside ``path``'s target; renames it into place on success.

    A symbolic link keeps pointing at its (replaced) target. The temporary
    name is no longer than the final one allows, and is removed on any
    exception, Ctrl-C and SIGTERM (:mod:`core.entry` raises through here).
    Problems with the destination are ``OutputError`` exceptions naming it.
    """
    target = output_target(path)
    folder = target.parent
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise OutputError(f"{path}: cannot create folder {folder}: a file of that name exists") from None
    except OSError as error:
        raise OutputError(f"{path}: cannot create folder {folder}: {write_failure(error)}") from None
    if is_read_only(target):
        raise OutputError(f"{path}: the existing file is read-only")
    limit = _name_max(folder)
    for _ in range(100):
        tmp = folder / _temporary_name(target.name, suffix, limit)
        try:
            # 0o666 less the umask: the finished file gets the usual mode
            os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
            break
        except FileExistsError:
            continue
        except OSError as error:
            raise OutputError(f"{path}: cannot write into {folder}: {write_failure(error)}") from None
    else:
        raise OutputError(f"{path}: cannot find a free temporary name in {folder}")
    TEMPORARY.add(str(tmp))  # removed by core.entry's watchdog where it ends the process meanwhile
    try:
        try:
            yield tmp
        except Exception as error:  # not BaseException: an interruption stays one
            why = write_failure(error)
            if why is None:
                raise
            raise OutputError(f"{path}: {why}") from None
        try:
            os.replace(tmp, target)
        except OSError as error:
            raise OutputError(f"{path}: cannot replace the file: {write_failure(error)}") from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    finally:
        TEMPORARY.discard(str(tmp))


def write_image(path: str | Path, pixels: np.ndarray) -> None:
    """Writes an 8-bit RGB (H, W, 3) or grey (H, W) array; the suffix picks the
    format (.png, .bmp, .tga, ... as Pillow knows them)."""
    pixels = np.asarray(pixels)
    if pixels.dtype != np.uint8:
        raise TypeError(f"write_image wants uint8 pixels, got {pixels.dtype}")
    path = Path(path)
    image_format = Image.registered_extensions().get(path.suffix.lower())
    if image_format is None:
        raise OutputError(f"{path}: unknown image type {path.suffix!r} (use .png, .bmp, .tga or .exr)")
    with atomic_path(path, path.suffix) as tmp:
        # zlib level 1: a fifth of the default's time, files ~1.3x larger
        options = {"compress_level": 1} if image_format == "PNG" else {}
        Image.fromarray(pixels).save(tmp, format=image_format, **options)




#: H.264 quality of the videos: FFmpeg's constant rate factor (lower is better; imageio's quality 8)
VIDEO_CRF = 10


def write_video(path: str | Path, frames: list[np.ndarray], fps: int = 2) -> None:
    """Writes 8-bit RGB frames as an H.264 MP4, with the FFmpeg that
    imageio-ffmpeg ships. H.264's 4:2:0 chroma wants even sizes: an odd width
    or height gets one more column or row (a copy of the last), rather than
    FFmpeg's resampling and warning.

    FFmpeg's messages are captured, never printed, and a failure (its exit
    status, which imageio's writer ignores: a full disk left a truncated
    video in place) is an :class:`OutputError` with FFmpeg's last line.
    """
    import imageio_ffmpeg  # noqa: PLC0415  imageio_ffmpeg loads on use: --help and the paths without it stay quick

    path = Path(path)
    height, width = frames[0].shape[:2]
    data = b"".join(np.ascontiguousarray(np.pad(frame, ((0, height % 2), (0, width % 2), (0, 0)), mode="edge"),
                                         np.uint8).tobytes() for frame in frames)
    with atomic_path(path, path.suffix) as tmp:
        command = [imageio_ffmpeg.get_ffmpeg_exe(), "-y", "-v", "error", "-f", "rawvideo", "-vcodec", "rawvideo",
                   "-s", f"{width + width % 2}x{height + height % 2}", "-pix_fmt", "rgb24", "-r", str(fps),
                   "-i", "-", "-an", "-vcodec", "libx264", "-pix_fmt", "yuv420p", "-crf", str(VIDEO_CRF),
                   str(tmp)]
        done = subprocess.run(command, input=data, capture_output=True)
        if done.returncode != 0:
            lines = [line.strip() for line in done.stderr.decode(errors="replace").splitlines() if line.strip()]
            last = lines[-1] if lines else f"exit status {done.returncode}"
            if write_failure(RuntimeError(" ".join(lines))) is not None:
                raise RuntimeError(" ".join(lines))  # a full disk: atomic_path names it
            raise OutputError(f"{path}: FFmpeg could not write the video: {last}")


def read_png(path: str | Path) -> np.ndarray:
    """The scores' one reader: a PNG of any mode and bit depth as uint8 RGB (H, W, 3), as its pixels
    (:func:`image_rgba`). What has no one meaning is a :class:`FrameError` naming the file: another
    format under the name (the content decides, not the extension: a JPEG's lossy pixels are not
    what was rendered) and transparent or translucent pixels (what they show depends on the
    viewer's background)."""
    rgba, kind = image_rgba(path)
    if kind != "PNG":
        raise FrameError(f"{path}: a {kind} file, not a PNG (the content decides, not the name: write it as PNG)")
    seen = int((rgba[..., 3] < 255).sum())
    if seen:
        raise FrameError(f"{path}: {seen} pixels of {rgba.shape[1]}x{rgba.shape[0]} are transparent or "
                         "translucent (alpha < 255); what they show depends on the background: write opaque RGB")
    return np.ascontiguousarray(rgba[..., :3])


def image_rgba(path: str | Path) -> tuple[np.ndarray, str]:
    """Any image Pillow reads as uint8 RGBA (H, W, 4), with its format as Pillow found it in the
    content. Every bit depth is rounded to the nearest 8-bit value: 16 bits per channel (which
    Pillow truncates to the high byte, or clips to 255 for grey) are read whole by libpng through
    Mitsuba's Bitmap; grey is repeated, a palette and its transparency looked up. Pillow's warning
    about images of more than 89 million pixels stays off stderr (the size goes into the caller's
    error); beyond twice that Pillow refuses it, a :data:`IMAGE_DECODE_ERRORS` error."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", Image.DecompressionBombWarning)
        with Image.open(path) as image:
            kind, rawmode = image.format, (image.tile[0][3] if image.tile else "")
            if kind == "PNG" and isinstance(rawmode, str) and rawmode.endswith(";16B"):
                return deep_png(path), kind
            if image.mode.startswith("I"):  # 16 or 32-bit grey of another format: scaled, not clipped
                grey = np.rint(np.asarray(image, np.float64) * (255 / 65535)).clip(0, 255).astype(np.uint8)
                return np.dstack([grey] * 3 + [np.full_like(grey, 255)]), kind
            return np.asarray(image.convert("RGBA")), kind


def deep_png(path: str | Path) -> np.ndarray:
    """A PNG of 16 bits per channel as uint8 RGBA, each value rounded to the nearest 8-bit one."""
    import mitsuba as mi  # noqa: PLC0415  only 16-bit PNGs need it; its importer chose the libLLVM first

    try:
        values = np.array(mi.Bitmap(str(path)), np.int64)
    except RuntimeError as error:  # libpng's damage, as Pillow's would be
        raise OSError(" ".join(str(error).split())) from None
    values = (2 * values + 257) // 514  # round(v / 257)
    if values.ndim == 2:
        values = values[..., None]
    colour = values[..., :-1] if values.shape[-1] in (2, 4) else values
    alpha = values[..., -1:] if values.shape[-1] in (2, 4) else np.full(values.shape[:2] + (1,), 255)
    return np.concatenate([np.broadcast_to(colour, values.shape[:2] + (3,)), alpha], -1).astype(np.uint8)


#: What Pillow raises on damaged, truncated or hostile image files: OSError
#: (unidentified, truncated), SyntaxError (broken chunks), ValueError and
#: TypeError (bad header fields), EOFError, struct.error, zlib.error, and the
#: decompression-bomb check
IMAGE_DECODE_ERRORS = (OSError, SyntaxError, ValueError, TypeError, EOFError, IndexError, struct.error,
                       zlib.error, Image.DecompressionBombError, MemoryError)

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
            rgbx = image_rgba(path)[0].copy()
            rgbx[..., 3] = 255  # padding: a face's texel is its colour only, as the course's binary reads it
            return rgbx
        except FileNotFoundError:
            raise SceneError(path, 1, 1, "expected a cube-map face image, found no file") from None
        except IMAGE_DECODE_ERRORS as error:
            detail = " ".join(str(error).split()) or type(error).__name__
            raise SceneError(path, 1, 1, f"expected a PNG image, found unreadable data ({detail})") from None

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
    import OpenEXR  # noqa: PLC0415  OpenEXR loads on use: start-up without EXR stays quick

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with atomic_path(path, ".exr") as tmp:
        with OpenEXR.File(header, channels) as exr:
            if utf8_path(tmp):
                exr.write(str(tmp))
            else:  # OpenEXR takes only a UTF-8 path: the file through Python's own, whatever its bytes
                data = io.BytesIO()
                exr.write(data)
                tmp.write_bytes(data.getvalue())
        if not exr_complete(tmp, EXR_ZIP_LINES):
            # OpenEXR's stream fails its last flush silently (a full disk under a small image)
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(tmp))


#: Scan lines per chunk of ZIP compression
EXR_ZIP_LINES = 16


def exr_complete(path: Path, lines_per_chunk: int) -> bool:
    """Whether the single-part scan-line EXR at ``path`` holds every chunk its
    offset table names, up to its last byte: a write whose end was lost is not."""
    try:
        with open(path, "rb") as file:
            data = file.read()
        if data[:4] != b"\x76\x2f\x31\x01":
            return False
        position, window = 8, None
        while data[position] != 0:  # attributes: name, type, size, value
            name_end = data.index(b"\0", position)
            type_end = data.index(b"\0", name_end + 1)
            (size,) = struct.unpack_from("<i", data, type_end + 1)
            if data[position:name_end] == b"dataWindow":
                window = struct.unpack_from("<4i", data, type_end + 5)
            position = type_end + 5 + size
        if window is None:
            return False
        chunks = -(-(window[3] - window[1] + 1) // lines_per_chunk)
        offsets = struct.unpack_from(f"<{chunks}Q", data, position + 1)
        _, size = struct.unpack_from("<ii", data, offsets[-1])
        return offsets[-1] + 8 + size == len(data)
    except (OSError, ValueError, IndexError, struct.error):
        return False


def read_exr(path: str | Path) -> dict[str, np.ndarray]:
    """Reads every channel of an EXR as float32 (H, W) arrays, keyed by channel name.
    A pipe, device or socket is a :class:`FrameError` before any read (a pipe
    that no one writes would block the reader forever)."""
    import OpenEXR  # noqa: PLC0415  OpenEXR loads on use: --help and the paths without it stay quick

    try:
        mode = os.stat(path).st_mode
    except OSError:
        mode = None  # missing or unreadable: OpenEXR's own error, as before
    if mode is not None and not stat.S_ISREG(mode) and not stat.S_ISDIR(mode):
        kind = "a pipe" if stat.S_ISFIFO(mode) else "a socket" if stat.S_ISSOCK(mode) else "a device"
        raise FrameError(f"{path}: {kind}, not a regular file")
    source = str(path) if utf8_path(path) else io.BytesIO(Path(path).read_bytes())
    with OpenEXR.File(source, separate_channels=True) as exr:
        return {name: np.asarray(channel.pixels, np.float32) for name, channel in exr.channels().items()}


def exr_size(path: str | Path) -> tuple[int, int] | None:
    """(width, height) of an EXR from its header alone, without its pixels;
    None where the header cannot be read (reading the file says why)."""
    import OpenEXR  # noqa: PLC0415  as in read_exr

    try:
        if not Path(path).is_file() or not utf8_path(path):
            return None
        with OpenEXR.File(str(path), header_only=True) as exr:
            low, high = exr.header()["dataWindow"]
        return int(high[0] - low[0] + 1), int(high[1] - low[1] + 1)
    except (OSError, RuntimeError, ValueError, KeyError, TypeError):
        return None


def utf8_path(path: str | Path) -> bool:
    """Whether ``path`` is text OpenEXR can open (a file name's bytes that are not UTF-8 are not)."""
    try:
        str(path).encode()
        return True
    except UnicodeEncodeError:
        return False


def read_exr_rgb(path: str | Path) -> np.ndarray:
    """The R, G, B channels of an EXR as one float32 (H, W, 3) array."""
    channels = read_exr(path)
    return np.stack([channels[c] for c in "RGB"], -1)


def check_writable(flag: str, path: Path) -> None:
    """``path`` can become a file: not a folder, its folder exists or can be
    created, and we may write there (and replace it, if it exists)."""
    if path.name in ("", ".", ".."):
        raise OutputError(f"{flag} {path}: expected a file name, found a folder")
    try:
        target = output_target(path)
    except OutputError as error:
        raise OutputError(f"{flag} {error}") from None
    if is_read_only(target):
        raise OutputError(f"{flag} {path}: the existing file is read-only")
    folder = target.parent if str(target.parent) else Path(".")
    existing = folder
    while not existing.exists():
        if existing.is_symlink():
            raise OutputError(f"{flag} {path}: {existing} is a broken link")
        existing = existing.parent
    if not existing.is_dir():
        raise OutputError(f"{flag} {path}: cannot create folder {folder}: {existing} is a file")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise OutputError(f"{flag} {path}: no permission to write in {existing}")
