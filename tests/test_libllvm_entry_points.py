"""Every entry point chooses the libLLVM before Dr.Jit starts (``core.launcher.start``).

Each command the README and docs name (and every module with a ``__main__``
guard) runs here as a user runs it: with ``DRJIT_LIBLLVM_PATH`` at a text file
and at a truncated copy of the real library it falls back to ``scalar_rgb``
with one line, or refuses with one line and exit 2 where it has no scalar
form; never a traceback, never a signal. In a child whose first import of
Dr.Jit is watched, the libLLVM Dr.Jit maps is the one chosen, and it was chosen
before that import. From a shell outside ./.venv each command shows its --help.
"""
from __future__ import annotations

import ast
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
REAL_LIBLLVM = next((p for p in ("/usr/lib/x86_64-linux-gnu/libLLVM-19.so", "/usr/lib/llvm-19/lib/libLLVM.so")
                     if os.path.exists(p)), None)
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]

#: folders whose scripts are not the project's commands (docs/experiments: scripts for a Python with PyTorch)
NOT_COMMANDS = (".venv", "tests", "docs")


def documented_commands() -> list[str]:
    """``python -m X`` and ``python X.py`` as README.md and docs/*.md write them, for X in this checkout."""
    text = "\n".join(page.read_text() for page in PAGES)
    names = set()
    for module, script in re.findall(r"python3? (?:-m ([A-Za-z_][\w.]*)|([\w/]+\.py)\b)", text):
        path = ROOT / (script or module.replace(".", "/"))
        if (script and path.is_file()) or (module and (path.with_suffix(".py").is_file()
                                                       or (path / "__main__.py").is_file())):
            names.add(script or module)
    return sorted(names)


def guarded_modules() -> list[str]:
    """Every production module with a ``__main__`` guard, as the command that runs it."""
    names = []
    for path in sorted(ROOT.rglob("*.py")):
        relative = path.relative_to(ROOT)
        if relative.parts[0] in NOT_COMMANDS or 'if __name__ == "__main__"' not in path.read_text():
            continue
        if relative.parent == Path("."):
            names.append(str(relative))
        else:
            names.append(".".join(relative.with_suffix("").parts).removesuffix(".__main__"))
    return names


DOCUMENTED = documented_commands()
#: the entry points: what the docs name and every module a user can run
#: (scenes.generate_assets rewrites committed files: only its start is checked, statically)
ENTRY_POINTS = sorted((set(DOCUMENTED) | set(guarded_modules())) - {"scenes.generate_assets"})
#: a cheap invocation of each that reaches the variant (where one is cheap), and what it does without a
#: usable libLLVM: "fallback" (scalar_rgb, one line), "refuse" (one line, exit 2) or "none" (no Dr.Jit work);
#: the rest show --help, which still runs the whole import path
RUNS = {
    "render.py": (["-input", "{scene}", "-size", "4", "3", "-output", "{tmp}/a.png"], "fallback"),
    "converters": (["{scene}", "-o", "{tmp}/s.xml", "-size", "4", "3"], "none"),
    "export": (["{spec}", "{tmp}/seq", "--local"], "fallback"),
    "denoise": (["{seq}", "{tmp}/den"], "refuse"),
    "denoise.score": (["{seq}", "--reference", "{seq}_reference", "--frames", "{seq}"], "refuse"),
    "denoise.fit": (["{spec}", "--work", "{tmp}/fit", "--steps", "1", "--switch-frame", "1", "--out", "{tmp}/p.json"],
                    "refuse"),
    "denoise.live": (["showcase", "--size", "16", "12", "--port", "0"], "refuse"),
    "denoise.methods": ([], "none"),
    "benchmarks.stress": (["--only", "empty file", "--fuzz", "0", "--json", "{tmp}/s.json"], "fallback"),
}
TINY = {"scene": "lamps", "frames": 2, "size": [16, 12], "spp": 1, "reference_spp": 2, "bounces": 1}


def command(name: str, python: str = sys.executable) -> list[str]:
    return [python, name] if name.endswith(".py") else [python, "-m", name]


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> dict:
    """A scene, a tiny spec and its sequence (exported with the usable libLLVM)."""
    from validation.stress.scene import scene

    folder = tmp_path_factory.mktemp("inputs")
    (folder / "s.txt").write_text(scene())
    (folder / "tiny.json").write_text(json.dumps(TINY))
    done = subprocess.run(command("export") + [str(folder / "tiny.json"), str(folder / "seq"), "--local"],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return {"scene": folder / "s.txt", "spec": folder / "tiny.json", "seq": folder / "seq"}


@pytest.fixture(scope="module")
def broken_libraries(tmp_path_factory) -> dict:
    """Both named as the real library is, so that each is probed: a text file, the first 1 MB of the real one."""
    folder = tmp_path_factory.mktemp("libllvm")
    (folder / "text").mkdir()
    (folder / "text" / "libLLVM-19.so").write_text("not a library\n")
    libraries = {"text file": folder / "text" / "libLLVM-19.so"}
    if REAL_LIBLLVM:
        (folder / "truncated").mkdir()
        with open(REAL_LIBLLVM, "rb") as real:
            (folder / "truncated" / "libLLVM-19.so").write_bytes(real.read(1 << 20))
        libraries["truncated copy"] = folder / "truncated" / "libLLVM-19.so"
    return libraries


def run_entry_point(name: str, inputs: dict, tmp_path: Path, env: dict) -> tuple[subprocess.CompletedProcess, str]:
    argv, kind = RUNS.get(name, (["--help"], "help"))
    places = {**inputs, "tmp": tmp_path}
    argv = [word.format(**places) for word in argv]
    done = subprocess.run(command(name) + argv, cwd=ROOT, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "XDG_CACHE_HOME": str(tmp_path / "cache"), **env})
    return done, kind


def check_contract(name: str, done: subprocess.CompletedProcess, kind: str, library: Path) -> None:
    err = done.stderr
    assert done.returncode >= 0, f"{name}: killed by signal {-done.returncode}: {err[-2000:]}"
    assert "Traceback" not in err and "Error:" not in err.replace("error:", ""), f"{name}: {err[-3000:]}"
    lines = err.splitlines()
    if kind == "help":
        assert done.returncode == 0 and done.stdout.startswith("usage:") and err == "", (name, err)
    elif kind == "fallback":
        assert done.returncode == 0, (name, err)
        assert len(lines) == 1 and str(library) in lines[0] and "using scalar_rgb instead" in lines[0], (name, err)
    elif kind == "refuse":
        assert done.returncode == 2 and len(lines) == 1, (name, done.returncode, err)
        assert ": error: " in lines[0] and str(library) in lines[0] and "JIT variant" in lines[0], (name, err)
    else:
        assert done.returncode == 0 and err == "", (name, err)


@pytest.mark.parametrize("case", ["text file", "truncated copy"])
def test_render_py_keeps_its_contract_with_a_broken_libllvm(case, inputs, broken_libraries, tmp_path):
    """The fast one: render.py falls back with one line (each entry point in the slow test below)."""
    if case not in broken_libraries:
        pytest.skip(f"no real libLLVM to truncate ({REAL_LIBLLVM})")
    library = broken_libraries[case]
    done, kind = run_entry_point("render.py", inputs, tmp_path, {"DRJIT_LIBLLVM_PATH": str(library)})
    check_contract("render.py", done, kind, library)


@pytest.mark.slow
@pytest.mark.parametrize("case", ["text file", "truncated copy"])
@pytest.mark.parametrize("name", ENTRY_POINTS)
def test_every_entry_point_keeps_the_contract_with_a_broken_libllvm(name, case, inputs, broken_libraries, tmp_path):
    if case not in broken_libraries:
        pytest.skip(f"no real libLLVM to truncate ({REAL_LIBLLVM})")
    library = broken_libraries[case]
    done, kind = run_entry_point(name, inputs, tmp_path, {"DRJIT_LIBLLVM_PATH": str(library)})
    check_contract(name, done, kind, library)


#: Run through ``sitecustomize`` (on PYTHONPATH) in the entry point's own process: it notes
#: DRJIT_LIBLLVM_PATH and the libLLVM choice at the moment Dr.Jit is first imported, and at
#: exit the libLLVM files mapped, into $LIBLLVM_REPORT
WATCH = r'''
import atexit, importlib.machinery, json, os, sys

seen = {}


def note():
    libllvm = sys.modules.get("core.libllvm")
    choice = libllvm.chosen() if libllvm is not None and hasattr(libllvm, "chosen") else None
    seen.update(imported=True, chosen_before=choice is not None, chosen=choice.library if choice else None,
                environment=os.environ.get("DRJIT_LIBLLVM_PATH"))


class NotingLoader:
    def __init__(self, loader):
        self.loader = loader

    def create_module(self, spec):
        return self.loader.create_module(spec)

    def exec_module(self, module):
        note()
        self.loader.exec_module(module)


class WatchDrJit:
    # Dr.Jit's spec with a loader that notes its first run (a find_spec alone imports nothing)
    def find_spec(self, name, path=None, target=None):
        if name != "drjit" or seen:
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        if spec is not None:
            spec.loader = NotingLoader(spec.loader)
        return spec


def report():
    if sys.orig_argv[1:2] == ["-c"]:  # the libLLVM probe's child: not the command
        return
    mapped = sorted({line.split()[-1] for line in open("/proc/self/maps") if "libLLVM" in line.split()[-1]})
    with open(os.environ["LIBLLVM_REPORT"], "w") as out:
        json.dump({**seen, "mapped": mapped}, out)


sys.meta_path.insert(0, WatchDrJit())
atexit.register(report)
'''


@pytest.fixture(scope="module")
def watch_folder(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("watch")
    (folder / "sitecustomize.py").write_text(WATCH)
    return folder


def loaded_and_chosen(name: str, watch_folder: Path, tmp_path: Path, env: dict) -> dict:
    report = tmp_path / "report.json"
    fresh = {key: value for key, value in os.environ.items() if key != "DRJIT_LIBLLVM_PATH"}  # conftest's choice
    done = subprocess.run(command(name) + ["--help"], cwd=ROOT, capture_output=True, text=True, timeout=300,
                          env={**fresh, "XDG_CACHE_HOME": str(tmp_path / "cache"), **env,
                               "PYTHONPATH": str(watch_folder), "LIBLLVM_REPORT": str(report)})
    assert done.returncode == 0 and done.stdout.startswith("usage:"), (name, done.stderr[-2000:])
    return json.loads(report.read_text())


def check_loaded_is_chosen(name: str, seen: dict) -> None:
    assert seen.get("imported"), f"{name}: Dr.Jit never imported ({seen})"
    assert seen["chosen_before"], f"{name}: Dr.Jit imported before the libLLVM was chosen ({seen})"
    assert seen["environment"] == seen["chosen"], f"{name}: DRJIT_LIBLLVM_PATH at Dr.Jit's import ({seen})"
    if seen["chosen"] is not None:
        assert seen["mapped"] == [os.path.realpath(seen["chosen"])], f"{name}: {seen}"


def test_the_watch_sees_a_library_loaded_before_the_choice(watch_folder, tmp_path):
    """What makes the next test mean something: Dr.Jit imported by hand, before any choice, is caught."""
    report = tmp_path / "report.json"
    (tmp_path / "first.py").write_text("import drjit\n")
    subprocess.run([sys.executable, "first.py"], cwd=tmp_path, check=True, timeout=120,
                   env={**os.environ, "PYTHONPATH": str(watch_folder), "LIBLLVM_REPORT": str(report)})
    seen = json.loads(report.read_text())
    assert seen["imported"] and not seen["chosen_before"] and seen["mapped"]
    with pytest.raises(AssertionError, match="before the libLLVM was chosen"):
        check_loaded_is_chosen("import drjit", seen)


@pytest.mark.parametrize("name", ["render.py", "denoise"])
def test_the_libllvm_dr_jit_loads_is_the_one_chosen(name, watch_folder, tmp_path):
    """The fast subset of the next test."""
    check_loaded_is_chosen(name, loaded_and_chosen(name, watch_folder, tmp_path, {}))


@pytest.mark.slow
@pytest.mark.parametrize("case", ["default", "truncated copy"])
@pytest.mark.parametrize("name", ENTRY_POINTS)
def test_every_entry_point_loads_the_libllvm_it_chose(name, case, watch_folder, broken_libraries, tmp_path):
    """Default: the newest usable libLLVM is chosen and mapped; a truncated copy: it is taken out of
    the environment before Dr.Jit starts, and never mapped."""
    env = {}
    if case == "truncated copy":
        if case not in broken_libraries:
            pytest.skip(f"no real libLLVM to truncate ({REAL_LIBLLVM})")
        env = {"DRJIT_LIBLLVM_PATH": str(broken_libraries[case])}
    seen = loaded_and_chosen(name, watch_folder, tmp_path, {key: value for key, value in env.items()})
    check_loaded_is_chosen(name, seen)
    if env:
        assert seen["chosen"] is None and env["DRJIT_LIBLLVM_PATH"] not in seen["mapped"], seen


def test_every_entry_point_is_found_and_starts_with_the_launcher():
    """The documented commands are among the runnable modules (none missed by the lists above), and
    in each runnable module nothing but the standard library is imported before core.launcher.start."""
    assert {"render.py", "converters", "denoise", "export", "denoise.score", "denoise.fit",
            "denoise.live", "benchmarks.denoise"} <= set(DOCUMENTED)
    assert set(DOCUMENTED) <= set(ENTRY_POINTS)
    late = []
    for name in guarded_modules():
        path = ROOT / name if name.endswith(".py") else ROOT / name.replace(".", "/")
        path = path if name.endswith(".py") else (path / "__main__.py" if path.is_dir() else path.with_suffix(".py"))
        for statement in ast.parse(path.read_text()).body:
            if isinstance(statement, ast.If) and "start" in ast.unparse(statement) and "core.launcher" in ast.unparse(
                    statement):
                break
            modules = ([a.name for a in statement.names] if isinstance(statement, ast.Import) else
                       [statement.module or ""] if isinstance(statement, ast.ImportFrom) and statement.level == 0
                       else ["."] if isinstance(statement, ast.ImportFrom) else [])
            outside = [m for m in modules if m.split(".")[0] not in sys.stdlib_module_names | {"__future__"}
                       and m not in ("core.start_up", "core.launcher")]  # standard library only, both
            if outside:
                late.append(f"{name}: imports {outside[0]} before core.launcher.start")
                break
        else:
            late.append(f"{name}: never calls core.launcher.start")
    assert not late, late


@pytest.fixture(scope="module")
def plain_shell(tmp_path_factory):
    """A fresh shell's environment: the system's python3 first on PATH, no venv active."""
    system = shutil.which("python3", path="/usr/bin:/bin")
    if system is None or Path(system).resolve().is_relative_to(ROOT):
        pytest.skip("no Python outside ./.venv")
    bin_dir = tmp_path_factory.mktemp("bin")
    (bin_dir / "python").symlink_to(system)
    env = {key: value for key, value in os.environ.items()
           if key not in ("VIRTUAL_ENV", "PYTHONPATH", "PYTHONHOME", "CONDA_PREFIX")}
    env["PATH"] = os.pathsep.join([str(bin_dir), "/usr/bin", "/bin"])
    return env


def test_the_denoising_benchmark_runs_from_a_plain_shell(plain_shell):
    """The fast one (it was ModuleNotFoundError: numpy): every documented command in the slow test below."""
    test_every_documented_entry_point_runs_from_a_plain_shell("benchmarks.denoise", plain_shell)


@pytest.mark.slow
@pytest.mark.parametrize("name", DOCUMENTED)
def test_every_documented_entry_point_runs_from_a_plain_shell(name, plain_shell):
    """README's promise: each command re-runs itself under ./.venv/bin/python (core.launcher)."""
    done = subprocess.run(["python", *command(name, python="python")[1:], "--help"], cwd=ROOT, env=plain_shell,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0 and done.stdout.startswith("usage:"), (name, done.stderr[-2000:])


@pytest.mark.parametrize("name", ["denoise", "denoise.score", "denoise.live"])
def test_a_command_without_a_scalar_form_refuses_scalar_rgb_in_one_line(name, inputs, tmp_path):
    """``--variant scalar_rgb`` given to the denoiser was a RuntimeError traceback (dtype.unravel)."""
    argv, _ = RUNS[name]
    argv = [word.format(**inputs, tmp=tmp_path) for word in argv] + ["--variant", "scalar_rgb"]
    done = subprocess.run(command(name) + argv, cwd=ROOT, capture_output=True, text=True, timeout=300)
    lines = done.stderr.splitlines()
    assert done.returncode == 2 and len(lines) == 1, (done.returncode, done.stderr[-2000:])
    assert lines[0] == f"python -m {name}: error: --variant scalar_rgb: this command needs a JIT variant " \
                       "(llvm_* or cuda_*)", lines
