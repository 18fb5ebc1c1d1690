"""Intel Open Image Denoise 2 through ``pyoidn``, set up as its users set it
up, and the method that runs it after our temporal accumulation.

- ``hdr`` on: our beauty is linear radiance, often above 1;
- ``albedo`` and ``normal`` auxiliary images when the frame has them, with
  ``cleanAux`` (they are noise-free: the first hit through the pixel centre);
- ``quality``: OIDN 2's ``fast``, ``balanced`` or ``high`` network;
- one filter per image size (and set of auxiliary images), created and
  committed once; a frame only copies into the shared buffers and executes
  (:meth:`OIDN.execute` is the part worth timing).

Negative radiance is clamped to 0 here, as HDR mode requires, and NaN or
infinite values of any input are set to 0 (as
:meth:`denoise.methods.base.DenoisingMethod.usable_frame` does before the
filters): OIDN passes an infinite colour through to its output. An image
narrower or lower than :data:`MIN_SIDE` pixels is denoised edge-padded to
that size and cropped back: OIDN's network darkens a constant 1x1 image to
0.18 (2x2: 0.74, 16x16: 1.00).
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import mitsuba as mi
import numpy as np
import pyoidn

from core.errors import FrameError, UsageError

from ..filters import TemporalParams, accumulate
from .base import DenoisingMethod, Option, temporal_options, temporal_params

#: images smaller than this on a side are denoised edge-padded to it
MIN_SIDE = 16
#: OIDN 2's quality modes by the names the command line uses
QUALITIES = {"fast": pyoidn.OIDN_QUALITY_FAST, "balanced": pyoidn.OIDN_QUALITY_BALANCED,
             "high": pyoidn.OIDN_QUALITY_HIGH}


def oidn_version() -> str:
    """The version of the OIDN library that pyoidn wraps, e.g. ``2.5.1``."""
    return pyoidn.version.oidn_version


@dataclass(frozen=True)
class OIDNParams:
    """OIDN's ``RT`` filter settings.

    - ``hdr``: HDR mode (off clips the input to [0, 1]);
    - ``clean_aux``: the auxiliary images are noise-free;
    - ``use_albedo``, ``use_normal``: pass the frame's albedo / normals when it has them;
    - ``quality``: ``fast``, ``balanced`` or ``high`` (:data:`QUALITIES`).
    """
    hdr: bool = True
    clean_aux: bool = True
    use_albedo: bool = True
    use_normal: bool = True
    quality: str = "high"

    def __post_init__(self):
        if self.quality not in QUALITIES:
            raise UsageError(f"unknown OIDN quality {self.quality!r}; choose from {', '.join(QUALITIES)}")


#: how long the main thread waits on an execute between checks for a stop signal
WAIT_SLICE_S = 0.05


class OIDN:
    """One OIDN CPU device and one committed ``RT`` filter per image size.

    The filter reads from and writes to NumPy buffers it shares with us;
    :meth:`set_inputs` copies a frame into them (committing a new filter
    only when the size or the set of auxiliary images changes),
    :meth:`execute` runs the network, :meth:`output` is the result."""

    def __init__(self, params: OIDNParams = OIDNParams()):
        self.params = params
        self.device = pyoidn.Device()
        self.device.commit()
        self.check("creating the device")
        self.filter: pyoidn.Filter | None = None
        self.key = None
        self.buffers: dict[str, np.ndarray] = {}
        self.size = (0, 0)  # the last input's height and width (the buffers may be padded beyond it)
        self.running: threading.Event | None = None  # set when an execute a stop signal left running ends

    def check(self, operation: str) -> None:
        """Raises the device's pending error, if any (OIDN reports errors there)."""
        message = self.device.get_error()
        if message is not None:
            raise RuntimeError(f"OIDN failed {operation}: {message}")

    def prepare(self, height: int, width: int, albedo: bool, normal: bool) -> None:
        """Creates and commits the filter, once per size and set of auxiliary images."""
        key = (height, width, albedo and self.params.use_albedo, normal and self.params.use_normal)
        if key == self.key:
            return
        self.release_filter()
        shape = (height, width, 3)
        buffers = {"color": np.zeros(shape, np.float32)}
        if key[2]:
            buffers["albedo"] = np.zeros(shape, np.float32)
        if key[3]:  # OIDN takes normals only together with albedo
            buffers.setdefault("albedo", np.ones(shape, np.float32))
            buffers["normal"] = np.zeros(shape, np.float32)
        buffers["output"] = np.zeros(shape, np.float32)
        self.filter = pyoidn.Filter(self.device, pyoidn.OIDN_FILTER_TYPE_RT)
        for name, image in buffers.items():
            self.filter.set_image(name, image, pyoidn.OIDN_FORMAT_FLOAT3)
        self.filter.set_bool("hdr", self.params.hdr)
        if len(buffers) > 2:
            self.filter.set_bool("cleanAux", self.params.clean_aux)
        self.filter.set_quality(QUALITIES[self.params.quality])
        self.filter.commit()
        self.check("committing the filter")
        self.buffers, self.key = buffers, key

    @property
    def hdr(self) -> bool:
        """The filter's ``hdr`` setting, as the library reports it."""
        return self.filter.get_bool("hdr")

    @property
    def quality(self) -> str:
        """The filter's ``quality`` setting, as the library reports it."""
        value = self.filter.get_int("quality")
        return next((name for name, q in QUALITIES.items() if q == value), str(value))

    def set_inputs(self, color: np.ndarray, albedo: np.ndarray | None = None,
                   normal: np.ndarray | None = None) -> None:
        """Copies a frame (``(H, W, 3)`` arrays) into the filter's buffers."""
        if color.ndim != 3 or color.shape[2] != 3 or 0 in color.shape:
            raise FrameError(f"OIDN needs a non-empty (height, width, 3) colour image, got shape {color.shape}")
        for name, image in (("albedo", albedo), ("normal", normal)):
            if image is not None and image.shape != color.shape:
                raise FrameError(f"OIDN: the {name} image has shape {image.shape}, the colour {color.shape}")
        self.finish_running()
        height, width = color.shape[:2]
        self.size = (height, width)
        self.prepare(max(height, MIN_SIDE), max(width, MIN_SIDE), albedo is not None, normal is not None)

        rows, columns = self.buffers["color"].shape[0] - height, self.buffers["color"].shape[1] - width

        def padded(image: np.ndarray) -> np.ndarray:
            if not np.isfinite(image).all():
                image = np.where(np.isfinite(image), image, 0.0)
            return np.pad(image, ((0, rows), (0, columns), (0, 0)), mode="edge") if rows or columns else image

        np.maximum(padded(color), 0.0, out=self.buffers["color"])
        if albedo is not None and self.key[2]:
            np.clip(padded(albedo), 0.0, 1.0, out=self.buffers["albedo"])
        if normal is not None and self.key[3]:
            np.copyto(self.buffers["normal"], padded(normal))

    def execute(self) -> None:
        """Runs the network. On the main thread it runs on a worker thread that the main
        thread waits on in short slices: one execute at 1280x720 ``high`` takes
        seconds in native code (pyoidn's cffi call releases the GIL), and a stop
        signal's handler runs only on the main thread, between Python's bytecodes. On
        a stop the worker is left to finish into the filter's own buffers; nothing
        reads them, and the next execute waits for it first. The worker's end is an
        Event it sets, not ``Thread.is_alive``: Python 3.11's ``join`` marks a thread
        stopped when a signal's exception cuts the join short."""
        self.finish_running()
        if threading.current_thread() is not threading.main_thread():
            self.filter.execute()
        else:
            failed: list[BaseException] = []
            done = threading.Event()

            def work(filter_=self.filter, device=self.device, buffers=self.buffers):  # all kept alive while it runs
                try:
                    filter_.execute()
                except BaseException as error:  # noqa: BLE001  handed to the waiting thread
                    failed.append(error)
                finally:
                    done.set()

            self.running = done
            threading.Thread(target=work, name="OIDN execute", daemon=True).start()
            while not done.wait(WAIT_SLICE_S):  # a stop signal's exception leaves here
                pass
            self.running = None
            if failed:
                raise failed[0]
        self.check("executing the filter")

    def finish_running(self) -> None:
        """Waits for an execute that a stop signal left running (its buffers are shared)."""
        running, self.running = getattr(self, "running", None), None
        if running is not None:
            running.wait()

    def output(self) -> np.ndarray:
        height, width = self.size
        return self.buffers["output"][:height, :width].copy()

    def __call__(self, color: np.ndarray, albedo: np.ndarray | None = None,
                 normal: np.ndarray | None = None) -> np.ndarray:
        self.set_inputs(color, albedo, normal)
        self.execute()
        return self.output()

    def release_filter(self) -> None:
        self.finish_running()
        if self.filter is not None:
            self.filter.release()
            self.filter, self.key = None, None

    def __del__(self):
        running = getattr(self, "running", None)
        if running is not None and not running.is_set():  # the worker holds the filter and device: left to it
            return
        try:
            self.release_filter()
            self.device.release()
        except Exception:
            pass


class OIDNMethod(DenoisingMethod):
    """Intel Open Image Denoise (:class:`OIDN` above; HDR, the frame's albedo and
    normals as clean auxiliary images, one filter committed per image size).
    With ``temporal``, the input is first accumulated with the back-projected
    history clamped to its 7x7 mean ± k sigma, and OIDN denoises the
    accumulated colour; without, OIDN denoises each frame alone. It never
    demodulates (OIDN takes the albedo itself).

    The accumulation before OIDN keeps more of the current frame and clamps
    more loosely than the one after a spatial filter: OIDN removes the noise
    that lets through (the measurement is in docs/denoising_methods.md).

    :attr:`last_execute_s` and :attr:`last_execute_cpu_s` are the OIDN execute
    calls' wall and CPU time of the last frame (what the benchmark times).
    """
    name = "oidn"
    description = ("Intel Open Image Denoise (HDR, albedo and normals); oidn+temporal: with temporal "
                   "accumulation first")
    demodulates = False
    temporal_defaults = TemporalParams(alpha=0.5, k=3.0)
    quality = Option("oidn_quality", OIDNParams().quality, "OIDN 2's filter quality", kind=str, choices=QUALITIES,
                     group="oidn")
    options = (quality,) + temporal_options(temporal_defaults)
    presets = {q: {"oidn_quality": q} for q in QUALITIES}
    benchmark = tuple(f"oidn-{q}" for q in QUALITIES) + ("oidn+temporal",)

    def __init__(self, **props):
        super().__init__(**props)
        self.params = OIDNParams(quality=self.props["oidn_quality"])
        self.temporal_params = temporal_params(self.props, self.temporal_defaults)
        self.oidn = None  # made on the first frame: checking parameters must not load the library

    def run_oidn(self, color: mi.TensorXf, frame) -> mi.TensorXf:
        """OIDN on ``color`` with the frame's albedo and normals; adds its execute time."""
        if self.oidn is None:
            self.oidn = OIDN(self.params)
        self.oidn.set_inputs(np.array(color, np.float32), frame.albedo, frame.normal)
        start, cpu = time.perf_counter(), time.process_time()
        self.oidn.execute()
        self.last_execute_s += time.perf_counter() - start
        self.last_execute_cpu_s += time.process_time() - cpu
        return mi.TensorXf(self.oidn.output())

    def filter(self, arrays, frame, index, valid):
        self.last_execute_s = self.last_execute_cpu_s = 0.0
        color = accumulated = arrays.tensor(arrays.color)
        if index is not None:
            accumulated = accumulate(color, self.history, index, valid, self.temporal_params,
                                     bounds=self.history_bounds(color, frame))
        self.history = accumulated
        return self.run_oidn(accumulated, frame)

    def history_bounds(self, color: mi.TensorXf, frame) -> mi.TensorXf | None:
        """The hook: the image whose neighbourhood clamps the history (None: ``color``'s own)."""
        return None
