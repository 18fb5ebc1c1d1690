"""One concept, one place: each metric and each piece of course access is
defined once, tests use :mod:`validation` (never ``benchmarks`` in-process), and the
image and scene packages do not import each other.

The import graph and the code's size and comments, checked on the source text:

- no import cycle between the project's modules, imports inside functions
  included (a function-level import hides a cycle, it does not remove it);
- no module imports another module's underscore names (what is shared is
  public, in the lower module);
- no production file is over :data:`MAX_LINES` lines;
- no code comment carries a date or an issue number (those belong to docs/
  and commit messages).

Each check is shown to fail on a planted example in a scratch tree.
"""
from __future__ import annotations

import ast
import io
import re
import tokenize
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("core", "converters", "course", "mi_plugins", "imaging", "renderer", "export", "validation", "benchmarks",
            "denoise", "notebooks", "tests")
#: function name -> the one module that defines it
HOMES = {"relmse": "imaging/metrics.py", "flip_error": "imaging/metrics.py",
         "bad_pixels": "imaging/metrics.py", "bad_fraction": "imaging/metrics.py",
         "grading_lines": "course/__init__.py", "course_runs": "course/__init__.py",
         "resolve_scene": "course/__init__.py", "course_camera_basis": "mi_plugins/camera_basis.py",
         "tone_map": "imaging/colour.py", "write_video": "imaging/image_io.py", "read_exr": "imaging/image_io.py",
         "ascii_int": "core/numbers.py", "ascii_float": "core/numbers.py", "read_input": "core/inputs.py",
         "pixel_coordinates": "denoise/filters.py", "check_json": "benchmarks/records.py",
         "replace_section": "core/markdown.py", "temporal_relmse": "denoise/temporal_metrics.py",
         "back_projected": "denoise/temporal_metrics.py", "stability": "denoise/temporal_metrics.py",
         "flip_heat_map": "imaging/metrics.py", "relmse_loss": "denoise/filters.py"}
#: the floors, lowest first: a package imports only those below it (tests and notebooks sit on top)
FLOORS = ("core", "imaging", "mi_plugins", "converters", "course", "renderer", "export", "denoise",
          "validation", "benchmarks", "notebooks", "tests")
#: the packages users run (the floors up to the denoiser)
PRODUCTION = FLOORS[:FLOORS.index("denoise") + 1]

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


def upward_imports(root: Path) -> list[str]:
    """``file: package`` for every import (in functions too) of a package on a floor above the file's."""
    found = []
    for path, tree in sources(root):
        floor = FLOORS.index(path.relative_to(root).parts[0])
        found += [f"{path.relative_to(root).as_posix()}: {name}"
                  for name in sorted(imported_packages(path, tree) & set(FLOORS)) if FLOORS.index(name) > floor]
    return found


def test_no_import_runs_up_the_floors():
    """Helpers sit below their users: metrics in imaging, the writability check beside the writers."""
    assert upward_imports(ROOT) == []


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
    (tmp_path / "course" / "score.py").write_text("from validation.metrics import relmse\n")
    assert upward_imports(tmp_path) == ["course/score.py: validation", "denoise/cli.py: benchmarks"]
    assert sorted(definitions(tmp_path)["relmse"]) == ["benchmarks/denoise.py", "imaging/metrics.py"]
    assert environment_reads(tmp_path) == {"COURSE_DATA"}
    assert imported_packages(tmp_path / "tests" / "test_x.py",
                             ast.parse((tmp_path / "tests" / "test_x.py").read_text())) == {"benchmarks"}


# -- the import graph, file sizes and comments ----------------------------------------
#: the packages of the import graph (tests are not imported by any of them)
GRAPH_PACKAGES = ("core", "converters", "course", "mi_plugins", "imaging", "renderer", "export", "validation",
                  "benchmarks", "denoise", "notebooks", "scenes")
MAX_LINES = 450
DIARY = re.compile(r"20\d\d-\d\d-\d\d|\bissue \d+|\bissue #\d+", re.IGNORECASE)


def python_files(root: Path, packages=GRAPH_PACKAGES) -> list[Path]:
    files = [path for package in packages for path in sorted((root / package).rglob("*.py"))]
    return files + sorted(root.glob("*.py"))


def module_name(root: Path, path: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imports(root: Path, path: Path, tree: ast.AST, modules: set[str]) -> list[tuple[str, list[str], int]]:
    """``(module, names, line)`` for every import of a project module in ``path``,
    at any depth; ``from pkg import sub`` names the submodule where it is one."""
    name = module_name(root, path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(alias.name, [], node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[:len(package.split(".")) - node.level + 1] if package else []
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            names = [alias.name for alias in node.names]
            submodules = [f"{target}.{n}" for n in names if f"{target}.{n}" in modules]
            found += [(sub, [], node.lineno) for sub in submodules]
            found.append((target, [n for n in names if f"{target}.{n}" not in modules], node.lineno))
    return [(target, names, line) for target, names, line in found if target in modules]


def import_graph(root: Path) -> tuple[dict[str, set[str]], list[str]]:
    """The project's module graph and the cross-module underscore imports (``file:line: name``)."""
    files = python_files(root)
    modules = {module_name(root, path) for path in files}
    graph, private = {}, []
    for path in files:
        name = module_name(root, path)
        tree = ast.parse(path.read_text(), str(path))
        graph[name] = set()
        for target, names, line in imports(root, path, tree, modules):
            if target != name:
                graph[name].add(target)
                private += [f"{path.relative_to(root).as_posix()}:{line}: {target}.{n}" for n in names
                            if n.startswith("_") and not n.startswith("__")]
    return graph, private


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(node):
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in sorted(graph.get(node, ())):
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def long_files(root: Path) -> list[str]:
    files = python_files(root, PRODUCTION) + [root / "render.py"]
    return [f"{path.relative_to(root).as_posix()}: {n} lines" for path in files if path.exists()
            and (n := len(path.read_text().splitlines())) > MAX_LINES]


def diary_comments(root: Path) -> list[str]:
    """Comments and docstrings with a date or an issue number, in every Python file of the tree."""
    found = []
    for path in python_files(root, GRAPH_PACKAGES + ("tests",)):
        text, name = path.read_text(), path.relative_to(root).as_posix()
        tokens = tokenize.generate_tokens(io.StringIO(text).readline)
        found += [f"{name}:{token.start[0]}: {token.string.strip()}"
                  for token in tokens if token.type == tokenize.COMMENT and DIARY.search(token.string)]
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
                docstring = ast.get_docstring(node, clean=False)
                if docstring and DIARY.search(docstring):
                    line = node.body[0].lineno
                    found.append(f"{name}:{line}: {DIARY.search(docstring).group()} (docstring)")
    return sorted(found)


def test_no_import_cycles():
    graph, _ = import_graph(ROOT)
    assert cycles(graph) == []


def test_no_module_imports_another_modules_underscore_names():
    _, private = import_graph(ROOT)
    assert private == []


def test_no_production_file_is_over_the_limit():
    assert long_files(ROOT) == []


def test_no_dates_or_issue_numbers_in_comments():
    assert diary_comments(ROOT) == []


def method_basename_pairs(root: Path) -> list[str]:
    """Modules elsewhere in ``denoise/`` named as a method module (a method is one file, with its kernels)."""
    methods = {path.name for path in (root / "denoise" / "methods").glob("*.py") if not path.name.startswith("__")}
    return sorted(path.relative_to(root).as_posix() for path in (root / "denoise").rglob("*.py")
                  if path.name in methods and path.parent != root / "denoise" / "methods")


def test_a_method_is_one_file():
    """No kernel module beside the method module of the same name (denoise/svgf.py and denoise/methods/svgf.py)."""
    assert method_basename_pairs(ROOT) == []


def test_the_checks_find_planted_faults(tmp_path):
    """A cycle through a function-level import, an underscore import, a long file and a dated comment."""
    for package in GRAPH_PACKAGES + ("tests",):
        (tmp_path / package).mkdir()
        (tmp_path / package / "__init__.py").write_text("")
    (tmp_path / "core" / "low.py").write_text("def helper():\n    from denoise import high\n    return high\n")
    (tmp_path / "denoise" / "high.py").write_text("from core.low import helper\nfrom ._mid import _secret\n")
    (tmp_path / "denoise" / "_mid.py").write_text('"""Chosen in issue 7."""\n_secret = 1  # measured 2026-11-29\n')
    (tmp_path / "renderer" / "big.py").write_text("x = 1\n" * (MAX_LINES + 1))
    (tmp_path / "render.py").write_text("from renderer import big  # see issue 12\n")
    (tmp_path / "denoise" / "methods").mkdir()
    (tmp_path / "denoise" / "methods" / "svgf.py").write_text("")
    (tmp_path / "denoise" / "svgf.py").write_text("")
    assert method_basename_pairs(tmp_path) == ["denoise/svgf.py"]
    graph, private = import_graph(tmp_path)
    assert cycles(graph) == [["core.low", "denoise.high"]]
    assert private == ["denoise/high.py:2: denoise._mid._secret"]
    assert long_files(tmp_path) == [f"renderer/big.py: {MAX_LINES + 1} lines"]
    assert diary_comments(tmp_path) == ["denoise/_mid.py:1: issue 7 (docstring)",
                                        "denoise/_mid.py:2: # measured 2026-11-29", "render.py:1: # see issue 12"]
