"""Choosing the Mitsuba variant, and the LLVM that Dr.Jit may use.

Dr.Jit 1.5's LLVM backend aborts the process with Debian's libLLVM 14-16
(``LLVM ERROR: Cannot select ... fminimum``), so it is only used with LLVM 17
or newer. :func:`find_libllvm` looks for one and points ``DRJIT_LIBLLVM_PATH``
at it; this must happen before Dr.Jit first uses its LLVM backend.
"""
from __future__ import annotations

import glob
import os
import re
import sys

#: Oldest libLLVM major version that Dr.Jit 1.5 works with
MIN_LLVM = 17
DEFAULT_JIT_VARIANT = "llvm_ad_rgb"
FALLBACK_VARIANT = "scalar_rgb"
_SEARCH = ("/usr/lib/x86_64-linux-gnu/libLLVM*.so*", "/usr/lib/llvm-*/lib/libLLVM*.so*",
           "/usr/lib64/libLLVM*.so*", "/usr/local/lib/libLLVM*.so*")


def llvm_major(path: str) -> int | None:
    """LLVM major version from a library name (``libLLVM-19.so``, ``libLLVM.so.19.1``)."""
    match = re.search(r"libLLVM(?:-(\d+)|\.so\.(\d+))", os.path.basename(path))
    if match is None:
        match = re.search(r"llvm-(\d+)", path)
        return int(match.group(1)) if match else None
    return int(match.group(1) or match.group(2))


def find_libllvm() -> str | None:
    """A usable libLLVM (>= 17): ``DRJIT_LIBLLVM_PATH`` if it is one, else the newest found."""
    configured = os.environ.get("DRJIT_LIBLLVM_PATH")
    if configured:
        major = llvm_major(configured)
        return configured if os.path.exists(configured) and (major or 0) >= MIN_LLVM else None
    candidates = [(llvm_major(p), p) for pattern in _SEARCH for p in glob.glob(pattern)]
    usable = sorted((m, p) for m, p in candidates if m is not None and m >= MIN_LLVM)
    return usable[-1][1] if usable else None


def choose_variant(requested: str | None = None, quiet: bool = False) -> str:
    """Sets up and returns the variant to use.

    Without a request: ``llvm_ad_rgb`` where a usable LLVM exists, else
    ``scalar_rgb`` with one line on stderr saying why. An explicit ``llvm_*``
    request without a usable LLVM falls back the same way, never a crash.
    """
    import mitsuba as mi

    variant = requested or DEFAULT_JIT_VARIANT
    if variant not in mi.variants():
        raise ValueError(f"unknown variant {variant!r}; available: {', '.join(mi.variants())}")
    if variant.startswith("llvm_"):
        library = find_libllvm()
        if library is None:
            if not quiet:
                configured = os.environ.get("DRJIT_LIBLLVM_PATH")
                why = (f"DRJIT_LIBLLVM_PATH={configured} is not LLVM >= {MIN_LLVM}" if configured
                       else f"no libLLVM >= {MIN_LLVM} found (apt-get install libllvm19)")
                print(f"render: {why}; using {FALLBACK_VARIANT} instead of {variant}", file=sys.stderr)
            variant = FALLBACK_VARIANT
        else:
            os.environ["DRJIT_LIBLLVM_PATH"] = library
    return variant


def set_variant(requested: str | None = None, quiet: bool = False) -> str:
    """Chooses the variant, sets it and registers the project's plugins."""
    import mitsuba as mi

    import mi_plugins

    variant = choose_variant(requested, quiet)
    mi.set_variant(variant)
    mi_plugins.register()
    return variant
