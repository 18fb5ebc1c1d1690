"""The denoiser's kernels, as Dr.Jit array code of the active Mitsuba variant.

Images are ``mi.TensorXf`` of shape (H, W, C); pixel (x, y) has flat index
``y * W + x``. No loop runs per pixel in Python: each filter is a handful of
kernels over all pixels (a symbolic loop over the window for the bilateral
filter).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from core.errors import UsageError
from imaging.metrics import RELMSE_EPSILON

from .edge_weights import EdgeWeights, edge_coefficients, edge_log_weight, inv_two_sigma_sq
from .fastmath import neg_exp
from .neighbours import ShiftedPlanes, margin_for, usable

#: B3-spline taps of the À-Trous wavelet
B3 = (1.0 / 16.0, 1.0 / 4.0, 3.0 / 8.0, 1.0 / 4.0, 1.0 / 16.0)


def check_positive(owner: str, **values: float) -> None:
    """A one-line :class:`UsageError` naming ``owner`` and the parameter unless
    each of ``values`` is a finite number > 0."""
    for name, value in values.items():
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise UsageError(f"{owner}: {name} must be a finite number > 0, got {value!r}")


def check_whole(owner: str, name: str, value, low: int, high: int) -> None:
    """A one-line :class:`UsageError` unless ``value`` is an int from ``low`` to ``high``."""
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise UsageError(f"{owner}: {name} must be a whole number from {low} to {high}, got {value!r}")


@dataclass(frozen=True)
class BilateralWindow:
    """The plain joint bilateral filter's window: (2 radius + 1)² pixels with a
    spatial weight ``exp(-d²/(2 sigma_coord²))`` (bilateral's options declare and check both)."""
    radius: int = 16
    sigma_coord: float = 32.0


@dataclass(frozen=True)
class TemporalParams:
    """Clamped temporal accumulation ``α·C + (1-α)·clamp(history)``."""
    alpha: float = 0.2  # weight of the current frame; 1 where the history is invalid
    k: float = 1.0  # clamp the history to mean ± k·σ of the current 7x7 neighbourhood
    clamp_radius: int = 3

    def __post_init__(self):  # alpha and k: the options of the accumulation declare and check them
        check_whole("temporal", "clamp_radius", self.clamp_radius, 1, 16)


@dataclass(frozen=True)
class OutlierParams:
    """Outlier removal before filtering: each pixel's luminance clamped to its
    (2 radius + 1)² neighbourhood's mean ± k·σ, the colour scaled along."""
    k: float = 2.0
    radius: int = 3

    def __post_init__(self):  # k: ``--outliers`` declares and checks it
        check_whole("outlier removal", "radius", self.radius, 1, 16)


def _safe_normalize(v: mi.Vector3f) -> mi.Vector3f:
    length = dr.norm(v)
    return dr.select(length > 0.0, v / dr.select(length > 0.0, length, 1.0), 0.0)


def pack(v: mi.Vector3f) -> mi.Float:
    """RGB/XYZ per pixel as consecutive 4-float records (the 4th is padding)."""
    packed = dr.ravel(mi.Vector4f(v.x, v.y, v.z, 0.0))
    dr.eval(packed)
    return packed


#: taps up to this many pixels away read the guides' planes made for the first level (six levels' holes)
GUIDE_REACH = 64
#: floats per pixel of the packed guides: a power of two, so a tap reads them in one packet gather
GUIDE_FLOATS = 8


_COORDINATES: dict = {}


def pixel_coordinates(width: int, height: int) -> tuple[mi.Int32, mi.Int32]:
    """(x, y) of every pixel, flat index ``y * width + x``; made once per size
    and variant (every frame of a sequence has the same)."""
    key = (mi.variant(), width, height)
    if key not in _COORDINATES:
        index = dr.arange(mi.UInt32, width * height)
        x, y = mi.Int32(index % width), mi.Int32(index // width)
        dr.eval(x, y)
        _COORDINATES.clear()  # one size at a time: a sequence does not change size
        _COORDINATES[key] = (x, y)
    return _COORDINATES[key]


class FrameArrays:
    """One frame's buffers as flat Dr.Jit arrays (colour, normal, position), uploaded once per
    frame; :class:`export.frames.FrameData` is the same frame as NumPy arrays, as read from its
    folder. Non-finite colours become 0 and normals are normalised (zero-length ones stay 0), so
    no NaN can spread through the weights. ``albedo``: the albedo the colour was divided by
    (:func:`demodulate`; the result is multiplied by it again), None where it was not."""

    def __init__(self, color: mi.TensorXf, normal: mi.TensorXf, position: mi.TensorXf,
                 albedo: mi.TensorXf | None = None):
        self.height, self.width = color.shape[0], color.shape[1]
        self.albedo = albedo
        c = dr.unravel(mi.Vector3f, color.array)
        self.color = dr.select(dr.isfinite(c), c, 0.0)
        self.normal = _safe_normalize(dr.unravel(mi.Vector3f, normal.array))
        q = dr.unravel(mi.Vector3f, position.array)
        self.position = dr.select(dr.isfinite(q), q, 0.0)
        # one kernel makes them all; left lazy, every level's kernel would redo the
        # normalisation and read the tensors through strided single-float gathers
        dr.eval(self.color, self.normal, self.position)
        self.x, self.y = pixel_coordinates(self.width, self.height)
        self._guide_planes = self._planes = self._guides = None

    @property
    def guides(self) -> mi.Float:
        """Normal and position as one 8-float record a pixel (2 floats of padding), which a tap gathers
        in one packet gather instead of two; packed when first gathered (shifted planes need none)."""
        if self._guides is None:
            n, x, zero = self.normal, self.position, dr.zeros(mi.Float, dr.width(self.normal))
            self._guides = dr.ravel(mi.ArrayXf(n.x, n.y, n.z, x.x, x.y, x.z, zero, zero))
            dr.eval(self._guides)
        return self._guides

    def gather(self, packed: mi.Float, x: mi.Int32, y: mi.Int32, active=None) -> mi.Vector3f:
        """The value at (x, y) of an image packed by :func:`pack`, (x, y)
        clamped to the image: an unmasked gather is cheaper than a masked one,
        and every caller gives taps outside the image the weight 0 anyway."""
        x = dr.clip(x, 0, self.width - 1)
        y = dr.clip(y, 0, self.height - 1)
        v = dr.gather(mi.Vector4f, packed, mi.UInt32(y * self.width + x))
        return mi.Vector3f(v.x, v.y, v.z)

    def gather_guides(self, x: mi.Int32, y: mi.Int32) -> tuple[mi.Vector3f, mi.Vector3f]:
        """(normal, position) at (x, y) clamped to the image, as :meth:`gather`."""
        x = dr.clip(x, 0, self.width - 1)
        y = dr.clip(y, 0, self.height - 1)
        g = dr.gather(mi.ArrayXf, self.guides, mi.UInt32(y * self.width + x), shape=(GUIDE_FLOATS, dr.width(x)))
        return mi.Vector3f(g[0], g[1], g[2]), mi.Vector3f(g[3], g[4], g[5])

    def guide_planes(self, reach: int) -> ShiftedPlanes:
        """Normal and position as :class:`ShiftedPlanes` for taps up to
        ``reach`` pixels away, made once per frame (for :data:`GUIDE_REACH`
        or more: every level of a frame reads the same)."""
        margin = margin_for(self.width, max(reach, GUIDE_REACH))
        if self._guide_planes is None or self._guide_planes.margin < margin:
            self._guide_planes = ShiftedPlanes([self.normal.x, self.normal.y, self.normal.z,
                                                self.position.x, self.position.y, self.position.z], margin)
        return self._guide_planes

    def offer_planes(self, channels: tuple, reach: int, derived: tuple = ()) -> None:
        """Schedules ``channels`` (lazy Dr.Jit Floats), then ``derived`` (values computed
        from them), to be written as :class:`ShiftedPlanes` by the kernel that evaluates
        them (one set kept: a filter's next level reads its level's output). Values with
        a gradient tracked are not offered: the next level gathers them."""
        if usable(*channels):
            self._planes = ShiftedPlanes(channels + derived, margin_for(self.width, reach), keep=channels)

    def planes_of(self, channels: tuple, reach: int, derived: tuple = ()) -> ShiftedPlanes:
        """``channels`` and then ``derived`` (values computed from them) as :class:`ShiftedPlanes`
        for taps up to ``reach`` pixels away: the ones :meth:`offer_planes` scheduled for
        exactly these arrays, else made now (a kernel of their own)."""
        margin = margin_for(self.width, reach)
        if (self._planes is None or not self._planes.made_from(*channels) or self._planes.margin < margin
                or len(self._planes.planes) < len(channels) + len(derived)):
            self._planes = ShiftedPlanes(channels + derived, margin, keep=channels)
        return self._planes

    def tensor(self, color: mi.Vector3f) -> mi.TensorXf:
        return mi.TensorXf(dr.ravel(color), shape=(self.height, self.width, 3))


@dr.syntax
def joint_bilateral(frame: FrameArrays, p: EdgeWeights | None = None, window: BilateralWindow = BilateralWindow()
                    ) -> mi.TensorXf:
    """The assignment's joint bilateral filter over a (2r+1)^2 window: a
    symbolic loop over the window's rows, each row's taps unrolled (less time
    than one loop iteration per tap; the same result)."""
    p = EdgeWeights() if p is None else p
    r = window.radius
    k_coord = inv_two_sigma_sq(window.sigma_coord)  # plain floats: not loop state
    coefficients = edge_coefficients(p, p.sigma_color)
    total = mi.Vector3f(frame.color)  # the centre pixel, weight exp(0) = 1
    color4 = pack(frame.color)
    dr.eval(frame.guides)  # packed before the symbolic loop, which may not evaluate anything
    weights = mi.Float(1.0)
    dy = mi.Int32(-r)
    while dy <= r:
        y = frame.y + dy
        inside_row = (y >= 0) & (y < frame.height)
        for dx in range(-r, r + 1):
            x = frame.x + dx
            inside = inside_row & (x >= 0) & (x < frame.width) & ((dy != 0) | (dx != 0))
            color_j = frame.gather(color4, x, y, inside)
            log_w = (mi.Float(dx * dx + dy * dy) * k_coord
                     + edge_log_weight(coefficients, frame.color, frame.normal, frame.position, color_j,
                                       *frame.gather_guides(x, y)))
            w = dr.select(inside, neg_exp(log_w), 0.0)
            total += w * color_j
            weights += w
        dy += 1
    return frame.tensor(total / weights)


def reproject(position: mi.TensorXf, ids: mi.TensorXf, prev_ids: mi.TensorXf, object_to_world, prev_object_to_world,
              prev_world_to_screen) -> tuple[mi.UInt32, mi.Bool]:
    """Back projection: for each pixel, the flat index of where its surface
    point was in the previous frame, and whether that is valid (on screen,
    in front of the camera, and the same object there).

    ``object_to_world`` and ``prev_object_to_world`` are lists of 4x4 NumPy
    matrices (one per object), ``prev_world_to_screen`` a 4x4 NumPy matrix.
    """
    height, width = position.shape[0], position.shape[1]
    p = dr.unravel(mi.Point3f, position.array)
    obj = mi.Int32(ids.array)
    count = len(object_to_world)
    # per object: the previous frame's world from this frame's world, then the screen;
    # an object whose matrix cannot be inverted, or whose product is beyond float32
    # (a camera dollied far away), has no history (NaN: invalid below)
    def to_previous(k: int) -> np.ndarray:
        current = np.asarray(object_to_world[k], np.float64)
        if not np.all(np.isfinite(current)) or abs(np.linalg.det(current)) < 1e-30:
            return np.full((4, 4), np.nan)
        with np.errstate(over="ignore", invalid="ignore"):
            product = (np.asarray(prev_world_to_screen, np.float64) @ np.asarray(prev_object_to_world[k], np.float64)
                       @ np.linalg.inv(current))
        return product if np.all(np.abs(product) < np.finfo(np.float32).max) else np.full((4, 4), np.nan)

    to_prev = np.stack([to_previous(k) for k in range(count)]) if count else np.zeros((0, 4, 4))
    table = mi.Float(to_prev.astype(np.float32).ravel()) if count else mi.Float(0.0)
    valid = (obj >= 0) & (obj < count)
    base = mi.UInt32(dr.select(valid, obj, 0)) * 16
    rows = [[dr.gather(mi.Float, table, base + 4 * i + j, valid) for j in range(4)] for i in range(4)]
    sx = rows[0][0] * p.x + rows[0][1] * p.y + rows[0][2] * p.z + rows[0][3]
    sy = rows[1][0] * p.x + rows[1][1] * p.y + rows[1][2] * p.z + rows[1][3]
    sw = rows[3][0] * p.x + rows[3][1] * p.y + rows[3][2] * p.z + rows[3][3]
    valid &= sw > 0.0
    px = dr.floor(sx / dr.select(valid, sw, 1.0))
    py = dr.floor(sy / dr.select(valid, sw, 1.0))
    valid &= dr.isfinite(px) & dr.isfinite(py) & (px >= 0) & (px < width) & (py >= 0) & (py < height)
    index = dr.select(valid, mi.UInt32(mi.Int32(py)) * width + mi.UInt32(mi.Int32(px)), 0)
    valid &= mi.Int32(dr.gather(mi.Float, prev_ids.array, index, valid)) == obj
    return index, valid


def clamp_box(color: mi.TensorXf, radius: int = 3) -> tuple[mi.Vector3f, mi.Vector3f]:
    """Mean and standard deviation of each pixel's (2r+1)^2 neighbourhood (inside
    the image), computed around the centre value so that HDR values with small
    noise do not cancel (no negative variance).

    Separable: a horizontal pass sums ``c_q - c_r`` and ``(c_q - c_r)²`` along
    each row around ``r``; the vertical pass moves those sums to the centre
    ``p`` with ``Σ(c_q - c_p) = Σ(c_q - c_r) + n (c_r - c_p)`` and
    ``Σ(c_q - c_p)² = Σ(c_q - c_r)² + 2 (c_r - c_p) Σ(c_q - c_r) + n (c_r - c_p)²``,
    so every term stays a difference: 2 (2r+1) taps instead of (2r+1)². ``n``,
    the columns inside the image, is the same for every row of a column, so
    a row's record is its two sums alone (one 8-float packet per tap).
    Where no gradient is tracked, both passes read shifted planes instead
    (:mod:`denoise.neighbours`; the same result, bit for bit)."""
    height, width = color.shape[0], color.shape[1]
    c = dr.unravel(mi.Vector3f, color.array)
    shifted = usable(c)
    if shifted:
        planes = ShiftedPlanes([c.x, c.y, c.z], margin_for(width, radius))
        dr.eval(c)  # with the planes, in one kernel
    else:
        c4 = pack(c)
    x0, y0 = pixel_coordinates(width, height)
    row_sum, row_sq = mi.Vector3f(0.0), mi.Vector3f(0.0)
    for dx in range(-radius, radius + 1):
        if dx == 0:  # c_r - c_r
            continue
        x = x0 + dx
        inside = (x >= 0) & (x < width)
        if shifted:
            v = mi.Vector3f(planes.at(0, dx), planes.at(1, dx), planes.at(2, dx))
        else:
            v = dr.gather(mi.Vector4f, c4, mi.UInt32(y0 * width + dr.clip(x, 0, width - 1)))
            v = mi.Vector3f(v.x, v.y, v.z)
        d = dr.select(inside, v - c, 0.0)
        row_sum += d
        row_sq += d * d
    if shifted:
        sums = ShiftedPlanes([row_sum.x, row_sum.y, row_sum.z, row_sq.x, row_sq.y, row_sq.z],
                             margin_for(width, radius))
    else:
        sums = dr.ravel(mi.ArrayXf(row_sum.x, row_sum.y, row_sum.z, row_sq.x, row_sq.y, row_sq.z, 0.0, 0.0))
        dr.eval(sums)
    n = mi.Float(dr.minimum(x0 + radius, width - 1) - dr.maximum(x0 - radius, 0) + 1)
    total, total_sq, rows = mi.Vector3f(0.0), mi.Vector3f(0.0), mi.Float(0.0)
    for dy in range(-radius, radius + 1):
        y = y0 + dy
        inside = (y >= 0) & (y < height)
        if shifted:
            s = [sums.at(k, dy * width) for k in range(6)]
            r = mi.Vector3f(planes.at(0, dy * width), planes.at(1, dy * width), planes.at(2, dy * width))
        else:
            j = mi.UInt32(dr.clip(y, 0, height - 1) * width + x0)  # clamped, unmasked; outside rows selected away
            s = dr.gather(mi.ArrayXf, sums, j, shape=(8, width * height))
            r = dr.gather(mi.Vector4f, c4, j)
            r = mi.Vector3f(r.x, r.y, r.z)
        row_s, row_q = mi.Vector3f(s[0], s[1], s[2]), mi.Vector3f(s[3], s[4], s[5])
        if dy == 0:  # the centre's own row: c_r = c_p
            total += row_s
            total_sq += row_q
            rows += 1.0
            continue
        offset = r - c
        total += dr.select(inside, row_s + n * offset, 0.0)
        total_sq += dr.select(inside, row_q + 2.0 * offset * row_s + n * offset * offset, 0.0)
        rows += dr.select(inside, 1.0, 0.0)
    count = n * rows
    mean_offset = total / count
    variance = dr.maximum(total_sq / count - mean_offset * mean_offset, 0.0)
    mean, sigma = c + mean_offset, dr.sqrt(variance)
    if shifted:  # read while the planes are held (see denoise.neighbours)
        dr.eval(mean, sigma)
    return mean, sigma


def box_mean(values: mi.Float, width: int, height: int, radius: int) -> mi.Float:
    """Mean of ``values`` (one channel, row order) over each pixel's (2r+1)² box
    inside the image: :func:`clamp_box`'s mean without its σ, for a caller that
    needs no more. Separable (a row pass, then a column pass over the row sums),
    through shifted planes where no gradient is tracked, else gathers."""
    x0, y0 = pixel_coordinates(width, height)
    shifted = usable(values)
    if shifted:
        planes = ShiftedPlanes([values], margin_for(width, radius))
        dr.eval(values)  # with the planes, in one kernel
    row_sum = mi.Float(0.0)
    for dx in range(-radius, radius + 1):
        x = x0 + dx
        if shifted:
            v = planes.at(0, dx)
        else:
            v = dr.gather(mi.Float, values, mi.UInt32(y0 * width + dr.clip(x, 0, width - 1)))
        row_sum += dr.select((x >= 0) & (x < width), v, 0.0)
    if shifted:
        sums = ShiftedPlanes([row_sum], margin_for(width, radius))
    else:
        dr.eval(row_sum)
    total, rows = mi.Float(0.0), mi.Float(0.0)
    for dy in range(-radius, radius + 1):
        y = y0 + dy
        inside = (y >= 0) & (y < height)
        if shifted:
            s = sums.at(0, dy * width)
        else:
            s = dr.gather(mi.Float, row_sum, mi.UInt32(dr.clip(y, 0, height - 1) * width + x0))
        total += dr.select(inside, s, 0.0)
        rows += dr.select(inside, 1.0, 0.0)
    mean = total / (mi.Float(dr.minimum(x0 + radius, width - 1) - dr.maximum(x0 - radius, 0) + 1) * rows)
    if shifted:  # read while the planes are held (see denoise.neighbours)
        dr.eval(mean)
    return mean


def accumulate(current: mi.TensorXf, previous: mi.TensorXf | None, index: mi.UInt32 | None, valid: mi.Bool | None,
               p: TemporalParams = TemporalParams(), bounds: mi.TensorXf | None = None) -> mi.TensorXf:
    """``α·C_i + (1-α)·clamp(C̄_{i-1})`` with the history clamped to mean ± k·σ of
    the current neighbourhood (of ``bounds`` where given: an estimate of the
    current frame less noisy than ``current``); α = 1 where the history is invalid."""
    c = dr.unravel(mi.Vector3f, current.array)
    if previous is None:
        return current
    history = dr.gather(mi.Vector3f, dr.unravel(mi.Vector3f, previous.array), index, valid)
    mean, sigma = clamp_box(current if bounds is None else bounds, p.clamp_radius)
    history = dr.clip(history, mean - p.k * sigma, mean + p.k * sigma)
    alpha = dr.select(valid & dr.all(dr.isfinite(history)), p.alpha, 1.0)
    out = alpha * c + (1.0 - alpha) * history
    return mi.TensorXf(dr.ravel(out), shape=current.shape)


def luminance(c: mi.Vector3f) -> mi.Float:
    """Rec. 709 luminance of linear RGB."""
    return dr.fma(c.z, 0.0722, dr.fma(c.y, 0.7152, c.x * 0.2126))  # 3 operations, not 5


def remove_outliers(color: mi.TensorXf, p: OutlierParams = OutlierParams()) -> mi.TensorXf:
    """Each pixel's luminance clamped to mean ± k·σ of its (2r+1)² neighbourhood
    (inside the image, the pixel included), its colour scaled by the same
    factor (a pixel of luminance <= 0 keeps its colour). Statistics are taken
    around the centre value, as in :func:`clamp_box`."""
    height, width = color.shape[0], color.shape[1]
    c = dr.unravel(mi.Vector3f, color.array)
    c = dr.select(dr.isfinite(c), c, 0.0)
    lum = luminance(c)
    dr.eval(lum)
    x0, y0 = pixel_coordinates(width, height)
    total, total_sq, count = mi.Float(0.0), mi.Float(0.0), mi.Float(0.0)
    for dy in range(-p.radius, p.radius + 1):
        for dx in range(-p.radius, p.radius + 1):
            x, y = x0 + dx, y0 + dy
            inside = (x >= 0) & (x < width) & (y >= 0) & (y < height)
            d = dr.select(inside, dr.gather(mi.Float, lum, mi.UInt32(y * width + x), inside) - lum, 0.0)
            total += d
            total_sq += d * d
            count += dr.select(inside, 1.0, 0.0)
    mean_offset = total / count
    sigma = dr.sqrt(dr.maximum(total_sq / count - mean_offset * mean_offset, 0.0))
    mean = lum + mean_offset
    clamped = dr.clip(lum, mean - p.k * sigma, mean + p.k * sigma)
    scale = dr.select(lum > 0.0, clamped / dr.select(lum > 0.0, lum, 1.0), 1.0)
    return mi.TensorXf(dr.ravel(c * scale), shape=color.shape)


#: below this albedo (per channel) demodulation leaves the colour as it is
ALBEDO_EPSILON = 1e-3


def albedo_factor(albedo: mi.TensorXf) -> mi.Float:
    """What :func:`demodulate` divides by and :func:`remodulate` multiplies by, value by
    value: the albedo, 1 in place of one below :data:`ALBEDO_EPSILON` (background, black surfaces)."""
    a = albedo.array
    return dr.select(a > ALBEDO_EPSILON, a, 1.0)


def demodulate(color: mi.TensorXf, albedo: mi.TensorXf) -> mi.TensorXf:
    """``colour / albedo`` per channel (:func:`albedo_factor`)."""
    return mi.TensorXf(color.array / albedo_factor(albedo), shape=color.shape)


def remodulate(color: mi.TensorXf, albedo: mi.TensorXf) -> mi.TensorXf:
    """The inverse of :func:`demodulate`."""
    return mi.TensorXf(color.array * albedo_factor(albedo), shape=color.shape)


def relmse_loss(image: mi.TensorXf, reference: mi.TensorXf, epsilon: float = RELMSE_EPSILON) -> mi.Float:
    """:func:`imaging.metrics.relmse` as a differentiable Dr.Jit Float: the loss of asvgf's fit and of the training."""
    return dr.mean(dr.square(image.array - reference.array) / (dr.square(reference.array) + epsilon))
