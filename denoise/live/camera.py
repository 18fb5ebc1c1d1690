"""``live_camera``: the course camera with its ray basis as opaque Dr.Jit
values, so that moving it changes no kernel.

Import it after ``mi.set_variant`` (it derives from the active variant's
``course_camera`` class).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from mi_plugins import plugin_class


class LiveCamera(plugin_class("course_camera")):
    r"""
    Live course camera (:monosp:`live_camera`)
    -------------------------------------------

    The parameters of ``course_camera`` (``origin``, ``direction``, ``up``,
    ``fov``, ``pixel_centers``), with the same rays. ``course_camera``
    computes its basis on the host and uses it as literals, so every new
    view compiles new kernels; here the origin and the three basis vectors
    are opaque arrays of width 1: a new view is new data for the same
    kernels, and a frozen function (``dr.freeze``) that traverses the
    sensor replays with the new view.
    """

    def parameters_changed(self, keys: list[str] | None = None):
        super().parameters_changed(keys)
        self.host_origin = self.ray_origin
        self.ray_origin = mi.Point3f(self.ray_origin)
        self.forward = mi.Vector3f(self.forward)
        self.horizontal = mi.Vector3f(self.horizontal)
        self.vertical = mi.Vector3f(self.vertical)
        dr.make_opaque(self.ray_origin, self.forward, self.horizontal, self.vertical)

    def bbox(self) -> mi.ScalarBoundingBox3f:
        return mi.ScalarBoundingBox3f(self.host_origin)


def register() -> None:
    """Registers ``live_camera`` for the active variant (a JIT variant)."""
    mi.register_sensor("live_camera", lambda props: LiveCamera(props))
