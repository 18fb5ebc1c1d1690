"""The project's Mitsuba plugins, registered by name for XML and dicts.

Call :func:`register` after ``mi.set_variant``; it registers ``phong``,
``whitted``, ``course_camera`` and ``course_cubemap`` for the active variant.
"""
from __future__ import annotations

import importlib
import sys

import mitsuba as mi

#: plugin name -> (module, class, registration function name)
PLUGINS = {
    "phong": ("phong", "PhongBSDF", "register_bsdf"),
    "whitted": ("whitted", "WhittedIntegrator", "register_integrator"),
    "course_camera": ("course_camera", "CourseCamera", "register_sensor"),
    "course_cubemap": ("cubemap", "CubeMapEmitter", "register_emitter"),
}

_registered: set[str] = set()
_module_variant: str | None = None


def register() -> None:
    """Registers every plugin for the active variant (once per variant)."""
    global _module_variant
    variant = mi.variant()
    if variant is None:
        raise RuntimeError("mi_plugins.register(): call mi.set_variant() first")
    if variant in _registered:
        return
    for name, (module_name, class_name, register_name) in PLUGINS.items():
        qualified = f"{__name__}.{module_name}"
        module = importlib.import_module(qualified)
        # The classes derive from the variant's base classes when the module
        # runs, so a module first loaded under another variant is run again.
        if _module_variant not in (None, variant) and qualified in sys.modules:
            module = importlib.reload(module)
        cls = getattr(module, class_name)
        getattr(mi, register_name)(name, lambda props, cls=cls: cls(props))
    _module_variant = variant
    _registered.add(variant)
