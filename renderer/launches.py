"""A JIT render as a sequence of kernel launches, each bounded by its work.

A kernel cannot be stopped once launched, so Ctrl-C and SIGTERM take effect
between launches: a render stops when the running launch ends (the next one
is traced meanwhile, and launched only if no signal came). A launch is therefore sized by
its *work*, not its sample count: a sample costs up to
:func:`sample_work` ray casts (``(1 + bounces) x (1 + lights)``: facing
mirrors bounce every ray the whole way). The first launch of a split render
holds :data:`FIRST_LAUNCH_WORK` of it; its measured time calibrates the next
ones to :data:`LAUNCH_SECONDS` each.

Calibration holds only if every launch costs what the first one did per
sample, so a launch never covers one part of the image: pixels are visited
in an interleaved order (blocks of :data:`BLOCK` pixels, in a stride
permutation over the whole image). A sample's jitter is a hash of its number
``pixel * spp + k``, so the image is the same however it is split and in
whatever order the pixels come.
"""
from __future__ import annotations

import math
import time

import drjit as dr
import mitsuba as mi
import numpy as np

from core.entry import hold_signals
from core.errors import LimitError

#: Renders of at most this much work (ray casts, see :func:`sample_work`) are
#: one launch: a course image of 800x800 pixels without bounces is
SINGLE_LAUNCH_WORK = 1 << 22
#: The first launch of a split render, in ray casts: short even on a slow,
#: shared machine; later launches aim at LAUNCH_SECONDS each
FIRST_LAUNCH_WORK = 1 << 20
#: short enough that a launch slowed several times by other jobs still ends well within the 2 s
#: a signal may wait
LAUNCH_SECONDS = 0.25
#: Sample indices are 32-bit in the kernel
MAX_SAMPLES = (1 << 32) - 1
#: Pixels visited together (rays of neighbouring pixels stay coherent)
BLOCK = 32

#: SIGINT and SIGTERM take effect between launches: tracing runs Python code
#: inside Dr.Jit's loop recording, which would turn a KeyboardInterrupt raised
#: there into a RuntimeError with a traceback, and a kernel cannot be stopped
#: anyway
signals_between_launches = hold_signals


def sample_work(scene) -> int:
    """Ray casts one sample of ``scene`` may cost at most: a camera ray and
    up to ``bounces`` mirror rays, each shaded by every light (a shadow ray each)."""
    bounces = int(getattr(scene.integrator(), "bounces", 0) or 0)
    return (1 + bounces) * (1 + len(scene.emitters()))


def pixel_order(start: int, count: int, pixels: int) -> np.ndarray:
    """Pixels ``start .. start + count - 1`` of the interleaved order over
    ``pixels`` pixels (uint32): whole blocks of :data:`BLOCK` in a stride
    permutation (consecutive blocks lie far apart), then the pixels left over."""
    blocks = pixels // BLOCK
    slots = np.arange(start, start + count, dtype=np.uint64)
    order = slots.copy()  # the tail beyond the whole blocks keeps its place
    inside = slots < blocks * BLOCK
    if blocks > 1:
        stride = max(int(blocks * 0.6180339887), 1)
        while math.gcd(stride, blocks) != 1:
            stride += 1
        block = (slots[inside] // BLOCK * np.uint64(stride)) % np.uint64(blocks)
        order[inside] = block * np.uint64(BLOCK) + slots[inside] % np.uint64(BLOCK)
    return order.astype(np.uint32)


def render_in_launches(scene, spp: int, jitter: bool, seed: int = 0, launch_samples: int | None = None,
                       sensor=None, progress: bool = True) -> np.ndarray:
    """The image of ``scene`` (JIT variants): RGB, then the integrator's AOVs,
    (H, W, C) float32, each pixel the mean of its ``spp`` samples.

    A launch renders whole pixels (all their samples), or, where one pixel's
    samples are more work than a launch may hold, a part of one pixel's
    samples (summed in float64 until the pixel is complete). Launch inputs
    are opaque, so every launch reuses the first one's compiled kernel.
    ``launch_samples``: a fixed launch size (tests). ``sensor``: another
    camera than the scene's. The integrator gets the sensor's sampler seeded
    per launch; ``whitted`` draws nothing from it.
    """
    sensor = sensor or scene.sensors()[0]
    width, height = (int(v) for v in sensor.film().size())
    pixels = width * height
    total = pixels * spp
    if total > MAX_SAMPLES:
        raise LimitError(f"{width}x{height} pixels x {spp} samples = {total} samples; "
                         f"at most {MAX_SAMPLES} fit in one render")
    channels = 3 + len(scene.integrator().aov_names())
    image = np.zeros((pixels, channels), np.float32)
    work = sample_work(scene)
    split = launch_samples is not None or total * work > SINGLE_LAUNCH_WORK
    size = (launch_samples or max(FIRST_LAUNCH_WORK // work, 1)) if split else total
    slot, within, done = 0, 0, 0  # next pixel of the order, next sample of it, samples read
    partial = np.zeros(channels, np.float64)  # the sum of a pixel rendered in parts
    queued = None  # (pixels, first sample, samples each, values being computed)
    began = time.perf_counter()
    while slot < pixels or queued is not None:
        with signals_between_launches() as held:
            # the next launch is traced while the previous one runs, and
            # launched once that is read, unless a signal came meanwhile
            following = None
            if slot < pixels:
                if within == 0 and size >= spp:
                    count = min(size // spp, pixels - slot)
                    ids, first, each = pixel_order(slot, count, pixels), 0, spp
                    slot += count
                else:
                    ids, first = pixel_order(slot, 1, pixels), within
                    each = min(max(size, 1), spp - within)
                    within += each
                    if within == spp:
                        slot, within = slot + 1, 0
                following = (ids, first, each, trace(scene, sensor, width, spp, jitter, seed, ids, first, each))
            measured = 0  # samples of the launch read now
            if queued is not None:
                ids, first, each, values = queued
                measured = len(ids) * each
                values = read(values, len(ids) * each, channels)
                if each == spp:
                    image[ids] = values if spp == 1 else values.reshape(-1, spp, channels).mean(axis=1,
                                                                                                 dtype=np.float64)
                else:
                    partial += values.sum(axis=0, dtype=np.float64)
                    if first + each == spp:
                        image[ids[0]] = partial / spp
                        partial[:] = 0.0
                done += len(ids) * each
            if following is not None and not held:
                dr.eval(*following[3])  # one kernel for all channels, running in the background until read
        queued = following
        if split and progress and done:  # shown by render.py's progress bar (as Mitsuba's own renders report)
            mi.logger().log_progress(done / total, "Rendering", "", "")
        if split and launch_samples is None and measured:
            # the launch just read ran from the end of the last pass to now: its rate sizes the
            # next one, which grows at most to twice its size (a lagging estimate never overshoots)
            now = time.perf_counter()
            elapsed, began = max(now - began, 1e-3), now
            size = max(int(min(measured * LAUNCH_SECONDS / elapsed, 2 * measured)), 1)
        elif split:
            began = time.perf_counter()
    return image.reshape(height, width, channels)


def trace(scene, sensor, width: int, spp: int, jitter: bool, seed: int, ids: np.ndarray, first: int,
          each: int) -> list:
    """Samples ``first .. first + each - 1`` of each pixel in ``ids``, RGB then
    AOVs, traced (not yet evaluated: ``dr.eval`` of them launches one kernel)."""
    with dr.suspend_grad():
        count = len(ids) * each
        index = dr.arange(mi.UInt32, count)
        slot = index // dr.opaque(mi.UInt32, each)
        pixel = dr.gather(mi.UInt32, mi.UInt32(ids), slot)
        number = pixel * dr.opaque(mi.UInt32, spp) + (index - slot * dr.opaque(mi.UInt32, each)) \
            + dr.opaque(mi.UInt32, first)
        y = pixel // dr.opaque(mi.UInt32, width)
        x = pixel - y * dr.opaque(mi.UInt32, width)
        if jitter:
            bits_x, bits_y = mi.sample_tea_32(number, dr.opaque(mi.UInt32, seed), 16)
            offset = mi.Point2f(mi.Float(bits_x >> 8), mi.Float(bits_y >> 8)) * 2.0 ** -24
        else:
            offset = mi.Point2f(0.5)
        film_size = sensor.film().size()
        position = (mi.Point2f(mi.Float(x), mi.Float(y)) + offset) / mi.ScalarPoint2f(film_size)
        ray, weight = sensor.sample_ray(0.0, 0.5, position, mi.Point2f(0.5))
        sampler = sensor.sampler().clone()
        sampler.seed(dr.opaque(mi.UInt32, (seed * 0x9E3779B1 + int(ids[0]) * spp + first) & 0xFFFFFFFF), count)
        spectrum, _, aovs = scene.integrator().sample(scene, sampler, ray, None, mi.Bool(True))
        spectrum *= weight
        return [spectrum.x, spectrum.y, spectrum.z] + list(aovs)


def read(values: list, count: int, channels: int) -> np.ndarray:
    """The launched channels as (count, channels) float32 (waits for the kernel)."""
    image = np.empty((count, channels), np.float32)
    for k, channel in enumerate(values):
        image[:, k] = np.asarray(channel, np.float32)
    return image
