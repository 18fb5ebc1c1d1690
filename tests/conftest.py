"""Fixtures in the style of Mitsuba's own test suite: one per variant.

``variant_scalar_rgb`` sets ``scalar_rgb``; ``variant_rgb`` (and its older
name ``variant_llvm_ad_rgb``) sets the best usable variant: ``llvm_ad_rgb``
where a libLLVM >= 17 exists, else ``scalar_rgb``, so that image tests run
instead of skipping (:data:`SCALAR_FALLBACK` tells a test to render smaller);
``variants_all_rgb`` runs a test once per variant, and ``variant_vectorised_rgb``
sets ``llvm_ad_rgb`` for checks that need vectorised kernels (both skip the LLVM
variant, with the reason, where no usable libLLVM exists). Every fixture
registers our plugins and, after the test, cleans up as Mitsuba's own
``src/conftest.py`` does (waits for running kernels, drops the kernel and
allocation caches and the instance registry, resets the JIT flags) and
restores the variant that was active before the test.

Tests that use ``variant_rgb``/``variant_llvm_ad_rgb``/``variant_scalar_rgb``
are marked ``required``: if one of them is skipped, the session fails (and the
summary names it), so a broken set-up cannot pass as green.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))
# the commands the tests start import this checkout, whatever folder they run in
# (the venv's editable install may name another checkout of the project)
os.environ["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])

# The first import, as every entry point's (core.launcher.start): the libLLVM is chosen before
# anything imports Dr.Jit, since test modules (and what they import) import it at their top
from core.libllvm import MIN_LLVM, prepare_libllvm  # noqa: E402

_LIBLLVM = prepare_libllvm("pytest").library

from course import ENVIRONMENT as COURSE_ENVIRONMENT, root as course_root  # noqa: E402
from export.tasks import forget_loaded_scenes  # noqa: E402
from renderer import variants  # noqa: E402

#: no usable LLVM: image tests run on scalar_rgb (Python plugins, one ray at a
#: time), at the smaller sizes they choose with this flag
SCALAR_FALLBACK = _LIBLLVM is None
COURSE = course_root()  # $COURSE_ROOT, else ../shared/course
#: fixtures whose tests must not be skipped
REQUIRED_FIXTURES = {"variant_rgb", "variant_llvm_ad_rgb", "variant_scalar_rgb"}
#: tests of Dr.Jit kernels that have no scalar form (the denoiser): for these
#: ``variant_llvm_ad_rgb`` means exactly that variant, as ``variant_vectorised_rgb``
#: does (until they ask for it by that name)
VECTORISED_TESTS = ("tests/test_denoise.py::", "tests/test_svgf.py::", "tests/stress/test_stress.py::test_denoise_case")


def best_variant() -> str:
    """``llvm_ad_rgb`` where usable, else ``scalar_rgb``."""
    return variants.FALLBACK_VARIANT if SCALAR_FALLBACK else variants.DEFAULT_JIT_VARIANT


def _set(variant: str) -> str:
    """Sets ``variant`` exactly (a test comparing two variants needs both): an
    ``llvm_*`` one without a usable libLLVM skips, with the reason."""
    if variant.startswith("llvm_") and _LIBLLVM is None:
        pytest.skip(f"no libLLVM >= {MIN_LLVM} for {variant}")
    variants.set_variant(variant, quiet=True)
    return variant


def _active_variant() -> str | None:
    if "mitsuba" not in sys.modules:
        return None
    return sys.modules["mitsuba"].variant()


def _clean_up(previous: str | None) -> None:
    """After a test: Mitsuba's ``src/conftest.py`` teardown, then the variant from before the test."""
    import drjit as dr

    dr.sync_thread()  # kernels still running
    dr.flush_kernel_cache()
    dr.kernel_history_clear()
    dr.flush_malloc_cache()
    dr.detail.malloc_clear_statistics()
    forget_loaded_scenes()  # the export's scenes hold instances that the registry's clearing invalidates
    dr.detail.clear_registry()  # instances kept alive by a failed test's traceback
    dr.set_flag(dr.JitFlag.Default, True)
    if previous is not None and previous != _active_variant():
        variants.set_variant(previous, quiet=True)


def _variant_fixture(variant: str):
    previous = _active_variant()
    yield _set(variant)
    _clean_up(previous)


@pytest.fixture
def variant_scalar_rgb():
    yield from _variant_fixture("scalar_rgb")


@pytest.fixture
def variant_rgb():
    """The best usable variant (see :func:`best_variant`); never skips."""
    yield from _variant_fixture(best_variant())


@pytest.fixture
def variant_llvm_ad_rgb(request):
    """Older name of :func:`variant_rgb`: ``llvm_ad_rgb``, or ``scalar_rgb`` without a usable LLVM
    (except for :data:`VECTORISED_TESTS`, which get ``llvm_ad_rgb`` or skip)."""
    vectorised = request.node.get_closest_marker("vectorised")
    yield from _variant_fixture("llvm_ad_rgb" if vectorised else best_variant())


@pytest.fixture
def variant_vectorised_rgb():
    """``llvm_ad_rgb`` exactly, for checks that need vectorised kernels (``mitsuba.chi2``);
    skips, with the reason, without a usable LLVM (such a test is not required)."""
    yield from _variant_fixture("llvm_ad_rgb")


@pytest.fixture(params=["scalar_rgb", "llvm_ad_rgb"])
def variants_all_rgb(request):
    yield from _variant_fixture(request.param)


@pytest.fixture(scope="session")
def course() -> Path:
    """The course's data folder (``../shared/course``); tests needing it skip without it."""
    if not (COURSE / "data").is_dir() or not (COURSE / "sample_out").is_dir():
        pytest.skip(f"course data not found at {COURSE} (set {COURSE_ENVIRONMENT})")
    return COURSE


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: full-size or scalar-variant checks (deselect with -m 'not slow')")
    config.addinivalue_line("markers", "required: must run; a skip fails the session")
    config.addinivalue_line("markers", "vectorised: needs a vectorised (LLVM) variant; skips without one")


def pytest_collection_modifyitems(config, items):
    for item in items:
        fixtures = set(getattr(item, "fixturenames", ()))
        if "variant_vectorised_rgb" in fixtures or item.nodeid.startswith(VECTORISED_TESTS):
            item.add_marker(pytest.mark.vectorised)
        elif REQUIRED_FIXTURES & fixtures:
            item.add_marker(pytest.mark.required)


_skipped: dict[str, list[str]] = {"required": [], "other": []}
_outcomes = {"passed": 0, "failed": 0}


def pytest_runtest_logreport(report):
    if report.failed:
        _outcomes["failed"] += 1
    elif report.passed and report.when == "call":
        _outcomes["passed"] += 1
    if report.skipped and not hasattr(report, "wasxfail"):
        kind = "required" if "required" in report.keywords else "other"
        reason = report.longrepr[2] if isinstance(report.longrepr, tuple) else str(report.longrepr)
        _skipped[kind].append(f"{report.nodeid}: {reason}")


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    required, other = _skipped["required"], _skipped["other"]
    terminalreporter.write_line(f"skips: {len(required) + len(other)} ({len(required)} required), variant for "
                                f"image tests: {best_variant()}")
    for line in required:
        terminalreporter.write_line(f"REQUIRED TEST SKIPPED {line}", red=True)


def pytest_sessionfinish(session, exitstatus):
    if _skipped["required"] and session.exitstatus == 0:
        session.exitstatus = 1
    report = os.environ.get("PYTEST_SKIP_REPORT")  # benchmarks.report's scalar_suite step
    if report:
        import json

        Path(report).write_text(json.dumps(
            {"variant": best_variant(), **_outcomes, "skipped": len(_skipped["required"]) + len(_skipped["other"]),
             "required_skipped": len(_skipped["required"]), "skips": _skipped["other"] + _skipped["required"]},
            indent=2) + "\n")


@pytest.fixture
def exported(variant_llvm_ad_rgb, tmp_path):
    """A small sequence exported by ``export`` (32x18, 2 frames), checked to be lit."""
    from export import Spec, export
    from imaging.image_io import read_exr_rgb

    folder = tmp_path / "glossy_shadow"
    export(Spec.load(ROOT / "scenes" / "sequences" / "glossy_shadow.json", size=(32, 18), frames=2, reference_spp=2),
           folder)
    assert read_exr_rgb(folder / "beauty_0.exr").max() > 0, "the exported frame is black"
    return folder


@pytest.fixture
def registry():
    """The method registry (and the live page's lists) as they were, after the test
    (``--method-file`` and ``register`` add to them in this process)."""
    from denoise.live.methods import refresh
    from denoise.methods import METHODS

    before = dict(METHODS)
    yield
    METHODS.clear()
    METHODS.update(before)
    refresh()
