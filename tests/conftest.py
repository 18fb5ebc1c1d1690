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

import fcntl
import os
import subprocess
import sys
from contextlib import ExitStack, contextmanager
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
    config.addinivalue_line("markers", "slow: exhaustive, full-size or scalar-variant forms of checks made in small "
                            "without the mark (./dev test leaves them out; -m slow runs them)")
    config.addinivalue_line("markers", "required: must run; a skip fails the session")
    config.addinivalue_line("markers", "vectorised: needs a vectorised (LLVM) variant; skips without one")
    config.addinivalue_line("markers", "timed: asserts a wall-clock bound; under pytest-xdist no other test runs "
                                       "meanwhile (see time_alone)")


@contextmanager
def turn(folder: Path, alone: bool):
    """A test's turn among pytest-xdist's workers, through two lock files in
    ``folder``: a ``timed`` test (``alone``) closes the gate, so no test starts,
    and waits until the tests running have ended; any other shares the room."""
    with open(folder / "tests.gate.lock", "a") as gate, open(folder / "tests.room.lock", "a") as room:
        fcntl.flock(gate, fcntl.LOCK_EX)  # waits while a timed test waits for the room or is in it
        try:
            fcntl.flock(room, fcntl.LOCK_EX if alone else fcntl.LOCK_SH)
        finally:
            if not alone:
                fcntl.flock(gate, fcntl.LOCK_UN)
        yield  # closing the files releases the locks


@pytest.fixture(autouse=True)
def time_alone(request, tmp_path_factory):
    """Under pytest-xdist, a test marked ``timed`` runs while no other does: its
    wall-clock bound (a stop within 2 s) is the program's, not a share of the
    cores. The lock files lie in the run's temporary folder, shared by its workers."""
    if not is_worker(request.config):
        yield
        return
    folder = tmp_path_factory.getbasetemp().parent
    with turn(folder, request.node.get_closest_marker("timed") is not None), ExitStack() as groups:
        # pytest-xdist 3.8 no longer keeps an xdist_group on one worker under pytest 9.2 (it renames
        # a node id attribute pytest no longer has): a group's tests take turns through a lock file
        for name in sorted({str(mark.args[0]) for mark in request.node.iter_markers("xdist_group")}):
            group = groups.enter_context(open(folder / f"tests.group-{name}.lock", "a"))
            fcntl.flock(group, fcntl.LOCK_EX)
        yield


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


#: the checkout's files (those git does not ignore) by modification time, at the session's start
CHECKOUT_AT_START = pytest.StashKey[dict]()


def checkout_files() -> dict[str, int]:
    """Each file of the checkout that git does not ignore, by its modification time
    (none outside a git checkout): a test writes only into its temporary folders."""
    try:
        listed = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=ROOT,
                                capture_output=True, check=True, timeout=60).stdout
    except (OSError, subprocess.SubprocessError):
        return {}
    files = {}
    for name in filter(None, listed.decode("utf-8", "surrogateescape").split("\0")):
        try:
            files[name] = (ROOT / name).lstat().st_mtime_ns
        except OSError:
            files[name] = -1  # listed but gone (deleted, not yet committed)
    return files


def is_worker(config) -> bool:
    """Whether this process is a pytest-xdist worker (the controller reports for the session)."""
    return hasattr(config, "workerinput")


def pytest_sessionstart(session):
    if not is_worker(session.config):
        session.config.stash[CHECKOUT_AT_START] = checkout_files()


def pytest_sessionfinish(session, exitstatus):
    if is_worker(session.config):
        return
    if _skipped["required"] and session.exitstatus == 0:
        session.exitstatus = 1
    before, after = session.config.stash.get(CHECKOUT_AT_START, {}), checkout_files()
    changed = sorted(name for name in before.keys() | after.keys() if before.get(name) != after.get(name))
    if before and changed:
        terminal = session.config.pluginmanager.get_plugin("terminalreporter")
        line = (f"THE TESTS CHANGED THE CHECKOUT (a test must write only into its temporary folders): "
                f"{', '.join(changed[:10])}{' ...' if len(changed) > 10 else ''}")
        if terminal:
            terminal.write("\n")
            terminal.write_line(line, red=True)
        else:
            print(line, file=sys.stderr)
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
