"""Fixtures in the style of Mitsuba's own test suite: one per variant.

``variant_scalar_rgb`` / ``variant_llvm_ad_rgb`` set that variant (and register
our plugins); ``variants_all_rgb`` runs a test once per variant. The LLVM
variant is skipped, with the reason, where no usable libLLVM exists.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from renderer import variants  # noqa: E402

# Point Dr.Jit at a usable LLVM before anything initialises its LLVM backend
_LIBLLVM = variants.find_libllvm()
if _LIBLLVM:
    os.environ["DRJIT_LIBLLVM_PATH"] = _LIBLLVM

COURSE = Path(os.environ.get("COURSE_ROOT", ROOT.parent / "shared" / "course"))


def _set(variant: str) -> str:
    if variant.startswith("llvm_") and _LIBLLVM is None:
        pytest.skip(f"no libLLVM >= {variants.MIN_LLVM} for {variant}")
    variants.set_variant(variant, quiet=True)
    return variant


@pytest.fixture
def variant_scalar_rgb():
    return _set("scalar_rgb")


@pytest.fixture
def variant_llvm_ad_rgb():
    return _set("llvm_ad_rgb")


@pytest.fixture(params=["scalar_rgb", "llvm_ad_rgb"])
def variants_all_rgb(request):
    return _set(request.param)


@pytest.fixture(scope="session")
def course() -> Path:
    """The course's data folder (``../shared/course``); tests needing it skip without it."""
    if not (COURSE / "data").is_dir() or not (COURSE / "sample_out").is_dir():
        pytest.skip(f"course data not found at {COURSE} (set COURSE_ROOT)")
    return COURSE


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: full-size or scalar-variant checks (deselect with -m 'not slow')")
