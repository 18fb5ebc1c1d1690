"""Choosing the Mitsuba variant, after :mod:`core.libllvm` has chosen the libLLVM.

The one module of the project that may be imported before the libLLVM is
chosen and that then imports Mitsuba: :func:`set_variant` makes the choice
itself where no entry point did (a notebook, a script of one's own), so
``set_variant`` first, then anything that imports Mitsuba at its top.
"""
from __future__ import annotations

import sys

from core.entry import hold_signals
from core.errors import UsageError
from core.libllvm import prepare_libllvm
from mi_plugins import register as register_plugins

DEFAULT_JIT_VARIANT = "llvm_ad_rgb"
FALLBACK_VARIANT = "scalar_rgb"


def _mitsuba():
    """Mitsuba, imported after the libLLVM is chosen (here, where no entry point
    chose it) and inside :func:`hold_signals`: a stop signal raised inside Dr.Jit's
    initialisation becomes an ImportError or SystemError with a traceback."""
    prepare_libllvm()
    with hold_signals():
        import mitsuba as mi  # noqa: PLC0415  this module is imported before the libLLVM is chosen (notebooks)
    return mi


def choose_variant(requested: str | None = None, quiet: bool = False, jit: bool = False) -> str:
    """Sets up and returns the variant to use.

    Without a request: ``llvm_ad_rgb`` where a usable LLVM exists, else
    ``scalar_rgb`` with one line on stderr saying why. An explicit ``llvm_*``
    request without a usable LLVM falls back the same way, never a crash.
    ``jit``: the command has no scalar form, so a scalar variant (asked for,
    or the fallback) is a :class:`UsageError` naming the reason. An unknown
    variant is a :class:`UsageError`.
    """
    variant = requested or DEFAULT_JIT_VARIANT
    mi = _mitsuba()
    choice = prepare_libllvm()
    usable = [v for v in mi.variants() if v.endswith("_rgb")]  # the plugins shade in RGB
    if variant not in usable:
        what = "an RGB variant" if variant in mi.variants() else "a known variant"
        raise UsageError(f"--variant: expected {what} ({', '.join(usable)}), found {variant!r}")
    fallback = variant.startswith("llvm_") and choice.library is None
    if jit and fallback:
        raise UsageError(f"{'; '.join(choice.notes)}; this command needs a JIT variant (llvm_* or cuda_*), "
                         f"and {FALLBACK_VARIANT} is all there is")
    if jit and variant.startswith("scalar_"):
        raise UsageError(f"--variant {variant}: this command needs a JIT variant (llvm_* or cuda_*)")
    if variant.startswith("llvm_") and not quiet and choice.notes:
        instead = f"using {choice.library}" if choice.library else f"using {FALLBACK_VARIANT} instead of {variant}"
        print(f"{choice.prog}: {'; '.join(choice.notes)}; {instead}", file=sys.stderr)
    return FALLBACK_VARIANT if fallback else variant


def set_variant(requested: str | None = None, quiet: bool = False, jit: bool = False) -> str:
    """Chooses the variant (:func:`choose_variant`), sets it and registers the project's plugins."""
    variant = choose_variant(requested, quiet, jit)
    mi = _mitsuba()
    with hold_signals():  # Dr.Jit starts its backend here: see _mitsuba
        try:
            mi.set_variant(variant)
        except (ImportError, RuntimeError, AttributeError) as error:  # e.g. a cuda_* variant without a GPU
            raise UsageError(f"--variant {variant} cannot be used here: "
                             f"{' '.join(str(error).split())[:200]}") from None
        register_plugins()
        from renderer.progress import log_to_stderr  # noqa: PLC0415  imports Mitsuba: after the libLLVM is chosen

        log_to_stderr()
    return variant
