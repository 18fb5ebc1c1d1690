"""The project's Mitsuba plugins, registered by name for XML and dicts.

Call :func:`register` after ``mi.set_variant``; it registers ``phong``,
``whitted``, ``course_camera`` and ``course_cubemap`` for the active variant.

A plugin class derives from its variant's base class (``mi.BSDF`` of
``llvm_ad_rgb`` is not that of ``scalar_rgb``), so each variant gets its own
classes: :func:`plugin_class` runs the plugin's module once per variant into a
module object of that variant (never reloading one that someone already holds),
and the registered factory looks the class up when Mitsuba constructs a plugin.
A class obtained under one variant therefore stays that variant's class after a
switch, and ``type(mi.load_dict({"type": "phong"}))`` is always the active
variant's. (Importing ``mi_plugins.phong`` directly also works; its class is
the one of the variant active at that import.)

Importing the package loads neither Mitsuba nor Dr.Jit, so that
:mod:`mi_plugins.aovs` and :mod:`mi_plugins.camera_basis` can be used before the
libLLVM is chosen.
"""
from __future__ import annotations

import importlib.util

#: plugin name -> (module, class, registration function name)
PLUGINS = {
    "phong": ("phong", "PhongBSDF", "register_bsdf"),
    "whitted": ("whitted", "WhittedIntegrator", "register_integrator"),
    "course_camera": ("course_camera", "CourseCamera", "register_sensor"),
    "course_cubemap": ("cubemap", "CubeMapEmitter", "register_emitter"),
}

#: (variant, module name) -> that module, run under that variant
_modules: dict[tuple[str, str], object] = {}
_registered: set[str] = set()


def _mitsuba():
    """Mitsuba, on first use: renderer.variants imports this package before the libLLVM is chosen."""
    import mitsuba as mi  # noqa: PLC0415  importing this package must not load Dr.Jit (see renderer.variants)

    return mi


def _active_variant() -> str:
    variant = _mitsuba().variant()
    if variant is None:
        raise RuntimeError("mi_plugins: call mi.set_variant() first")
    return variant


def plugin_module(module_name: str):
    """Module ``mi_plugins.<module_name>`` as run under the active variant (once per variant)."""
    key = (_active_variant(), module_name)
    if key not in _modules:
        spec = importlib.util.find_spec(f"{__name__}.{module_name}")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)  # its class statements derive from this variant's bases
        _modules[key] = module
    return _modules[key]


def plugin_class(name: str) -> type:
    """Class of plugin ``name`` (``phong``, ``whitted``, ...) for the active variant."""
    module_name, class_name, _ = PLUGINS[name]
    return getattr(plugin_module(module_name), class_name)


def register() -> None:
    """Registers every plugin for the active variant (once per variant)."""
    mi = _mitsuba()
    variant = _active_variant()
    if variant in _registered:
        return
    for name, (_, _, register_name) in PLUGINS.items():
        plugin_class(name)  # build it now: a broken module fails here, not at the first load
        # looked up at construction time, under the variant Mitsuba constructs it for
        getattr(mi, register_name)(name, lambda props, name=name: plugin_class(name)(props))
    _registered.add(variant)
