from __future__ import annotations

import drjit as dr
import mitsuba as mi


def clamped_power(x: mi.Float, exponent: float | mi.Float) -> mi.Float:
    """``max(x, 0) ** exponent`` without NaN: ``0 ** 0 = 1``, ``0 ** s = 0``.

    A Python float exponent is a constant of the kernel (integer exponents are
    exact products); a ``mi.Float`` one is an input of it, differentiable in
    both ``x`` and the exponent (no NaN derivative where ``x <= 0``)."""
    x = dr.maximum(x, 0.0)
    if isinstance(exponent, float):
        if exponent == 0.0:
            return dr.full(mi.Float, 1.0, dr.width(x))
        return dr.select(x > 0.0, dr.power(x, exponent), 0.0)
    positive = x > 0.0
    # the power of 1 where x <= 0: its derivatives there are finite, and not selected
    return dr.select(positive, dr.power(dr.select(positive, x, 1.0), exponent),
                     dr.select(exponent == 0.0, 1.0, 0.0))


class PhongBSDF(mi.BSDF):
    r"""
    .. _bsdf-phong:

    Course Phong material (:monosp:`phong`)
    ----------------------------------------

    .. pluginparameters::

     * - diffuse_reflectance
       - |rgb|
       - Diffuse colour :math:`k_d` (Default: 0.5)
       - |exposed|, |differentiable|

     * - specular_reflectance
       - |rgb|
       - Specular colour :math:`k_s`; also the weight of the ideal mirror
         lobe that Whitted-style integrators follow (Default: 0)
       - |exposed|, |differentiable|

     * - exponent
       - |float|
       - Phong shininess :math:`s \geq 0` (Default: 0)
       - |exposed|, |differentiable| (in ``eval``). The kernels take :math:`s`
         as a constant (``dr.power`` with a Python float: integer exponents
         are exact products, and ``0 ** 0 = 1`` is decided when tracing), so
         the images stay the course's and a new value recompiles them; while
         the parameter has gradients enabled (an optimisation), ``eval``
         takes it as a kernel input instead, with its derivative.

     * - sampling
       - |string|
       - ``phong``: sample the diffuse and glossy lobes (a path tracer then
         renders the full model); ``mirror``: sample only the Whitted mirror
         (a path tracer then follows exactly the light paths of the
         ``whitted`` integrator: direct light plus mirror recursion)
         (Default: ``phong``)

    The shading model of the course's ray tracer, written as a BSDF so that
    Mitsuba's own integrators can use it. With :math:`\omega_o` the direction
    towards the light and :math:`R` the mirror image of the direction towards
    the viewer,

    .. math::

        f(\omega_i, \omega_o)\,\cos\theta_o = \frac{k_d}{\pi}\cos\theta_o
            + \frac{k_s}{\pi}\max(0, R\cdot\omega_o)^s ,

    i.e. the course's :math:`k_d\,(L\cdot N) + k_s\,(L\cdot R)^s` per unit of
    light colour, once the light's intensity carries the factor :math:`\pi`
    (the scene converter does this). The diffuse lobe is Lambertian with albedo
    :math:`k_d`; the glossy lobe is the classic Phong lobe.

    Sampling picks the diffuse lobe (cosine-weighted) or the glossy lobe
    (:math:`\cos^s` around :math:`R`) in proportion to the mean of
    :math:`k_d` and :math:`k_s`. Its third component is a Whitted mirror: an
    ideal reflection with weight :math:`k_s`, sampled only when a context asks
    for ``DeltaReflection`` alone (as the ``whitted`` integrator does), so a
    path tracer never double-counts it.

    As in the course, the diffuse term is clamped by :math:`\cos\theta_o`
    and the highlight by :math:`R\cdot\omega_o`, and nothing else is checked
    (a point whose interpolated normal faces slightly away from the viewer is
    still lit). Sampling, for path tracers, draws directions above the
    surface from points seen from the front.

    .. tabs::

        .. code-tab:: python

            'type': 'phong',
            'diffuse_reflectance': {'type': 'rgb', 'value': [0.8, 0.2, 0.2]},
            'specular_reflectance': {'type': 'rgb', 'value': [1, 1, 1]},
            'exponent': 20
    """

    def __init__(self, props: mi.Properties):
        super().__init__(props)
        self.kd = mi.Color3f(self._color(props, "diffuse_reflectance", 0.5))
        self.ks = mi.Color3f(self._color(props, "specular_reflectance", 0.0))
        # exposed as "exponent"; the kernels read the host copy self.exponent
        self.exponent_parameter = mi.Float(props.get("exponent", 0.0))
        self.sampling = str(props.get("sampling", "phong"))
        if self.sampling not in ("phong", "mirror"):
            raise ValueError(f"phong: sampling must be 'phong' or 'mirror', got {self.sampling!r}")
        self._update_flags()

    @staticmethod
    def _color(props: mi.Properties, name: str, default: float) -> mi.ScalarColor3f:
        value = props.get(name, mi.ScalarColor3f(default))
        if isinstance(value, (int, float)):
            value = mi.ScalarColor3f(value)
        return mi.ScalarColor3f(value)

    def _update_flags(self):
        self.exponent = float(dr.slice(self.exponent_parameter, 0))
        if not self.exponent >= 0.0:
            raise ValueError(f"phong: exponent must be >= 0, got {self.exponent}")
        # what eval raises to: the constant, or the parameter itself while it is
        # differentiated (decided here: renders may suspend gradients)
        self.eval_exponent = (self.exponent_parameter if dr.grad_enabled(self.exponent_parameter)
                              else self.exponent)
        self.reflective = bool(dr.any(dr.ravel(self.ks) > 0.0))
        glossy = mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide
        mirror = mi.BSDFFlags.DeltaReflection | mi.BSDFFlags.FrontSide
        components = [mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide, glossy]
        if self.reflective:
            components.append(mirror)
        flags = components[0]
        for component in components[1:]:
            flags |= component
        # m_components is a copy on read: assign whole lists only
        self.m_components = components
        self.m_flags = flags

    # -- lobes ----------------------------------------------------------------
    def _lobes(self, ctx: mi.BSDFContext):
        """Which of (diffuse, glossy) the context enables."""
        def enabled(index: int, flag: mi.BSDFFlags) -> bool:
            return ctx.is_enabled(flag, index)
        return enabled(0, mi.BSDFFlags.DiffuseReflection), enabled(1, mi.BSDFFlags.GlossyReflection)

    def _mirror_only(self, ctx: mi.BSDFContext) -> bool:
        if self.sampling == "mirror":
            return True
        mask = ctx.type_mask
        return (mi.has_flag(mask, mi.BSDFFlags.DeltaReflection)
                and not mi.has_flag(mask, mi.BSDFFlags.DiffuseReflection)
                and not mi.has_flag(mask, mi.BSDFFlags.GlossyReflection)) or ctx.component == 2

    def _weights(self):
        """Probability of sampling the diffuse lobe (vs the glossy one)."""
        d, s = dr.mean(self.kd), dr.mean(self.ks)
        return dr.select(d + s > 0.0, d / (d + s), 1.0)

    def _glossy_frame(self, si: mi.SurfaceInteraction3f) -> mi.Frame3f:
        return mi.Frame3f(mi.reflect(si.wi))

    def eval(self, ctx: mi.BSDFContext, si: mi.SurfaceInteraction3f, wo: mi.Vector3f,
             active: bool = True) -> mi.Color3f:
        diffuse, glossy = self._lobes(ctx)
        # The course's clamps and nothing more: the diffuse term needs the
        # light above the surface, the highlight only needs L.R > 0; neither
        # looks at the viewer's side (with interpolated normals a visible
        # point may face slightly away from the viewer).
        value = mi.Color3f(0.0)
        if diffuse:
            value += self.kd * (dr.inv_pi * dr.maximum(mi.Frame3f.cos_theta(wo), 0.0))
        if glossy:
            highlight = clamped_power(dr.dot(mi.reflect(si.wi), wo), self.eval_exponent)
            value += self.ks * (dr.inv_pi * highlight)
        return dr.select(active, value, 0.0)

    def pdf(self, ctx: mi.BSDFContext, si: mi.SurfaceInteraction3f, wo: mi.Vector3f,
            active: bool = True) -> mi.Float:
        if self.sampling == "mirror":
            return mi.Float(0.0)  # only the delta lobe is sampled
        diffuse, glossy = self._lobes(ctx)
        cos_i, cos_o = mi.Frame3f.cos_theta(si.wi), mi.Frame3f.cos_theta(wo)
        active = active & (cos_i > 0.0) & (cos_o > 0.0)
        p_diffuse = self._weights() if (diffuse and glossy) else mi.Float(1.0 if diffuse else 0.0)
        pdf = mi.Float(0.0)
        if diffuse:
            pdf += p_diffuse * mi.warp.square_to_cosine_hemisphere_pdf(wo)
        if glossy:
            local = self._glossy_frame(si).to_local(wo)
            pdf += (1.0 - p_diffuse) * self._lobe_pdf(mi.Frame3f.cos_theta(local))
        return dr.select(active, pdf, 0.0)

    def _lobe_pdf(self, cos_alpha: mi.Float) -> mi.Float:
        # density of cos^s(alpha) on the sphere: (s + 1) / (2 pi) cos^s(alpha)
        return (self.exponent + 1.0) * dr.inv_two_pi * clamped_power(cos_alpha, self.exponent)

    def sample(self, ctx: mi.BSDFContext, si: mi.SurfaceInteraction3f, sample1: mi.Float,
               sample2: mi.Point2f, active: bool = True) -> tuple[mi.BSDFSample3f, mi.Color3f]:
        bs = dr.zeros(mi.BSDFSample3f)
        if self._mirror_only(ctx):
            bs.wo = mi.reflect(si.wi)
            bs.pdf = mi.Float(1.0)
            bs.eta = mi.Float(1.0)
            bs.sampled_type = mi.UInt32(+mi.BSDFFlags.DeltaReflection)
            bs.sampled_component = mi.UInt32(2)
            weight = self.ks if self.reflective else mi.Color3f(0.0)
            return bs, dr.select(active, weight, 0.0)

        active = active & (mi.Frame3f.cos_theta(si.wi) > 0.0)
        diffuse, glossy = self._lobes(ctx)
        if not (diffuse or glossy):
            return bs, mi.Color3f(0.0)
        p_diffuse = self._weights() if (diffuse and glossy) else mi.Float(1.0 if diffuse else 0.0)
        pick_diffuse = sample1 < p_diffuse
        wo_diffuse = mi.warp.square_to_cosine_hemisphere(sample2)
        # cos^s lobe around the mirror direction: cos(alpha) = u^(1/(s+1))
        cos_alpha = dr.power(sample2.x, 1.0 / (self.exponent + 1.0))
        sin_alpha = dr.safe_sqrt(1.0 - cos_alpha * cos_alpha)
        sin_phi, cos_phi = dr.sincos(dr.two_pi * sample2.y)
        wo_glossy = self._glossy_frame(si).to_world(
            mi.Vector3f(sin_alpha * cos_phi, sin_alpha * sin_phi, cos_alpha))
        bs.wo = dr.select(pick_diffuse, wo_diffuse, wo_glossy)
        bs.eta = mi.Float(1.0)
        bs.sampled_type = dr.select(pick_diffuse, mi.UInt32(+mi.BSDFFlags.DiffuseReflection),
                                    mi.UInt32(+mi.BSDFFlags.GlossyReflection))
        bs.sampled_component = dr.select(pick_diffuse, mi.UInt32(0), mi.UInt32(1))
        bs.pdf = self.pdf(ctx, si, bs.wo, active)
        active = active & (bs.pdf > 0.0)
        value = self.eval(ctx, si, bs.wo, active)
        return bs, dr.select(active, value / dr.select(active, bs.pdf, 1.0), 0.0)

    def eval_diffuse_reflectance(self, si: mi.SurfaceInteraction3f, active: bool = True) -> mi.Color3f:
        return mi.Color3f(self.kd)

    def traverse(self, callback):
        callback.put("diffuse_reflectance", self.kd, mi.ParamFlags.Differentiable)
        callback.put("specular_reflectance", self.ks, mi.ParamFlags.Differentiable)
        callback.put("exponent", self.exponent_parameter, mi.ParamFlags.Differentiable)

    def parameters_changed(self, keys: list[str] | None = None):
        # ks > 0 decides whether there is a mirror lobe; the exponent is read back to the host
        self._update_flags()

    def to_string(self):
        return (f"PhongBSDF[\n  diffuse_reflectance = {self.kd},\n  specular_reflectance = {self.ks},\n"
                f"  exponent = {self.exponent},\n  sampling = {self.sampling}\n]")
