"""A filter's neighbour reads as plain vector loads instead of gathers.

An image's channels are copied into planes, each padded at both ends by
``margin`` pixels of zeros. The neighbour at flat offset ``o`` (``dy * width
+ dx``) of every pixel is then the plane itself shifted by ``o``:
:meth:`ShiftedPlanes.at` returns it as a Dr.Jit array mapped onto the plane's
memory at that offset (through NumPy, no copy), which a kernel reads with
contiguous loads, where a gather needs an index, a clamp and a transposing
shuffle per record (``benchmarks.roofline`` measures both).

The contract a caller keeps: a tap outside the image (``dx`` past a row's
end wraps into the next row; past the first or last row reads the zero
padding) reads some finite value of the planes, not the clamped pixel a
gather would read; so every caller gives such taps the weight 0 with a
``dr.select`` (which also discards any NaN their weight's arithmetic makes),
and the channels written must be finite. ``|o|`` is at most ``margin``.

A plane's memory goes back to a pool when its :class:`ShiftedPlanes` is
dropped, and the next planes of that length write into it: so every kernel
that reads planes is launched (``dr.eval``) while they are held; Dr.Jit
runs kernels in launch order.

The mapped arrays carry no derivatives and are read from memory: a filter
uses them only where no gradient is tracked (:func:`usable`), never inside
``dr.freeze`` (reading the planes waits for the kernel that writes them).
"""
from __future__ import annotations

import threading
from collections.abc import Sequence

import drjit as dr
import mitsuba as mi

#: False: every neighbour read is a gather (the A/B of the speed checks, the tests' comparison)
ENABLED = True


def usable(*values) -> bool:
    """Whether neighbour reads for a result made of ``values`` may be shifted planes: enabled, an
    LLVM variant (its arrays are the host memory NumPy maps; a CUDA array's
    ``numpy()`` is a copy) and no gradient tracked."""
    return (ENABLED and dr.backend_v(mi.Float) == dr.JitBackend.LLVM
            and not any(dr.grad_enabled(v) for v in values))


def margin_for(width: int, reach: int) -> int:
    """The padding that taps up to ``reach`` pixels away in x and y need."""
    return reach * (width + 1)


class Plane:
    """One zero-padded plane's memory: a Dr.Jit array, its NumPy view and the
    arrays mapped onto it at each offset asked for so far (kept: a mapped array
    freed costs the queue a task that releases its NumPy owner)."""

    def __init__(self, length: int):
        self.array = dr.zeros(mi.Float, length)
        dr.make_opaque(self.array)
        self.view = self.array.numpy()  # no copy: the array's memory (waits for the queued kernels, once)
        self.mapped = {}

    def at(self, start: int, pixels: int) -> mi.Float:
        """``pixels`` values from ``start`` on, as a Dr.Jit array mapped onto this memory."""
        key = (start, pixels)
        if key not in self.mapped:
            self.mapped[key] = mi.Float(self.view[start:start + pixels])
        return self.mapped[key]


#: planes no ShiftedPlanes holds, by thread and length, for the next planes of that length.
#: By thread: Dr.Jit orders the kernels of one thread, not those of two
FREE: dict[tuple[int, int], list[Plane]] = {}


def take(pixels: int, length: int) -> Plane:
    """A plane of ``length`` floats from this thread's :data:`FREE`, else a new
    one. This thread's planes of another image size are dropped (a sequence
    keeps its size)."""
    thread = threading.get_ident()
    for key in [k for k in FREE if k[0] == thread and FREE[k] and FREE[k][0].pixels != pixels]:
        del FREE[key]
    free = FREE.get((thread, length))
    plane = free.pop() if free else Plane(length)
    plane.pixels, plane.thread = pixels, thread
    return plane


class ShiftedPlanes:
    """``channels`` (Dr.Jit Floats of one width each) as zero-padded planes.

    Each plane is memory of its own, taken from the planes of earlier frames
    where one of its length is free (its mapped arrays made once: no new
    NumPy view, no wait for the queue), and given back when these planes are
    dropped. The values are scattered in as side effects of whichever kernel
    evaluates next at this width (the kernel that computes them, when they
    are a level's lazy output); Dr.Jit runs kernels in order, so a plane is
    written only after every kernel that read it before. Scatters into one
    array would each be a kernel of their own, hence a plane per channel.
    ``keep`` holds arrays alive with the planes (see :meth:`made_from`)."""

    def __init__(self, channels: Sequence[mi.Float], margin: int, keep: Sequence = ()):
        if any(dr.grad_enabled(values) for values in channels):
            # a scatter of tracked values would replace the plane's array, not write its mapped memory
            raise ValueError("shifted planes of values with a gradient tracked")
        self.pixels = dr.width(channels[0])
        self.margin = margin
        self.planes = [take(self.pixels, self.pixels + 2 * margin) for _ in channels]
        where = dr.arange(mi.UInt32, self.pixels) + margin
        for plane, values in zip(self.planes, channels):
            dr.scatter(plane.array, values, where)  # in place: the memory mapped (the padding stays 0)
        self._filled = False
        # the arrays the planes were made from, by Dr.Jit variable: held, so that no
        # other array can take their indices while the planes exist
        self.keep = tuple(keep)
        self.sources = tuple(v.index for v in self.keep)

    def __del__(self):
        for plane in getattr(self, "planes", ()):
            FREE.setdefault((plane.thread, len(plane.view)), []).append(plane)

    def made_from(self, *values) -> bool:
        """Whether these are the planes of exactly ``values`` (as given in ``keep``)."""
        return tuple(v.index for v in values) == self.sources

    def at(self, channel: int, offset: int) -> mi.Float:
        """Plane ``channel`` at flat offset ``offset``: the value of pixel ``i + offset`` at lane ``i``."""
        if abs(offset) > self.margin:
            raise ValueError(f"offset {offset} beyond the planes' margin {self.margin}")
        if not self._filled:  # the scatters run before any kernel that reads the planes (no-op when they ran)
            dr.eval(*(plane.array for plane in self.planes))
            self._filled = True
        return self.planes[channel].at(self.margin + offset, self.pixels)
