from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import re

from .aovs import AOV_CHANNELS, OBJECT_ID_PREFIX, parse_aovs

#: the longest ray (Mitsuba's "largest" float32)
FLOAT32_MAX = float(np.finfo(np.float32).max)

_OBJECT_ID = re.compile(OBJECT_ID_PREFIX + r"(\d+)(?:_part\d+)?")


def object_index(shape: mi.Shape, position: int) -> int:
    """Object id of a shape: ``k`` from its id ``object_<k>`` or ``object_<k>_part<j>``
    (the converter's names), else its position in the scene."""
    match = _OBJECT_ID.fullmatch(shape.id())
    return int(match.group(1)) if match else position


class WhittedIntegrator(mi.SamplingIntegrator):
    r"""
    .. _integrator-whitted:

    Whitted ray tracer (:monosp:`whitted`)
    ---------------------------------------

    .. pluginparameters::

     * - max_depth
       - |int|
       - Number of mirror bounces (the course's ``-bounces``); 0 is plain ray
         casting (Default: 0)

     * - shadows
       - |bool|
       - Trace a shadow ray to every light (the course's ``-shadows``)
         (Default: |false|)

     * - ambient
       - |rgb|
       - Ambient light, multiplied by each surface's diffuse reflectance
         (Default: 0)

     * - ray_epsilon
       - |float|
       - Secondary (mirror and shadow) rays ignore hits closer than this
         distance, on top of Mitsuba's floating-point-safe ray offset. The
         course's solution skips hits within a small distance, which decides
         what grazing mirror rays see; the scene converter sets this to a
         fixed fraction of the scene's size, so the image does not change
         when the whole scene is scaled (Default: 0)

     * - stats
       - |bool|
       - Count the rays this integrator traces (camera, shadow, mirror rays
         per depth, environment lookups) into :attr:`counters`; the counting
         adds atomics to the kernel, so it is off by default (Default: |false|)

     * - aovs
       - |string|
       - Comma-separated AOVs of the first hit: ``depth`` (ray distance, 0
         on a miss), ``normal`` (world shading normal, 0 on a miss),
         ``position`` (world, 0 on a miss), ``albedo`` (diffuse reflectance)
         and ``id`` (object index, -1 on a miss) (Default: none)

    The course's recursive ray tracer. At each hit it adds the ambient term and,
    for every point or directional light, the BSDF's response towards the
    light times the light's radiance (zero when a shadow ray is blocked); a
    ray that hits nothing returns the scene's environment emitter (a colour or
    a cube map) or black. The ideal mirror direction is then followed with
    the weight of the BSDF's delta-reflection lobe, up to ``max_depth`` times.

    The traced kernel is specialised to the scene: the lights are unrolled by
    kind, and no shadow ray, mirror loop, environment lookup or AOV is traced
    unless the flags and the scene need it. The mirror loop is a symbolic loop
    that ends as soon as no lane continues.

    .. tabs::

        .. code-tab:: python

            'type': 'whitted', 'max_depth': 4, 'shadows': True,
            'ambient': {'type': 'rgb', 'value': [0.1, 0.1, 0.1]}, 'aovs': 'depth,normal'
    """

    def __init__(self, props: mi.Properties):
        super().__init__(props)
        self.max_depth = int(props.get("max_depth", 0))
        if self.max_depth < 0:
            raise ValueError(f"whitted: max_depth must be >= 0, got {self.max_depth}")
        self.shadows = bool(props.get("shadows", False))
        ambient = props.get("ambient", mi.ScalarColor3f(0.0))
        self.ambient = mi.ScalarColor3f(ambient)
        self.has_ambient = any(float(self.ambient[k]) != 0.0 for k in range(3))
        self.aovs = parse_aovs(props.get("aovs", ""))
        self.ray_epsilon = float(props.get("ray_epsilon", 0.0))
        self.stats = bool(props.get("stats", False))
        self.counters = None
        if not self.ray_epsilon >= 0.0:
            raise ValueError(f"whitted: ray_epsilon must be >= 0, got {self.ray_epsilon}")

    def aov_names(self) -> list[str]:
        return [channel for name in self.aovs for channel in AOV_CHANNELS[name]]

    # -- scene analysis (trace time) ----------------------------------------
    def analyse(self, scene: mi.Scene) -> tuple[list[mi.Emitter], bool, dict[str, int]]:
        """(delta lights, any mirror lobe, shape id -> object id) of ``scene``;
        computed once per scene (scalar variants call the integrator once per ray)."""
        key = id(scene)
        if getattr(self, "_analysed", (None,))[0] != key:
            shapes = scene.shapes()
            lights = [e for e in scene.emitters() if mi.has_flag(e.flags(), mi.EmitterFlags.Delta)]
            mirrors = any(s.bsdf() is not None and mi.has_flag(s.bsdf().flags(), mi.BSDFFlags.DeltaReflection)
                          for s in shapes)
            ids = {s.id(): object_index(s, position) for position, s in enumerate(shapes)}
            self._analysed = (key, lights, mirrors, ids)
        return self._analysed[1:]

    def delta_lights(self, scene: mi.Scene) -> list[mi.Emitter]:
        return self.analyse(scene)[0]

    def recursion_enabled(self, scene: mi.Scene) -> bool:
        return self.max_depth > 0 and self.analyse(scene)[1]

    # -- ray statistics ------------------------------------------------------
    #: counter slots: camera, shadow, environment, then mirror rays of depth 1..max_depth
    CAMERA, SHADOW, ENVIRONMENT, MIRROR = 0, 1, 2, 3

    def count(self, slot, mask) -> None:
        """Adds the number of active lanes of ``mask`` to counter ``slot`` (if ``stats``)."""
        if not self.stats:
            return
        if dr.is_jit_v(mi.Float):
            dr.scatter_reduce(dr.ReduceOp.Add, self.counters, mi.UInt32(1), mi.UInt32(slot), mask)
        elif mask:
            self.counters[int(slot)] += 1

    def ray_counts(self) -> dict[str, int | list[int]]:
        """Counts of the last render(s) since :meth:`reset_counts` (``stats`` on)."""
        values = [int(v) for v in (np.array(self.counters) if self.counters is not None else [])]
        if not values:
            return {}
        return {"camera": values[self.CAMERA], "shadow": values[self.SHADOW],
                "environment": values[self.ENVIRONMENT], "mirror_by_depth": values[self.MIRROR:]}

    def reset_counts(self) -> None:
        size = self.MIRROR + self.max_depth
        self.counters = dr.zeros(mi.UInt32, size) if dr.is_jit_v(mi.Float) else [0] * size

    # -- kernels ------------------------------------------------------------
    def spawn(self, si: mi.SurfaceInteraction3f, direction: mi.Vector3f = None,
              target: mi.Point3f = None) -> mi.Ray3f:
        """A secondary ray from ``si`` along ``direction`` or towards ``target``
        that skips hits closer than ``ray_epsilon``.

        Without ``ray_epsilon`` this is Mitsuba's ``spawn_ray[_to]``. With it,
        the ray starts at the hit point moved ``ray_epsilon`` along the ray, as
        in the course; only where that distance is not well above the rounding
        error of the hit point (~1e-7 of its coordinates) is the point first
        nudged off the surface, by a few units of that rounding error. Unlike
        Mitsuba's own offset, which never goes below ~1e-4 (as large as a
        scene of that size), both scale with the scene.
        """
        if self.ray_epsilon == 0.0:
            return si.spawn_ray(direction) if target is None else si.spawn_ray_to(target)
        reference = target - si.p if target is not None else direction
        magnitude = dr.max(dr.abs(si.p))
        nudge = magnitude * 2.0 ** -21  # ~8 float32 ulps of the hit point
        side = dr.select(dr.dot(si.n, reference) >= 0.0, nudge, -nudge)
        origin = dr.select(self.ray_epsilon > magnitude * 1e-4, si.p, dr.fma(si.n, side, si.p))
        if target is None:
            d, maxt = dr.normalize(direction), FLOAT32_MAX
        else:
            d = target - origin
            distance = dr.norm(d)
            d, maxt = d / distance, distance * (1.0 - mi.math.ShadowEpsilon)
        return mi.Ray3f(dr.fma(d, self.ray_epsilon, origin), d, dr.maximum(maxt - self.ray_epsilon, 0.0),
                        si.time, si.wavelengths)

    def shade(self, scene: mi.Scene, si: mi.SurfaceInteraction3f, active: mi.Bool) -> mi.Color3f:
        """Local illumination at ``si``, or the background where it is a miss."""
        hit = active & si.is_valid()
        result = mi.Color3f(0.0)
        environment = scene.environment()
        if environment is not None:
            miss = active & (si.t == dr.inf)  # (not "~hit": scalar variants use Python bools)
            self.count(self.ENVIRONMENT, miss)
            result = dr.select(miss, environment.eval(si, miss), 0.0)

        if not dr.is_jit_v(mi.Float) and not hit:
            return result  # scalar variants: a miss has no BSDF to call
        ctx = mi.BSDFContext()
        bsdf = si.bsdf()
        if self.has_ambient:
            result += dr.select(hit, self.ambient * bsdf.eval_diffuse_reflectance(si, hit), 0.0)
        for light in self.delta_lights(scene):
            ds, radiance = light.sample_direction(si, mi.Point2f(0.5), hit)
            # a point light exactly at the shaded point has no direction: unlit, not inf
            lit = hit & (ds.pdf > 0.0) & (ds.dist > 0.0)
            if self.shadows:
                self.count(self.SHADOW, lit)
                lit &= dr.select(scene.ray_test(self.spawn(si, target=ds.p), lit), False, True)
            response = bsdf.eval(ctx, si, si.to_local(ds.d), lit)
            result += dr.select(lit, response * radiance, 0.0)
        return result

    def sample(self, scene: mi.Scene, sampler: mi.Sampler, ray: mi.RayDifferential3f,
               medium: mi.Medium = None, active: mi.Bool = True) -> tuple[mi.Color3f, mi.Bool, list[mi.Float]]:
        ray = mi.Ray3f(ray)
        active = mi.Bool(active)
        if dr.is_jit_v(mi.Float):  # one mask lane per ray (the caller may pass a scalar True)
            active &= dr.full(mi.Bool, True, dr.width(ray.d.x))
        if self.stats and self.counters is None:
            self.reset_counts()
        self.count(self.CAMERA, active)
        si = scene.ray_intersect(ray, active)
        aovs = self.first_hit_aovs(scene, si, active)
        if self.recursion_enabled(scene):
            result = self.trace_mirrors(scene, si, active)
        else:
            result = self.shade(scene, si, active)
        return result, si.is_valid(), aovs

    @dr.syntax
    def trace_mirrors(self, scene: mi.Scene, si: mi.SurfaceInteraction3f, active: mi.Bool) -> mi.Color3f:
        """Shades ``si`` and follows the mirror lobe up to ``max_depth`` times."""
        mirror = mi.BSDFContext(mi.TransportMode.Radiance, +mi.BSDFFlags.DeltaReflection)
        result = mi.Color3f(0.0)
        throughput = mi.Color3f(1.0)
        depth = mi.UInt32(0)
        while dr.hint(active, label="whitted_mirror"):
            result += throughput * self.shade(scene, si, active)
            active &= si.is_valid() & (depth < self.max_depth)
            weight, ray = self.mirror(mirror, si, active)
            throughput *= weight
            active &= dr.max(throughput) > 0.0
            self.count(self.MIRROR + depth, active)
            si = scene.ray_intersect(ray, active)
            depth += 1
        return result

    def mirror(self, ctx: mi.BSDFContext, si: mi.SurfaceInteraction3f,
               active: mi.Bool) -> tuple[mi.Color3f, mi.Ray3f]:
        """Weight and ray of the BSDF's mirror lobe at ``si``."""
        if not dr.is_jit_v(mi.Float) and not active:
            return mi.Color3f(0.0), dr.zeros(mi.Ray3f)  # scalar variants: no BSDF to call
        bs, weight = si.bsdf().sample(ctx, si, 0.0, mi.Point2f(0.0), active)
        return weight, self.spawn(si, direction=si.to_world(bs.wo))

    def first_hit_aovs(self, scene: mi.Scene, si: mi.SurfaceInteraction3f, active: mi.Bool) -> list[mi.Float]:
        if not self.aovs:
            return []
        hit = active & si.is_valid()
        values: list[mi.Float] = []
        for name in self.aovs:
            if name == "depth":
                values.append(dr.select(hit, si.t, 0.0))
            elif name == "normal":
                n = si.sh_frame.n
                values += [dr.select(hit, n.x, 0.0), dr.select(hit, n.y, 0.0), dr.select(hit, n.z, 0.0)]
            elif name == "position":
                values += [dr.select(hit, si.p.x, 0.0), dr.select(hit, si.p.y, 0.0), dr.select(hit, si.p.z, 0.0)]
            elif name == "albedo":
                if dr.is_jit_v(mi.Float) or hit:  # scalar variants: a miss has no BSDF
                    albedo = dr.select(hit, si.bsdf().eval_diffuse_reflectance(si, hit), 0.0)
                else:
                    albedo = mi.Color3f(0.0)
                values += [albedo.x, albedo.y, albedo.z]
            elif name == "id":
                values.append(dr.select(hit, self.object_ids(scene, si), -1.0))
        return values

    def object_ids(self, scene: mi.Scene, si: mi.SurfaceInteraction3f) -> mi.Float:
        ids = self.analyse(scene)[2]
        if not dr.is_jit_v(mi.Float):
            return mi.Float(-1.0 if si.shape is None else ids[si.shape.id()])
        # JIT variants: shape pointers are registry indices; map them through a table
        shapes = scene.shapes()
        registry = [int(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(s))[0]) for s in shapes]
        table = np.full(max(registry) + 1, -1.0, np.float32)
        for shape, index in zip(shapes, registry):
            table[index] = ids[shape.id()]
        return dr.gather(mi.Float, mi.Float(table), dr.reinterpret_array(mi.UInt32, si.shape))

    def to_string(self):
        return (f"WhittedIntegrator[\n  max_depth = {self.max_depth},\n  shadows = {self.shadows},\n"
                f"  ambient = {self.ambient},\n  aovs = {self.aovs}\n]")
