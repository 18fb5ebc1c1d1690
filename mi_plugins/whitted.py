from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from .aovs import AOV_CHANNELS, parse_aovs
from .first_hit import finite, first_hit_values, none_active
from .scene_analysis import POINT, SceneAnalysis, analyse_scene, scene_state

#: the longest ray (Mitsuba's "largest" float32)
FLOAT32_MAX = float(np.finfo(np.float32).max)

#: A few (~8) float32 rounding units of a coordinate, relative to its magnitude
ROUNDING = 2.0 ** -21


def parse_epsilons(text: str) -> list[float]:
    values = [float(v) for v in text.replace(",", " ").split()]
    bad = [v for v in values if not (np.isfinite(v) and v >= 0.0)]
    if bad:
        raise ValueError(f"whitted: ray_epsilons must be finite and >= 0, got {bad[0]}")
    return values


class WhittedIntegrator(mi.SamplingIntegrator):
    r"""
    .. _integrator-whitted:

    Whitted ray tracer (:monosp:`whitted`)
    ---------------------------------------

    .. pluginparameters::

     * - bounces
       - |int|
       - Number of mirror bounces (the course's ``-bounces``); 0 is plain ray
         casting (Default: 0). Not Mitsuba's ``max_depth`` (path length; a
         path tracer needs ``bounces + 2``): passing ``max_depth`` is an error

     * - shadows
       - |bool|
       - Trace a shadow ray to every light (the course's ``-shadows``)
         (Default: |false|)

     * - ambient
       - |rgb|
       - Ambient light, multiplied by each surface's diffuse reflectance
         (Default: 0)

     * - ray_epsilons
       - |string|
       - Per object: secondary (mirror and shadow) rays leaving object ``k``
         (the shape ``object_<k>`` or ``object_<k>_part<j>``) ignore hits
         closer than the ``k``-th of these comma-separated distances, on top
         of a floating-point-safe offset of a few rounding units of the hit
         point and of the hit shape's coordinates. The course's solution
         skips hits within a small distance, which decides what grazing
         mirror rays see; the scene converter sets each object's distance to
         a fixed fraction of that object's own size, so the image depends on
         neither the scale of the scene nor on lights or other objects far
         away (Default: none)

     * - ray_epsilon
       - |float|
       - The same distance for shapes that ``ray_epsilons`` does not cover
         (Default: 0; with no distances at all, secondary rays use Mitsuba's
         own offset)

     * - max_unrolled_lights
       - |int|
       - Up to this many point and directional lights are unrolled into the
         kernel one by one; more are shaded in one symbolic loop over arrays
         of light data, so that compile time does not grow with their number
         (Default: 8)

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
    the weight of the BSDF's delta-reflection lobe, up to ``bounces`` times.
    Radiance is clamped to :data:`mi_plugins.first_hit.MAX_RADIANCE` (a NaN from ``inf * 0``
    becomes 0), so no output is ever non-finite.

    The traced kernel is specialised to the scene: a few lights are unrolled
    by kind, many are a symbolic loop, and no shadow ray, mirror loop,
    environment lookup or AOV is traced unless the flags and the scene need
    it. The mirror loop is a symbolic loop that ends as soon as no lane
    continues. One code path serves scalar and vectorised variants.

    The image is differentiable (``mi.render(scene, params)``, reverse or
    forward mode) with respect to what the BSDFs' and emitters' ``eval`` and
    ``sample`` depend on, e.g. ``phong``'s ``diffuse_reflectance``: Mitsuba's
    default ``render_backward`` re-renders with the AD graph recorded and the
    loops evaluated (Whitted paths are short and deterministic, so there is
    nothing to replay). Visibility (shadow and mirror ray hits) is not
    differentiated.

    .. tabs::

        .. code-tab:: python

            'type': 'whitted', 'bounces': 4, 'shadows': True,
            'ambient': {'type': 'rgb', 'value': [0.1, 0.1, 0.1]}, 'aovs': 'depth,normal'
    """

    def __init__(self, props: mi.Properties):
        super().__init__(props)
        if "max_depth" in props:
            raise ValueError("whitted: no max_depth parameter: use bounces, the number of mirror bounces "
                             "(0: ray casting; Mitsuba's max_depth would be bounces + 2)")
        self.bounces = int(props.get("bounces", 0))
        if self.bounces < 0:
            raise ValueError(f"whitted: bounces must be >= 0, got {self.bounces}")
        self.shadows = bool(props.get("shadows", False))
        ambient = props.get("ambient", mi.ScalarColor3f(0.0))
        self.ambient = mi.ScalarColor3f(ambient)
        self.has_ambient = any(float(self.ambient[k]) != 0.0 for k in range(3))
        self.aovs = parse_aovs(props.get("aovs", ""))
        self.ray_epsilon = float(props.get("ray_epsilon", 0.0))
        if not (np.isfinite(self.ray_epsilon) and self.ray_epsilon >= 0.0):
            raise ValueError(f"whitted: ray_epsilon must be finite and >= 0, got {self.ray_epsilon}")
        self.ray_epsilons = parse_epsilons(props.get("ray_epsilons", ""))
        #: Mitsuba's own offset where no distance is given at all
        self.mitsuba_offset = self.ray_epsilon == 0.0 and not any(self.ray_epsilons)
        self.max_unrolled_lights = int(props.get("max_unrolled_lights", 8))
        self.stats = bool(props.get("stats", False))
        self.counters = None
        self._analysed: SceneAnalysis | None = None

    def render(self, scene: mi.Scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
        # parameter updates since the last render that change the analysis (a
        # phong's ks switching its mirror lobe on, a shape moved) are seen here
        if self._analysed is not None and self._analysed.state != scene_state(scene):
            self._analysed = None
        self.analyse(scene)
        return super().render(scene, sensor, seed, spp, develop, evaluate)

    def aov_names(self) -> list[str]:
        return [channel for name in self.aovs for channel in AOV_CHANNELS[name]]

    # -- scene analysis (trace time) ----------------------------------------
    def analyse(self, scene: mi.Scene) -> SceneAnalysis:
        """Lights, mirrors and per-shape tables of ``scene`` (:func:`analyse_scene`),
        reused (scalar variants call :meth:`sample` once per ray) while the scene
        still holds exactly the same shapes and emitters, and renewed by
        :meth:`render` when its :func:`scene_state` changed. The analysis holds
        those objects, so a new scene at a freed one's address is never mistaken
        for it."""
        if self._analysed is None or not self._analysed.belongs_to(scene):
            self._analysed = analyse_scene(scene, self.max_unrolled_lights, self.ray_epsilon, self.ray_epsilons)
        return self._analysed

    def forget(self) -> None:
        """Drops the scene analysis: the next render or ``sample`` makes a new one."""
        self._analysed = None

    def delta_lights(self, scene: mi.Scene) -> list[mi.Emitter]:
        """The delta lights unrolled into the kernel (all of them, below the loop threshold)."""
        return self.analyse(scene).unrolled

    def recursion_enabled(self, scene: mi.Scene) -> bool:
        return self.bounces > 0 and self.analyse(scene).mirrors

    # -- ray statistics ------------------------------------------------------
    #: counter slots: camera, shadow, environment, then mirror rays of depth 1..bounces
    CAMERA, SHADOW, ENVIRONMENT, MIRROR = 0, 1, 2, 3

    def count(self, slot, mask) -> None:
        """Adds the number of active lanes of ``mask`` to counter ``slot`` (if ``stats``)."""
        if self.stats:
            dr.scatter_reduce(dr.ReduceOp.Add, self.counters.array, mi.UInt32(1), mi.UInt32(slot), mask)

    def ray_counts(self) -> dict[str, int | list[int]]:
        """Counts of the last render(s) since :meth:`reset_counts` (``stats`` on)."""
        values = [int(v) for v in (np.array(self.counters).reshape(-1) if self.counters is not None else [])]
        if not values:
            return {}
        return {"camera": values[self.CAMERA], "shadow": values[self.SHADOW],
                "environment": values[self.ENVIRONMENT], "mirror_by_depth": values[self.MIRROR:]}

    def reset_counts(self) -> None:
        size = self.MIRROR + self.bounces
        self.counters = dr.zeros(mi.TensorXu, size)

    # -- kernels ------------------------------------------------------------
    def spawn(self, si: mi.SurfaceInteraction3f, epsilon: mi.Float, scale: mi.Float,
              direction: mi.Vector3f = None, target: mi.Point3f = None) -> mi.Ray3f:
        """A secondary ray from ``si`` along ``direction`` or towards ``target``
        that skips hits closer than ``epsilon`` (the hit object's distance).

        With no distances configured this is Mitsuba's ``spawn_ray[_to]``.
        Otherwise the ray starts at the hit point moved ``epsilon`` along the
        ray, as in the course; only where that distance is not well above
        the rounding error of the hit point and of the hit shape's own
        coordinates (``scale``: ~1e-7 of their magnitude) is the point first
        nudged off the surface, by a few units of that rounding error.
        Unlike Mitsuba's own offset, which never goes below ~1e-4 (as large
        as a scene of that size), both follow the geometry that was hit, and
        nothing else: no light and no other object changes them.
        """
        if self.mitsuba_offset:
            return si.spawn_ray(direction) if target is None else si.spawn_ray_to(target)
        reference = target - si.p if target is not None else direction
        magnitude = dr.maximum(dr.max(dr.abs(si.p)), scale)
        nudge = magnitude * ROUNDING
        side = dr.select(dr.dot(si.n, reference) >= 0.0, nudge, -nudge)
        origin = dr.select(epsilon > magnitude * 1e-4, si.p, dr.fma(si.n, side, si.p))
        if target is None:
            d, maxt = dr.normalize(direction), FLOAT32_MAX
        else:
            d = target - origin
            distance = dr.norm(d)
            d, maxt = d / distance, distance * (1.0 - mi.math.ShadowEpsilon)
        return mi.Ray3f(dr.fma(d, epsilon, origin), d, dr.maximum(maxt - epsilon, 0.0), si.time, si.wavelengths)

    def shade(self, scene: mi.Scene, analysis: SceneAnalysis, si: mi.SurfaceInteraction3f,
              active: mi.Bool) -> mi.Color3f:
        """Local illumination at ``si``, or the background where it is a miss."""
        hit = active & si.is_valid()
        result = mi.Color3f(0.0)
        environment = scene.environment()
        if environment is not None:
            miss = active & (si.t == dr.inf)  # (not "~hit": scalar variants use Python bools)
            self.count(self.ENVIRONMENT, miss)
            result = dr.select(miss, environment.eval(si, miss), 0.0)

        if none_active(hit):
            return result
        bsdf = si.bsdf()
        if self.has_ambient:
            result += dr.select(hit, self.ambient * bsdf.eval_diffuse_reflectance(si, hit), 0.0)
        if not analysis.unrolled and analysis.table is None:
            return result
        epsilon = analysis.per_shape(si, "epsilons") if self.shadows else None
        scale = analysis.per_shape(si, "scales") if self.shadows else None
        for light in analysis.unrolled:
            ds, radiance = light.sample_direction(si, mi.Point2f(0.5), hit)
            result += self.lit_by(scene, si, bsdf, hit, ds.p, ds.d, ds.dist, ds.pdf > 0.0, radiance,
                                  epsilon, scale)[0]
        if analysis.table is not None:
            result += self.shade_light_loop(scene, analysis, si, bsdf, hit, epsilon, scale)
        return result

    def lit_by(self, scene, si, bsdf, hit, target, direction, distance, valid, radiance,
               epsilon, scale, count: bool = True) -> tuple[mi.Color3f, mi.Bool]:
        """One light's contribution: the BSDF's response towards ``direction``
        times ``radiance``, unless a shadow ray towards ``target`` is blocked;
        and where a shadow ray was traced (counted here if ``count``)."""
        # a point light exactly at the shaded point has no direction: unlit, not inf
        lit = hit & valid & (distance > 0.0)
        traced = lit if self.shadows else hit & False
        if self.shadows:
            if count:
                self.count(self.SHADOW, lit)
            # (not "&=": that would change "traced" too, the same array)
            lit = lit & dr.select(scene.ray_test(self.spawn(si, epsilon, scale, target=target), lit), False, True)
        response = bsdf.eval(mi.BSDFContext(), si, si.to_local(direction), lit)
        # a light too bright for float32 adds inf, or NaN where the response is 0: 0 then
        return dr.select(lit, finite(response * radiance), 0.0), traced

    @dr.syntax
    def shade_light_loop(self, scene, analysis, si, bsdf, hit, epsilon, scale) -> mi.Color3f:
        """Every light of the light table, one per iteration of a symbolic loop:
        the kernel holds one copy of the shading code however many lights there are."""
        result = mi.Color3f(0.0)
        shadow_rays = mi.UInt32(0)  # counted after the loop: no scatter into the counters inside it
        index = mi.UInt32(0)
        count = analysis.table.count_opaque  # a kernel input: any light count reuses the kernel
        # (not "self" in the body: the loop would capture the integrator's counters, which
        # have pending scatters that cannot be evaluated inside the mirror loop)
        shade_one = self.table_light
        while dr.hint(index < count, label="whitted_lights"):
            contribution, traced = shade_one(scene, analysis, si, bsdf, hit, index, epsilon, scale)
            result += contribution
            shadow_rays += dr.select(traced, 1, 0)
            index += 1
        if self.stats and self.shadows:
            dr.scatter_reduce(dr.ReduceOp.Add, self.counters.array, shadow_rays, mi.UInt32(self.SHADOW), hit)
        return result

    def table_light(self, scene, analysis, si, bsdf, hit, index, epsilon, scale) -> mi.Color3f:
        """Light ``index`` of the table, as Mitsuba's ``point`` and ``directional`` emitters sample it."""
        table = analysis.table
        kind = table.kinds.array[index]
        vector = table.vector(table.vectors, index)
        value = mi.Color3f(table.vector(table.values, index))
        point = kind == POINT
        # point: towards its position, intensity / distance^2
        to_light = vector - si.p
        squared = dr.squared_norm(to_light)
        distance = dr.sqrt(squared)
        # directional: a shadow ray to twice the scene's bounding sphere away, as Mitsuba's emitter
        cx, cy, cz, radius = analysis.bsphere
        far = 2.0 * dr.maximum(radius, dr.norm(si.p - mi.Point3f(cx, cy, cz)))
        target = dr.select(point, mi.Point3f(vector), dr.fma(vector, far, si.p))
        direction = dr.select(point, to_light / distance, vector)
        distance = dr.select(point, distance, far)
        radiance = dr.select(point, value / squared, value)
        return self.lit_by(scene, si, bsdf, hit, target, direction, distance, True, radiance, epsilon, scale,
                           count=False)

    def sample(self, scene: mi.Scene, sampler: mi.Sampler, ray: mi.RayDifferential3f,
               medium: mi.Medium = None, active: mi.Bool = True) -> tuple[mi.Color3f, mi.Bool, list[mi.Float]]:
        ray = mi.Ray3f(ray)
        # one mask lane per ray (the caller may pass a scalar True)
        active = mi.Bool(active) & dr.full(mi.Bool, True, dr.width(ray.d.x))
        if self.stats and self.counters is None:
            self.reset_counts()
        analysis = self.analyse(scene)
        self.count(self.CAMERA, active)
        si = scene.ray_intersect(ray, active)
        aovs = self.first_hit_aovs(analysis, si, active)
        if self.bounces > 0 and analysis.mirrors:
            result = self.trace_mirrors(scene, analysis, si, active)
        else:
            result = self.shade(scene, analysis, si, active)
        return finite(result), si.is_valid(), [finite(v) for v in aovs]

    @dr.syntax
    def trace_mirrors(self, scene: mi.Scene, analysis: SceneAnalysis, si: mi.SurfaceInteraction3f,
                      active: mi.Bool) -> mi.Color3f:
        """Shades ``si`` and follows the mirror lobe up to ``bounces`` times."""
        mirror = mi.BSDFContext(mi.TransportMode.Radiance, +mi.BSDFFlags.DeltaReflection)
        result = mi.Color3f(0.0)
        throughput = mi.Color3f(1.0)
        depth = mi.UInt32(0)
        while dr.hint(active, label="whitted_mirror"):
            result += throughput * self.shade(scene, analysis, si, active)
            active &= si.is_valid() & (depth < self.bounces)
            weight, ray = self.mirror(analysis, mirror, si, active)
            throughput *= weight
            active &= dr.max(throughput) > 0.0
            self.count(self.MIRROR + depth, active)
            si = scene.ray_intersect(ray, active)
            depth += 1
        return result

    def mirror(self, analysis: SceneAnalysis, ctx: mi.BSDFContext, si: mi.SurfaceInteraction3f,
               active: mi.Bool) -> tuple[mi.Color3f, mi.Ray3f]:
        """Weight and ray of the BSDF's mirror lobe at ``si``."""
        if none_active(active):
            return mi.Color3f(0.0), dr.zeros(mi.Ray3f)
        bs, weight = si.bsdf().sample(ctx, si, 0.0, mi.Point2f(0.0), active)
        epsilon = analysis.per_shape(si, "epsilons")
        scale = analysis.per_shape(si, "scales")
        return weight, self.spawn(si, epsilon, scale, direction=si.to_world(bs.wo))

    def first_hit_aovs(self, analysis: SceneAnalysis, si: mi.SurfaceInteraction3f,
                       active: mi.Bool) -> list[mi.Float]:
        return first_hit_values(self.aovs, si, active, lambda: analysis.per_shape(si, "ids"))

    def object_ids(self, scene: mi.Scene, si: mi.SurfaceInteraction3f) -> mi.Float:
        """Object id of each hit (-1: none)."""
        return self.analyse(scene).per_shape(si, "ids")

    def to_string(self):
        return (f"WhittedIntegrator[\n  bounces = {self.bounces},\n  shadows = {self.shadows},\n"
                f"  ambient = {self.ambient},\n  aovs = {self.aovs}\n]")

