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

The mapped arrays carry no derivatives and are read from memory: a filter
uses them only where no gradient is tracked (:func:`usable`), never inside
``dr.freeze`` (reading the planes waits for the kernel that writes them).
"""
from __future__ import annotations

from collections.abc import Sequence

import drjit as dr
import mitsuba as mi

#: False: every neighbour read is a gather (the A/B of the speed checks, the tests' comparison)
ENABLED = True


def usable(*values) -> bool:
    """Whether neighbour reads of ``values`` may be shifted planes: enabled, an
    LLVM variant (its arrays are the host memory NumPy maps; a CUDA array's
    ``numpy()`` is a copy) and no gradient tracked."""
    return (ENABLED and dr.backend_v(mi.Float) == dr.JitBackend.LLVM
            and not any(dr.grad_enabled(v) for v in values))


def margin_for(width: int, reach: int) -> int:
    """The padding that taps up to ``reach`` pixels away in x and y need."""
    return reach * (width + 1)


class ShiftedPlanes:
    """``channels`` (Dr.Jit Floats of one width each) as zero-padded planes.

    Each plane is its own array, so that the scatters filling them are side
    effects of whichever kernel evaluates next at this width (the kernel that
    computes the values writes the planes too; scatters into one array would
    each be a kernel of their own). ``keep`` holds arrays alive with the
    planes (see :meth:`made_from`)."""

    def __init__(self, channels: Sequence[mi.Float], margin: int, keep: Sequence = ()):
        self.pixels = dr.width(channels[0])
        self.margin = margin
        where = dr.arange(mi.UInt32, self.pixels) + margin
        self.planes = []
        for values in channels:
            plane = dr.zeros(mi.Float, self.pixels + 2 * margin)
            dr.make_opaque(plane)
            dr.scatter(plane, values, where)
            self.planes.append(plane)
        # the arrays the planes were made from, by Dr.Jit variable: held, so that no
        # other array can take their indices while the planes exist
        self.keep = tuple(keep)
        self.sources = tuple(v.index for v in self.keep)
        self._views = None

    def made_from(self, *values) -> bool:
        """Whether these are the planes of exactly ``values`` (as given in ``keep``)."""
        return tuple(v.index for v in values) == self.sources

    def at(self, channel: int, offset: int) -> mi.Float:
        """Plane ``channel`` at flat offset ``offset``: the value of pixel ``i + offset`` at lane ``i``."""
        if abs(offset) > self.margin:
            raise ValueError(f"offset {offset} beyond the planes' margin {self.margin}")
        if self._views is None:  # no copy: each plane's memory, once its kernel has run
            self._views = [plane.numpy() for plane in self.planes]
        start = self.margin + offset
        return mi.Float(self._views[channel][start:start + self.pixels])
