"""Intel Open Image Denoise as its users run it, through its C API.

The ``oidn`` package (0.2.1) wraps only a few calls of the library it ships
(libOpenImageDenoise 1.4.3) and none that sets a parameter, so a filter made
through it runs in LDR mode: HDR input is clipped to [0, 1]. This module calls
the same shared library with :mod:`ctypes` and sets what users set:

- ``hdr`` on (our beauty is linear radiance, often above 1);
- ``albedo`` and ``normal`` auxiliary images when the frame has them, and
  ``cleanAux`` (they are noise-free: the first hit through the pixel centre);
- one filter per image size, created and committed once and only executed per
  frame (:meth:`OIDN.execute` is the part worth timing).
"""
from __future__ import annotations

import ctypes
import importlib.util
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from core.errors import UsageError

FORMAT_FLOAT3 = 3  # OIDN_FORMAT_FLOAT3
DEVICE_TYPE_DEFAULT = 0


#: OIDN 2's filter quality modes, fastest first
QUALITIES = ("fast", "balanced", "high")


@dataclass(frozen=True)
class OIDNParams:
    """OIDN's ``RT`` filter settings."""
    hdr: bool = True
    clean_aux: bool = True
    use_albedo: bool = True
    use_normal: bool = True
    quality: str = "high"  # one of QUALITIES

    def __post_init__(self):
        if self.quality not in QUALITIES:
            raise UsageError(f"oidn: quality must be one of {', '.join(QUALITIES)}, got {self.quality!r}")


def library() -> ctypes.CDLL:
    """libOpenImageDenoise from the ``oidn`` wheel. The wheel ships
    libtbb.so.12.5 but not the libtbb.so.12 name the library asks for, so
    that file is loaded (globally) first."""
    spec = importlib.util.find_spec("oidn")
    if spec is None:
        raise ImportError("the oidn package is not installed (pip install oidn)")
    folder = Path(spec.origin).parent / "lib.linux.x64"
    tbb = folder / "libtbb.so.12.5"
    if tbb.exists():
        ctypes.CDLL(str(tbb), mode=ctypes.RTLD_GLOBAL)
    found = sorted(folder.glob("libOpenImageDenoise.so*"))
    if not found:
        raise ImportError(f"{folder}: no libOpenImageDenoise.so")
    lib = ctypes.CDLL(str(found[-1]))
    p, s = ctypes.c_void_p, ctypes.c_char_p
    signatures = {
        "oidnNewDevice": ([ctypes.c_int], p), "oidnCommitDevice": ([p], None),
        "oidnGetDeviceError": ([p, ctypes.POINTER(ctypes.c_char_p)], ctypes.c_int),
        "oidnReleaseDevice": ([p], None), "oidnNewFilter": ([p, s], p),
        "oidnSetSharedFilterImage": ([p, s, p, ctypes.c_int] + [ctypes.c_size_t] * 5, None),
        "oidnSetFilter1b": ([p, s, ctypes.c_bool], None), "oidnGetFilter1b": ([p, s], ctypes.c_bool),
        "oidnCommitFilter": ([p], None), "oidnExecuteFilter": ([p], None), "oidnReleaseFilter": ([p], None),
    }
    for name, (arguments, result) in signatures.items():
        function = getattr(lib, name)
        function.argtypes, function.restype = arguments, result
    return lib


class OIDN:
    """One OIDN device and one committed ``RT`` filter per image size.

    The filter reads from and writes to NumPy buffers it shares with us;
    :meth:`set_inputs` copies a frame into them, :meth:`execute` runs the
    network, :meth:`output` is the result."""

    def __init__(self, params: OIDNParams = OIDNParams()):
        self.params = params
        self.lib = library()
        self.device = self.lib.oidnNewDevice(DEVICE_TYPE_DEFAULT)
        self.lib.oidnCommitDevice(self.device)
        self._check()
        self.filter = None
        self.key = None

    def _check(self) -> None:
        message = ctypes.c_char_p()
        code = self.lib.oidnGetDeviceError(self.device, ctypes.byref(message))
        if code != 0:
            raise RuntimeError(f"OIDN error {code}: {(message.value or b'').decode(errors='replace')}")

    def _share(self, name: str, image: np.ndarray) -> None:
        height, width = image.shape[:2]
        self.lib.oidnSetSharedFilterImage(self.filter, name.encode(), image.ctypes.data, FORMAT_FLOAT3,
                                          width, height, 0, 0, 0)

    def prepare(self, height: int, width: int, albedo: bool, normal: bool) -> None:
        """Creates and commits the filter, once per size and set of auxiliary images."""
        key = (height, width, albedo and self.params.use_albedo, normal and self.params.use_normal)
        if key == self.key:
            return
        self.release_filter()
        self.buffers = {"color": np.zeros((height, width, 3), np.float32)}
        if key[2]:
            self.buffers["albedo"] = np.zeros_like(self.buffers["color"])
        if key[3]:  # OIDN takes normals only together with albedo
            if not key[2]:
                self.buffers["albedo"] = np.ones_like(self.buffers["color"])
            self.buffers["normal"] = np.zeros_like(self.buffers["color"])
        self.buffers["output"] = np.zeros_like(self.buffers["color"])
        self.filter = self.lib.oidnNewFilter(self.device, b"RT")
        for name, image in self.buffers.items():
            self._share(name, image)
        self.lib.oidnSetFilter1b(self.filter, b"hdr", bool(self.params.hdr))
        if len(self.buffers) > 2:
            self.lib.oidnSetFilter1b(self.filter, b"cleanAux", bool(self.params.clean_aux))
        self.lib.oidnCommitFilter(self.filter)
        self._check()
        self.key = key

    @property
    def hdr(self) -> bool:
        """The filter's ``hdr`` setting, as the library reports it."""
        return bool(self.lib.oidnGetFilter1b(self.filter, b"hdr"))

    def set_inputs(self, color: np.ndarray, albedo: np.ndarray | None = None,
                   normal: np.ndarray | None = None) -> None:
        self.prepare(color.shape[0], color.shape[1], albedo is not None, normal is not None)
        # OIDN's HDR mode wants finite, non-negative radiance
        np.copyto(self.buffers["color"], np.nan_to_num(np.maximum(color, 0.0), nan=0.0, posinf=0.0))
        if "albedo" in self.buffers and albedo is not None:
            np.copyto(self.buffers["albedo"], np.clip(np.nan_to_num(albedo), 0.0, 1.0))
        if "normal" in self.buffers:
            np.copyto(self.buffers["normal"], np.nan_to_num(normal))

    def execute(self) -> None:
        self.lib.oidnExecuteFilter(self.filter)
        self._check()

    def output(self) -> np.ndarray:
        return self.buffers["output"].copy()

    def __call__(self, color: np.ndarray, albedo: np.ndarray | None = None,
                 normal: np.ndarray | None = None) -> np.ndarray:
        self.set_inputs(color, albedo, normal)
        self.execute()
        return self.output()

    def release_filter(self) -> None:
        if self.filter is not None:
            self.lib.oidnReleaseFilter(self.filter)
            self.filter, self.key = None, None

    def __del__(self):
        try:
            self.release_filter()
            self.lib.oidnReleaseDevice(self.device)
        except Exception:
            pass
