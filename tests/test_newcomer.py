"""A newcomer's first hour: the README's commands as typed in a fresh
shell, quiet set-up, scene headers, converter flags and outputs, progress lines."""
from __future__ import annotations

import io
import os
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import numpy as np
import pytest
from helpers import MAX_BAD_FRACTION, bad_fraction, encode

from core.errors import SceneError
from course import root as course_root

ROOT = Path(__file__).resolve().parent.parent
COURSE_SCENES = course_root() / "data"


def _system_python() -> Path:
    """A Python outside ./.venv that lacks the project's packages (the one a fresh shell finds)."""
    for candidate in (shutil.which("python3", path="/usr/bin:/bin"), os.path.realpath(sys._base_executable)):
        if candidate and not Path(candidate).resolve().is_relative_to(ROOT):
            return Path(candidate)
    pytest.skip("no Python outside ./.venv")


@pytest.fixture(scope="module")
def fresh_shell(tmp_path_factory):
    """Environment of a fresh shell: ``python`` is the system's, no venv active."""
    system = _system_python()
    bin_dir = tmp_path_factory.mktemp("bin")
    (bin_dir / "python").symlink_to(system)
    env = {key: value for key, value in os.environ.items()
           if key not in ("VIRTUAL_ENV", "PYTHONPATH", "PYTHONHOME", "CONDA_PREFIX")}
    env["PATH"] = os.pathsep.join([str(bin_dir), "/usr/bin", "/bin"])
    env["PYTHONDONTWRITEBYTECODE"] = "1"

    def run(*command, timeout=600):
        return subprocess.run(list(command), cwd=ROOT, env=env, capture_output=True, text=True, timeout=timeout)

    return run


def test_the_system_python_really_lacks_the_packages(fresh_shell, tmp_path):
    """What makes the next test mean something: without the launcher lines at
    the top of render.py, the user's command fails on the first import."""
    probe = fresh_shell("python", "-c", "import numpy, drjit, mitsuba")
    if probe.returncode == 0:
        pytest.skip("this machine's system Python has the project's packages")
    assert "ModuleNotFoundError" in probe.stderr
    script = (ROOT / "render.py").read_text()
    # (renderer.cli itself imports only the standard library, so --help would work: render something)
    without_launcher = (script.split('if __name__ == "__main__":  # started', 1)[0]
                        + "from renderer.cli import main\n"
                        + f"sys.exit(main(['showcase', '-size', '4', '4', '--out', {str(tmp_path)!r}]))\n")
    failed = fresh_shell("python", "-c", without_launcher)
    assert failed.returncode != 0 and "ModuleNotFoundError" in failed.stderr


def test_readme_commands_in_a_fresh_shell(fresh_shell, tmp_path):
    """`python render.py scene06 --variant scalar_rgb`, `python -m converters`,
    `python -m export` and `python -m denoise` as the README writes them,
    with the system Python first on PATH (tiny sizes)."""
    if COURSE_SCENES.is_dir():
        result = fresh_shell("python", "render.py", "scene06", "--variant", "scalar_rgb", "-size", "16", "16",
                             "--out", str(tmp_path / "out"))
        assert result.returncode == 0, result.stderr
        assert (tmp_path / "out" / "scene06_bunny_1k.png").is_file()
        assert result.stdout.count("\n") == 1 and result.stderr == ""
    result = fresh_shell("python", "-m", "converters", "scenes/showcase.txt", "-o", str(tmp_path / "x.xml"),
                         "-size", "16", "16")
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "x.xml").is_file()
    frames = tmp_path / "seq"
    result = fresh_shell("python", "-m", "export", "scenes/sequences/dolly_lamps.json", str(frames),
                         "--frames", "2", "--size", "16", "12", "--spp", "1", "--reference-spp", "2")
    assert result.returncode == 0, result.stderr
    result = fresh_shell("python", "-m", "denoise", str(frames), str(tmp_path / "denoised"))
    assert result.returncode == 0, result.stderr
    assert sorted(p.name for p in (tmp_path / "denoised").glob("result_*.exr")) == ["result_0.exr", "result_1.exr"]


def test_launcher_without_a_venv_says_what_to_do(monkeypatch, capsys, tmp_path):
    from core import launcher

    monkeypatch.setattr(launcher, "REQUIRED", ("no_such_package_here",))
    monkeypatch.setattr(launcher, "VENV", tmp_path / ".venv")
    monkeypatch.setattr(launcher, "VENV_PYTHON", tmp_path / ".venv" / "bin" / "python")
    with pytest.raises(SystemExit) as stop:
        launcher.use_project_python("render.py")
    assert stop.value.code == 2
    message = capsys.readouterr().err
    assert message.count("\n") == 1 and "run ./dev setup" in message and "no_such_package_here" in message


@pytest.mark.xdist_group("notebooks")  # may install the notebook extra: not while a notebook runs
def test_jupyter_command_of_the_readme():
    """`./dev notebooks` (the README's way to open the notebooks) finds JupyterLab
    and nbconvert in ./.venv, installing the notebook extra on first use."""
    result = subprocess.run(["./dev", "notebooks", "--version"], cwd=ROOT, capture_output=True, text=True,
                            timeout=900)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip()[0].isdigit()
    nbconvert = subprocess.run([str(ROOT / ".venv" / "bin" / "jupyter"), "nbconvert", "--version"],
                               capture_output=True, text=True)
    assert nbconvert.returncode == 0, nbconvert.stderr


# -- set-up -------------------------------------------------------------------

def test_package_discovery_lists_every_folder_with_data():
    """setuptools warns "Package 'scenes.meshes' is absent from the `packages`
    configuration" for a data folder that no package pattern covers."""
    import tomllib

    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    include = config["packages"]["find"]["include"]
    data_folders = {p.parent.relative_to(ROOT).as_posix().replace("/", ".")
                    for p in (ROOT / "scenes").rglob("*") if p.is_file() and "__pycache__" not in p.parts}
    from fnmatch import fnmatch

    for folder in data_folders:
        assert any(fnmatch(folder, pattern) for pattern in include), folder


@pytest.mark.slow
def test_editable_install_prints_nothing(tmp_path):
    """The project's own build step (pip's output for it) is silent on success."""
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    # a pip as new as ./dev's: older ones hide the build backend's warnings
    subprocess.run([str(venv / "bin" / "python"), "-m", "pip", "install", "-q", "--upgrade", "pip"], check=True)
    # as ./dev installs it (build isolation: pip fetches the build backend), without the dependencies
    result = subprocess.run([str(venv / "bin" / "python"), "-m", "pip", "install", "-q", "--no-deps",
                             "--disable-pip-version-check", "-e", str(ROOT)], capture_output=True, text=True,
                            cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "Warning" not in result.stdout + result.stderr, result.stdout + result.stderr


# -- scene headers ---------------------------------------------------------------

def test_named_scenes_carry_their_render_flags():
    from converters.scene_flags import read_scene_flags

    assert read_scene_flags(ROOT / "scenes" / "showcase.txt") == {"bounces": 3, "shadows": True}
    assert read_scene_flags(ROOT / "scenes" / "mirrors.txt") == {"bounces": 4, "shadows": True}
    assert read_scene_flags(ROOT / "scenes" / "lamps.txt") == {"shadows": True}


def test_header_applies_where_no_flag_overrides():
    from renderer.cli import build_parser, jobs_from_args

    def job(*words):
        return jobs_from_args(build_parser().parse_args(list(words)))[0]

    plain = job("showcase")
    assert (plain.bounces, plain.shadows, plain.width) == (3, True, 800)
    assert job("showcase", "-bounces", "1").bounces == 1
    assert job("showcase", "-size", "40", "30").shadows
    # the course binary's mode reads no header, as the course binary skips comments
    verbatim = job("-input", str(ROOT / "scenes" / "showcase.txt"), "-output", "x.png")
    assert (verbatim.bounces, verbatim.shadows) == (0, False)


def test_bad_header_is_one_located_error(tmp_path):
    from converters.scene_flags import read_scene_flags

    scene = tmp_path / "s.txt"
    scene.write_text("# a scene\n# render: -bounces 2 -shadow\nPerspectiveCamera {\n")
    with pytest.raises(SceneError) as error:
        read_scene_flags(scene)
    assert str(error.value).startswith(f"{scene}:2:10: ") and "-shadow" in str(error.value)
    scene.write_text("# render: -size 10\n")
    with pytest.raises(SceneError, match="wants 2 numbers"):
        read_scene_flags(scene)
    scene.write_text("PerspectiveCamera {\n# render: -shadows\n")  # not a header: after the first line of scene
    assert read_scene_flags(scene) == {}


def test_default_render_shows_shadows_and_reflections(variant_llvm_ad_rgb, tmp_path):
    """`./dev render` (no flags) renders the showcase as its header says; with
    the header ignored (-input), shadows and the mirror's reflections vanish."""
    from imaging.image_io import read_png
    from renderer.cli import main

    assert main(["-size", "48", "48", "--out", str(tmp_path), "--quiet"]) == 0
    default = read_png(tmp_path / "showcase.png")
    assert main(["showcase", "-size", "48", "48", "-bounces", "3", "-shadows", "--out", str(tmp_path / "f"),
                 "--quiet"]) == 0
    assert np.array_equal(default, read_png(tmp_path / "f" / "showcase.png"))
    assert main(["-input", str(ROOT / "scenes" / "showcase.txt"), "-size", "48", "48", "-output",
                 str(tmp_path / "bare.png"), "--quiet"]) == 0
    assert bad_fraction(default, read_png(tmp_path / "bare.png")) > 0.05


# -- converter ------------------------------------------------------------------

def _xml_values(path: Path) -> dict:
    root = ElementTree.parse(path).getroot()
    values = {}
    for tag in ("integrator", "film", "sampler", "sensor"):
        for element in root.iter(tag):
            for child in element:
                if "name" in child.attrib and "value" in child.attrib:
                    values[f"{tag}.{child.attrib['name']}"] = child.attrib["value"]
    return values


def test_converter_writes_the_render_flags(variant_scalar_rgb, tmp_path):
    from converters.__main__ import main

    target = tmp_path / "t.xml"
    assert main([str(ROOT / "scenes" / "transforms.txt"), "-o", str(target), "-size", "32", "24", "-bounces",
                 "2", "-shadows", "-jitter"]) == 0
    values = _xml_values(target)
    assert values["integrator.bounces"] == "2" and values["integrator.shadows"] == "true"
    assert (values["film.width"], values["film.height"]) == ("32", "24")
    assert values["sampler.sample_count"] == "16" and values["sensor.pixel_centers"] == "false"
    assert main([str(ROOT / "scenes" / "transforms.txt"), "-o", str(target), "-size", "32", "24", "-filter"]) == 0
    assert (_xml_values(target)["film.width"], _xml_values(target)["film.height"]) == ("96", "72")
    # the scene's header fills in what the command line leaves out
    assert main([str(ROOT / "scenes" / "mirrors.txt"), "-o", str(target)]) == 0
    assert _xml_values(target)["integrator.bounces"] == "4"


def _render_xml(path: Path, seed: int = 0) -> np.ndarray:
    import mitsuba as mi

    import mi_plugins

    mi_plugins.register()
    return np.array(mi.render(mi.load_file(str(path), optimize=False), seed=seed), np.float32)[..., :3]


@pytest.mark.parametrize("flags", [["-bounces", "3", "-shadows"], ["-bounces", "2", "-jitter"], ["-filter"]],
                         ids=["bounces-shadows", "jitter", "filter"])
def test_converted_xml_renders_like_render_py(variant_llvm_ad_rgb, tmp_path, flags):
    """Plain `mitsuba.load_file` on the converter's XML gives render.py's image
    with the same flags (within the course-image bar); with -filter after the
    documented downsampling."""
    from converters.__main__ import main as convert
    from imaging.filters import downsample_3x
    from imaging.image_io import read_exr
    from renderer.cli import main as render

    # the mirrors scene without its "# render:" header, so that only the flags given here count
    text = (ROOT / "scenes" / "mirrors.txt").read_text().replace("# render:", "# was:")
    scene, size = str(tmp_path / "mirrors.txt"), ["40", "32"]
    Path(scene).write_text(text)
    for folder in ("meshes", "tex"):
        (tmp_path / folder).symlink_to(ROOT / "scenes" / folder)
    ours = tmp_path / "ours.exr"
    assert render(["-input", scene, "-size", *size, *flags, "-output", str(ours), "--quiet"]) == 0
    channels = read_exr(ours)
    expected = np.stack([channels[c] for c in "RGB"], -1)
    assert convert([scene, "-o", str(tmp_path / "s.xml"), "-size", *size, *flags]) == 0
    image = _render_xml(tmp_path / "s.xml")
    if "-filter" in flags:
        image = downsample_3x(image)
    assert image.shape == expected.shape
    if "-jitter" in flags:
        # render.py draws its jitter offsets from its own hash (so that a render split into
        # launches is the same image), Mitsuba's sampler from another stream: the same
        # estimator, not the same samples. So render.py must differ from the XML's render by
        # no more than a second XML render (another seed) does (render.py without -jitter,
        # at pixel centres, is about twice as far away).
        noise = float(np.mean(np.abs(_render_xml(tmp_path / "s.xml", seed=1) - image)))
        assert float(np.mean(np.abs(expected - image))) <= 1.5 * noise
        assert render(["-input", scene, "-size", *size, "-bounces", "2", "-output", str(ours), "--quiet"]) == 0
        centres = np.stack([read_exr(ours)[c] for c in "RGB"], -1)
        assert float(np.mean(np.abs(centres - image))) > 1.5 * noise  # the check can fail
        return
    assert bad_fraction(encode(image), encode(expected)) <= MAX_BAD_FRACTION
    if flags[0] == "-bounces":  # the check can fail: the XML without the flags is another image
        assert convert([scene, "-o", str(tmp_path / "d.xml"), "-size", *size, "-bounces", "0"]) == 0
        assert bad_fraction(encode(_render_xml(tmp_path / "d.xml")), encode(expected)) > 10 * MAX_BAD_FRACTION


def test_converter_help_is_plain_text(capsys):
    from converters.__main__ import main

    with pytest.raises(SystemExit):
        main(["--help"])
    text = capsys.readouterr().out
    assert "``" not in text and not text.rstrip().endswith("...")
    for option in ("-o OUT", "-size W H", "-bounces N", "-shadows", "-jitter", "-filter", "--spp N"):
        assert option in text
    words = " ".join(text.split())
    assert "default 800 800" in words and "(default 0)" in words and "examples:" in text


def _one_error(capsys, code: int) -> str:
    assert code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("python -m converters: error: ")
    return err


def test_converter_refuses_two_scenes_onto_one_file(variant_scalar_rgb, tmp_path, capsys):
    from converters.__main__ import main

    for folder in ("a", "b"):
        (tmp_path / folder).mkdir()
        shutil.copy(ROOT / "scenes" / "transforms.txt", tmp_path / folder / "scene.txt")
    out = tmp_path / "out"
    err = _one_error(capsys, main([str(tmp_path / "a" / "scene.txt"), str(tmp_path / "b" / "scene.txt"),
                                   "-o", str(out)]))
    assert "both be written to" in err
    assert not out.exists() or not any(out.iterdir())  # refused before writing anything
    err = _one_error(capsys, main([str(tmp_path / "a" / "scene.txt"), str(ROOT / "scenes" / "lamps.txt"),
                                   "-o", str(tmp_path / "one.xml")]))
    assert "give a folder" in err


def test_converter_output_errors_are_one_line(variant_scalar_rgb, tmp_path, capsys):
    from converters.__main__ import main

    scene = str(ROOT / "scenes" / "transforms.txt")
    (tmp_path / "file").write_text("x")
    err = _one_error(capsys, main([scene, str(ROOT / "scenes" / "lamps.txt"), "-o", str(tmp_path / "file")]))
    assert "is a file" in err
    err = _one_error(capsys, main([scene, "-o", str(tmp_path / "file" / "t.xml")]))
    assert "cannot write into" in err
    (tmp_path / "dir.xml").mkdir()
    (tmp_path / "dir.xml" / "transforms.xml").mkdir()
    err = _one_error(capsys, main([scene, "-o", str(tmp_path / "dir.xml")]))
    assert "is a folder" in err
    # an existing file is replaced, and mesh files the new XML does not use are removed
    target = tmp_path / "t.xml"
    target.write_text("old")
    stale = tmp_path / "t_meshes" / "object_99.ply"
    stale.parent.mkdir()
    stale.write_text("stale")
    assert main([scene, "-o", str(target)]) == 0
    assert target.read_text().startswith("<scene") and not stale.exists()


def test_converter_read_only_folder(variant_scalar_rgb, tmp_path, capsys):
    """A folder nobody may write into: one line, exit 2, nothing written. Root
    ignores permission bits, so as root the folder is /sys (read-only for root too)."""
    from converters.__main__ import main

    if os.geteuid() == 0:
        folder = Path("/sys")
        if not folder.is_dir() or os.access(folder, os.W_OK) and _can_create_in(folder):
            pytest.skip("no read-only folder for root here")
    else:
        folder = tmp_path / "ro"
        folder.mkdir()
        folder.chmod(0o555)
    err = _one_error(capsys, main([str(ROOT / "scenes" / "transforms.txt"), "-o", str(folder / "nc_t.xml")]))
    assert f"cannot write into {folder}" in err
    assert not (folder / "nc_t.xml").exists() and not (folder / "nc_t_meshes").exists()


def _can_create_in(folder: Path) -> bool:
    import tempfile

    try:
        with tempfile.TemporaryFile(dir=folder):
            return True
    except OSError:
        return False


# -- progress -------------------------------------------------------------------

def test_result_lines_one_per_scene_without_a_terminal(variant_llvm_ad_rgb, tmp_path, capsys):
    from renderer.cli import main

    assert main(["showcase", "transforms", "-size", "24", "16", "--out", str(tmp_path)]) == 0
    out, err = capsys.readouterr()
    lines = out.splitlines()
    assert len(lines) == 2 and lines[0].startswith("showcase") and lines[1].startswith("transforms")
    # nothing on stderr but, without a usable libLLVM, the one line that says so
    assert err == "" or (err.count("\n") == 1 and "using scalar_rgb instead of llvm_ad_rgb" in err)


def test_bars_only_on_a_terminal(monkeypatch):
    from renderer import progress

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    monkeypatch.setattr(sys, "stderr", io.StringIO())
    assert not progress.bars_wanted(True)
    monkeypatch.setattr(sys, "stderr", Terminal())
    assert progress.bars_wanted(True) and not progress.bars_wanted(False)


def test_converter_writes_spp_and_refuses_what_render_py_refuses(variant_scalar_rgb, tmp_path, capsys):
    """``--spp`` reaches the XML's sampler (it was checked, then dropped), and the
    converter refuses the numbers render.py refuses instead of writing an XML no
    render could run."""
    from converters.__main__ import main

    scene = str(ROOT / "scenes" / "transforms.txt")
    for extra, count in ((["--spp", "7"], 7), (["--spp", "7", "-jitter"], 7), (["-jitter"], 16), ([], 1)):
        target = tmp_path / f"s{len(extra)}_{count}.xml"
        assert main([scene, "-o", str(target), "-size", "8", "8", *extra]) == 0
        sampler = ElementTree.parse(target).getroot().find("sensor/sampler")
        assert sampler.find("integer[@name='sample_count']").get("value") == str(count), extra
    capsys.readouterr()
    for extra, message in ((["--spp", "99999999999"], "--spp wants"), (["-bounces", "5000"], "-bounces wants"),
                           (["-size", "100000", "100000"], "exceed")):
        err = _one_error(capsys, main([scene, "-o", str(tmp_path / "bad.xml"), *extra]))
        assert message in err
        assert not (tmp_path / "bad.xml").exists()


@pytest.mark.parametrize("command", [["converters", "scenes/transforms.txt", "-o", "x.xml", "-size", "32"],
                                     ["converters"], ["denoise", "a", "b", "--bogus"],
                                     ["export", "a.json", "b", "--bogus"]])
def test_argument_errors_are_one_line(command, tmp_path):
    """argparse's usage block is not an error line: every command's parser raises UsageError."""
    result = subprocess.run([sys.executable, "-m", *command], cwd=ROOT, capture_output=True, text=True)
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and result.stderr.startswith(f"python -m {command[0]}: error: ")
