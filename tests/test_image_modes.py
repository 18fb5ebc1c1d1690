"""Every PNG mode and bit depth a user's tools write is scored as its pixels, through one reader.

The same pixels are written in each mode as the student's image (and as the
reference); ``python -m course.score`` must find them identical (0 pixels off,
FLIP 0) with stderr empty, or refuse in one line what has no one meaning: a
PNG with transparent pixels (what it shows depends on the viewer's
background), another format under a ``.png`` name (the content decides, not
the extension). The renderer's cube-map faces go through the same decoding.
"""
from __future__ import annotations

import io
import re
import struct
import warnings
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from course.score import main
from imaging.image_io import read_cube_map, read_png

GREY = np.random.default_rng(3).integers(0, 256, (6, 9), np.uint8)
GREY[0, :2] = (0, 255)
OPAQUE = np.full(GREY.shape, 255, np.uint8)


def png16(channels: np.ndarray) -> bytes:
    """A 16-bit PNG of (H, W, C) uint16 (C: 1 grey, 2 grey+alpha, 3 RGB, 4 RGBA); Pillow writes none but grey."""
    height, width, count = channels.shape
    raw = b"".join(b"\0" + channels[y].astype(">u2").tobytes() for y in range(height))

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", width, height, 16, {1: 0, 2: 4, 3: 2, 4: 6}[count], 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")


def deep(grey: np.ndarray) -> np.ndarray:
    """16-bit values whose nearest 8-bit value is ``grey`` but whose high byte is not (but at 0 and 255)."""
    offset = np.where((grey < 128) & (grey > 0), -128, 128)
    return (grey.astype(np.int64) * 257 + np.where(grey == 255, -128, offset)).astype(np.uint16)


def palette(grey: np.ndarray, **info) -> Image.Image:
    image = Image.fromarray(grey, "L").convert("P")
    image.putpalette([v for k in range(256) for v in (k, k, k)])
    image.info.update(info)
    return image


def encoded(image: Image.Image, kind: str, **options) -> bytes:
    buffer = io.BytesIO()
    image.save(buffer, kind, **options)
    return buffer.getvalue()


def rgb(grey):
    return np.dstack([grey] * 3)


#: mode -> (the file's bytes from the grey pixels, None where they must read as those pixels, else the refusal)
WRITES = {
    "RGB": (lambda g: encoded(Image.fromarray(rgb(g)), "PNG"), None),
    "L": (lambda g: encoded(Image.fromarray(g), "PNG"), None),
    "LA opaque": (lambda g: encoded(Image.fromarray(np.dstack([g, OPAQUE]), "LA"), "PNG"), None),
    "RGBA opaque": (lambda g: encoded(Image.fromarray(np.dstack([rgb(g), OPAQUE]), "RGBA"), "PNG"), None),
    "1-bit": (lambda g: encoded(Image.fromarray(g >= 128).convert("1"), "PNG"), None),
    "4-bit grey": (lambda g: encoded(Image.fromarray(g), "PNG", bits=4), None),
    "P": (lambda g: encoded(palette(g), "PNG"), None),
    "P, transparency unused": (lambda g: encoded(palette(g | 1), "PNG", transparency=0), None),
    "P, alpha table all opaque": (lambda g: encoded(palette(g), "PNG", transparency=bytes([255] * 256)), None),
    "I;16": (lambda g: png16(deep(g)[..., None]), None),
    "16-bit RGB": (lambda g: png16(np.dstack([deep(g)] * 3)), None),
    "16-bit RGBA": (lambda g: png16(np.dstack([deep(g)] * 3 + [np.full(g.shape, 65535, np.uint16)])), None),
    "16-bit LA": (lambda g: png16(np.dstack([deep(g), np.full(g.shape, 65535, np.uint16)])), None),
    "RGBA, alpha 0": (lambda g: encoded(Image.fromarray(np.dstack([rgb(g), np.where(g > 100, 255, 0)
                                                                   .astype(np.uint8)]), "RGBA"), "PNG"),
                      r"pixels of 9x6 are transparent or translucent \(alpha < 255\)"),
    "LA, alpha 128": (lambda g: encoded(Image.fromarray(np.dstack([g, np.full(g.shape, 128, np.uint8)]), "LA"),
                                        "PNG"), r"54 pixels of 9x6 are transparent"),
    "P, transparency used": (lambda g: encoded(palette(g), "PNG", transparency=int(g[0, 0])),
                             r"pixels of 9x6 are transparent"),
    "16-bit RGBA, alpha 0": (lambda g: png16(np.dstack([deep(g)] * 3 + [np.zeros(g.shape, np.uint16)])),
                             r"54 pixels of 9x6 are transparent"),
    "JPEG": (lambda g: encoded(Image.fromarray(rgb(g)), "JPEG", quality=100), r"a JPEG file, not a PNG"),
    "BMP": (lambda g: encoded(Image.fromarray(rgb(g)), "BMP"), r"a BMP file, not a PNG"),
    "GIF": (lambda g: encoded(Image.fromarray(g), "GIF"), r"a GIF file, not a PNG"),
}


def expected_pixels(mode: str, grey: np.ndarray = GREY) -> np.ndarray:
    """What ``grey`` written in ``mode`` holds (1 bit: black or white; 4 bits: Pillow keeps the low four)."""
    held = (grey >= 128) * 255 if mode == "1-bit" else (grey & 15) * 17 if "4-bit" in mode \
        else grey | 1 if "unused" in mode else grey
    return rgb(held.astype(np.uint8))


def score(arguments: list[Path], capsys) -> tuple[int, str, str]:
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a library's warning would be a line on the user's stderr
        status = main([str(a) for a in arguments])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


@pytest.mark.parametrize("side", ["yours", "reference"])
@pytest.mark.parametrize("mode", WRITES)
def test_every_png_mode_is_scored_as_its_pixels_or_refused_in_one_line(tmp_path, capsys, mode, side):
    write, refusal = WRITES[mode]
    mine, reference = tmp_path / "mine", tmp_path / "ref"
    mine.mkdir(), reference.mkdir()
    pixels = expected_pixels(mode)
    odd = (mine if side == "yours" else reference) / "a01.png"
    (reference / "a01.png").write_bytes(encoded(Image.fromarray(pixels), "PNG"))
    (mine / "a01.png").write_bytes(encoded(Image.fromarray(pixels), "PNG"))
    odd.write_bytes(write(GREY))
    status, out, err = score([mine, "--reference", reference, "--report", tmp_path / "r.md"], capsys)
    if refusal is None:
        assert (status, err) == (0, ""), err
        assert "| a01.png | 0 | 0.000 % | 0.00000 | meets |" in out
        assert np.array_equal(read_png(odd), pixels)
    else:
        assert status == 2 and out == "" and err.count("\n") == 1, err
        assert err.startswith(f"python -m course.score: error: {odd}: "), err
        assert re.search(refusal, err), err


@pytest.mark.parametrize("mode", ["I;16", "16-bit RGB", "P", "4-bit grey"])
def test_cube_map_faces_are_read_by_the_same_decoding(tmp_path, mode):
    """A 16-bit grey face used to be clipped to white by Pillow's conversion."""
    square = GREY[:, :6]
    for face in ("left", "right", "up", "down", "front", "back"):
        (tmp_path / f"{face}.png").write_bytes(WRITES[mode][0](square))
    cube = read_cube_map(tmp_path)
    assert cube.shape == (6, 6, 6, 4)
    for face in cube:
        assert np.array_equal(face[..., :3], expected_pixels(mode, square))
