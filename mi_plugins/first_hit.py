"""The first hit's AOVs as ``whitted`` writes them, and its radiance clamp.

An ordinary module (not run per variant like the plugins' modules; import it
after ``mi.set_variant``): ``whitted`` computes its AOVs here, and the live
page's G-buffer pass (``denoise.live.frame_loop``) calls the same function
inside ``dr.freeze`` with the per-shape id table passed as an argument, so
both give the same values bit for bit.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

#: Radiance is clamped to this (and NaN, from inf * 0, set to 0), so that sums
#: over lights, bounces and samples stay finite in float32
MAX_RADIANCE = 2.0 ** 100


def none_active(mask) -> bool:
    """Dr.Jit's C++ ``dr::none_or<false>(mask)``: true only for a one-lane mask
    (scalar variants trace one ray per call) that is off, where a miss has no
    BSDF to call; a vectorised mask never ends the kernel early."""
    return not dr.is_array_v(mask) and not mask


def finite(value):
    """``value`` with NaN set to 0 and magnitudes clamped to :data:`MAX_RADIANCE`."""
    return dr.select(dr.isnan(value), 0.0, dr.clip(value, -MAX_RADIANCE, MAX_RADIANCE))


def first_hit_values(names, si: mi.SurfaceInteraction3f, active: mi.Bool, object_ids) -> list[mi.Float]:
    """The AOVs ``names`` (see :data:`mi_plugins.aovs.AOV_CHANNELS`) of the hit
    ``si``, one Float per channel (0 where nothing was hit; id -1 there), before
    :func:`finite`; ``object_ids()`` gives the hit shape's object id (called only
    where ``names`` has ``id``)."""
    hit = active & si.is_valid()
    values: list[mi.Float] = []
    for name in names:
        if name == "depth":
            values.append(dr.select(hit, si.t, 0.0))
        elif name == "normal":
            n = si.sh_frame.n
            values += [dr.select(hit, n.x, 0.0), dr.select(hit, n.y, 0.0), dr.select(hit, n.z, 0.0)]
        elif name == "position":
            values += [dr.select(hit, si.p.x, 0.0), dr.select(hit, si.p.y, 0.0), dr.select(hit, si.p.z, 0.0)]
        elif name == "albedo":
            albedo = mi.Color3f(0.0)
            if not none_active(hit):
                albedo = dr.select(hit, si.bsdf().eval_diffuse_reflectance(si, hit), 0.0)
            values += [albedo.x, albedo.y, albedo.z]
        elif name == "id":
            values.append(dr.select(hit, object_ids(), -1.0))
    return values
