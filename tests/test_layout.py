"""One concept, one place (issue 12): each metric and each piece of course access is
defined once, tests use :mod:`validation` (never ``benchmarks`` in-process), and the
image and scene packages do not import each other."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("core", "converters", "course", "mi_plugins", "imaging", "renderer", "validation", "benchmarks",
            "denoise", "notebooks", "tests")
#: function name -> the one module that defines it
HOMES = {"relmse": "validation/metrics.py", "flip_error": "validation/metrics.py",
         "bad_pixels": "validation/metrics.py", "bad_fraction": "validation/metrics.py",
         "grading_lines": "course/__init__.py", "course_runs": "course/__init__.py",
         "resolve_scene": "course/__init__.py", "course_camera_basis": "mi_plugins/camera_basis.py",
         "tone_map": "imaging/colour.py", "write_video": "imaging/image_io.py", "read_exr": "imaging/image_io.py",
         "ascii_int": "core/numbers.py", "ascii_float": "core/numbers.py", "read_input": "core/inputs.py",
         "pixel_coordinates": "denoise/filters.py", "check_json": "benchmarks/__init__.py",
         "replace_section": "core/markdown.py", "temporal_relmse": "validation/metrics.py",
         "back_projected": "validation/metrics.py", "stability": "validation/metrics.py",
         "flip_heat_map": "validation/metrics.py"}
#: the packages users run; they never need the checks or the measurements
PRODUCTION = ("core", "converters", "course", "mi_plugins", "imaging", "renderer", "denoise")
#: the commands that measure against a ground truth (a student's output, the fit's loss): checks that
#: users run, so they use validation's metrics
SCORING = ("course/score.py", "denoise/score.py", "denoise/fit.py")


def sources(root: Path):
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            yield path, ast.parse(path.read_text(), str(path))


def definitions(root: Path) -> dict[str, list[str]]:
    """Where each function of :data:`HOMES` is defined (module-level or nested)."""
    found = {name: [] for name in HOMES}
    for path, tree in sources(root):
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.name in found:
                found[node.name].append(path.relative_to(root).as_posix())
    return found


def imported_packages(path: Path, tree: ast.AST) -> set[str]:
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def environment_reads(root: Path) -> set[str]:
    """The ``COURSE_*`` names in the code: the environment variables that could locate the course."""
    names = set()
    for path, tree in sources(root):
        if path == Path(__file__).resolve():  # (this file names them to test the check)
            continue
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value.startswith("COURSE_"):
                names.add(node.value)
    return names


def test_each_metric_and_course_function_has_one_home():
    assert definitions(ROOT) == {name: [home] for name, home in HOMES.items()}


def test_the_course_is_located_by_one_environment_variable():
    from course import ENVIRONMENT, RETIRED_ENVIRONMENT

    assert environment_reads(ROOT) == {ENVIRONMENT, *RETIRED_ENVIRONMENT}


def test_a_retired_course_variable_is_refused_not_ignored(monkeypatch):
    import course
    from core.errors import UsageError

    monkeypatch.delenv(course.ENVIRONMENT, raising=False)
    monkeypatch.setenv("COURSE_DATA", "/somewhere/data")
    with pytest.raises(UsageError, match=r"\$COURSE_DATA is no longer read; set \$COURSE_ROOT"):
        course.root()
    monkeypatch.setenv(course.ENVIRONMENT, "/somewhere")
    assert course.root() == Path("/somewhere")


def test_tests_do_not_import_benchmarks():
    """A test that checks a benchmark runs its command (``python -m benchmarks.x``)."""
    offenders = [path.relative_to(ROOT).as_posix() for path, tree in sources(ROOT)
                 if path.is_relative_to(ROOT / "tests") and "benchmarks" in imported_packages(path, tree)]
    assert offenders == []


def production_offenders(root: Path) -> list[str]:
    return [path.relative_to(root).as_posix() for path, tree in sources(root)
            if any(path.is_relative_to(root / package) for package in PRODUCTION)
            and imported_packages(path, tree) & ({"benchmarks", "notebooks", "tests"}
                                                 | ({"validation"} if path.relative_to(root).as_posix()
                                                    not in SCORING else set()))]


def test_production_code_imports_no_checks_or_benchmarks():
    """denoise's CLI once took its PNG and video writers from benchmarks.denoise."""
    assert production_offenders(ROOT) == []


def test_imaging_depends_on_core_only():
    """imaging is below converters (it used to import converters for the error type, and converters imports it)."""
    for path, tree in sources(ROOT):
        if path.is_relative_to(ROOT / "imaging"):
            assert imported_packages(path, tree) & set(PACKAGES) <= {"core"}, path


def test_the_layout_checks_can_fail(tmp_path):
    """A second relmse, a second course variable, and a test importing benchmarks are all found."""
    for package in PACKAGES:
        (tmp_path / package).mkdir()
    for name, home in HOMES.items():
        (tmp_path / home).touch()
        with open(tmp_path / home, "a") as module:
            module.write(f"def {name}():\n    pass\n")
    (tmp_path / "benchmarks" / "denoise.py").write_text(
        "import os\ndef relmse(a, b):\n    return 0\nDATA = os.environ.get('COURSE_DATA')\n")
    (tmp_path / "tests" / "test_x.py").write_text("from benchmarks.crossval import run\n")
    (tmp_path / "denoise" / "cli.py").write_text("def main():\n    from benchmarks.denoise import write_video\n")
    assert production_offenders(tmp_path) == ["denoise/cli.py"]
    assert sorted(definitions(tmp_path)["relmse"]) == ["benchmarks/denoise.py", "validation/metrics.py"]
    assert environment_reads(tmp_path) == {"COURSE_DATA"}
    assert imported_packages(tmp_path / "tests" / "test_x.py",
                             ast.parse((tmp_path / "tests" / "test_x.py").read_text())) == {"benchmarks"}
