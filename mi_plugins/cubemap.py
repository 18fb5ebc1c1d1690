from __future__ import annotations

from pathlib import Path

import drjit as dr
import mitsuba as mi

from imaging.image_io import read_cube_map


class CubeMapEmitter(mi.Emitter):
    r"""
    .. _emitter-course_cubemap:

    Course cube map background (:monosp:`course_cubemap`)
    -------------------------------------------------------

    .. pluginparameters::

     * - folder
       - |string|
       - Folder holding ``left.png right.png up.png down.png front.png
         back.png``, six square faces of equal size (8-bit RGB, values / 255,
         no gamma decoding)

     * - scale
       - |float|
       - Factor on the radiance (Default: 1)

    An infinitely distant environment with the course's cube-map lookup: the
    face is the direction's dominant axis (ties go to x, then y), the face
    coordinates follow the course's orientation per face, and texels are
    interpolated bilinearly with the course's convention (texel :math:`k`
    covers :math:`[k, k+1)` and is sampled at its corner, indices clamped at
    the face's edges). ``eval`` returns the texel seen along :math:`-\omega_i`.

    Sampling is uniform over the sphere, which is enough for a background that
    Whitted-style integrators look up and path tracers hit.
    """

    def __init__(self, props: mi.Properties):
        super().__init__(props)
        # relative to the XML file's folder when loaded from XML
        self.folder = Path(str(mi.file_resolver().resolve(props.get("folder"))))
        faces = read_cube_map(self.folder)  # (6, N, N, 4) uint8 RGBX, faces in CUBE_FACES order
        self.size = faces.shape[1]
        self.scale = float(props.get("scale", 1.0))
        # One little-endian 32-bit word per texel (R | G << 8 | B << 16 | X << 24):
        # one gather per bilinear tap
        packed = faces.reshape(-1).view("<u4")
        self.texels = mi.TensorXu(packed)
        self.m_flags = mi.EmitterFlags.Infinite | mi.EmitterFlags.SpatiallyVarying
        # scalar variants name the scalar type without the "Scalar" prefix
        sphere = getattr(mi, "ScalarBoundingSphere3f", None) or mi.BoundingSphere3f
        self.bsphere = sphere(mi.ScalarPoint3f(0.0), 1.0)

    def set_scene(self, scene: mi.Scene):
        bbox = scene.bbox()
        if bbox.valid():
            self.bsphere = bbox.bounding_sphere()
        self.bsphere.radius = dr.maximum(1e-3, 1.5 * self.bsphere.radius)

    def lookup(self, d: mi.Vector3f, active: bool = True) -> mi.Color3f:
        """The course's ``CubeMap::getTexel`` for world direction ``d``."""
        d = dr.normalize(d)
        ax, ay, az = dr.abs(d.x), dr.abs(d.y), dr.abs(d.z)
        x_major = (ax >= ay) & (ax >= az)
        # (no "~": scalar variants use Python bools)
        y_major = ((ax < ay) | (ax < az)) & (ay >= az)
        z_major = (ax < az) & (ay < az)
        # dominant component, and the two others in the face's (u, v) order
        major = dr.select(x_major, d.x, dr.select(y_major, d.y, d.z))
        a = dr.select(x_major, d.z, d.x)
        b = dr.select(x_major, d.y, dr.select(y_major, d.z, d.y))
        u = 0.5 * (a / major + 1.0)
        v = 0.5 * (b / major + 1.0)
        u = dr.select((y_major & (d.y < 0.0)) | (z_major & (d.z > 0.0)), 1.0 - u, u)
        v = dr.select(major < 0.0, 1.0 - v, v)
        face = dr.select(x_major, dr.select(d.x > 0.0, mi.UInt32(1), mi.UInt32(0)),
                         dr.select(y_major, dr.select(d.y > 0.0, mi.UInt32(2), mi.UInt32(3)),
                                   dr.select(d.z > 0.0, mi.UInt32(4), mi.UInt32(5))))
        n = self.size
        x = u * n
        y = (1.0 - v) * n  # image row, 0 at the top of the face picture
        ix, iy = mi.Int32(dr.floor(x)), mi.Int32(dr.floor(y))
        alpha, beta = x - mi.Float(ix), y - mi.Float(iy)
        base = face * (n * n)

        unit = self.scale / 255.0

        def texel(i, j):
            index = base + mi.UInt32(dr.clip(j, 0, n - 1)) * n + mi.UInt32(dr.clip(i, 0, n - 1))
            word = self.texels.array[index]  # a gather (indexing works in scalar variants too)
            return mi.Color3f(mi.Float(word & 0xFF), mi.Float((word >> 8) & 0xFF),
                              mi.Float((word >> 16) & 0xFF)) * unit

        return ((1.0 - alpha) * (1.0 - beta) * texel(ix, iy) + alpha * (1.0 - beta) * texel(ix + 1, iy)
                + (1.0 - alpha) * beta * texel(ix, iy + 1) + alpha * beta * texel(ix + 1, iy + 1))

    def eval(self, si: mi.SurfaceInteraction3f, active: bool = True) -> mi.Color3f:
        return dr.select(active, self.lookup(-si.wi, active), 0.0)

    def sample_direction(self, it: mi.Interaction3f, sample: mi.Point2f, active: bool = True):
        d = mi.warp.square_to_uniform_sphere(sample)
        # a scalar variant cannot dr.zeros() a record that holds an emitter pointer; its constructor zeros it
        ds = dr.zeros(mi.DirectionSample3f) if dr.is_jit_v(mi.Float) else mi.DirectionSample3f()
        ds.p = it.p + d * (2.0 * self.bsphere.radius)
        ds.n = -d
        ds.d = d
        ds.dist = mi.Float(dr.inf)
        ds.pdf = mi.warp.square_to_uniform_sphere_pdf(d)
        ds.delta = mi.Bool(False)
        ds.emitter = mi.EmitterPtr(self) if dr.is_jit_v(mi.Float) else self
        return ds, dr.select(active, self.lookup(d, active) / ds.pdf, 0.0)

    def pdf_direction(self, it: mi.Interaction3f, ds: mi.DirectionSample3f, active: bool = True) -> mi.Float:
        return dr.select(active, mi.warp.square_to_uniform_sphere_pdf(ds.d), 0.0)

    def eval_direction(self, it: mi.Interaction3f, ds: mi.DirectionSample3f, active: bool = True):
        return dr.select(active, self.lookup(ds.d, active), 0.0)

    def sample_ray(self, time, sample1, sample2, sample3, active=True):
        d = mi.warp.square_to_uniform_sphere(sample2)
        offset = mi.warp.square_to_uniform_disk_concentric(sample3)
        frame = mi.Frame3f(-d)
        origin = self.bsphere.center + (frame.to_world(mi.Vector3f(offset.x, offset.y, 0.0)) + d) * self.bsphere.radius
        weight = self.lookup(d, active) * (4.0 * dr.pi * dr.pi * dr.square(self.bsphere.radius))
        return mi.Ray3f(origin, -d, time), dr.select(active, weight, 0.0)

    def traverse(self, callback):
        callback.put("data", self.texels, mi.ParamFlags.NonDifferentiable)

    def to_string(self):
        return f"CubeMapEmitter[folder = {self.folder}, size = {self.size}]"
