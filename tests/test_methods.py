"""The registry of denoising methods: one class per method, and everything
that lists methods (``python -m denoise``, the benchmark, the docs) made from it."""
from __future__ import annotations

import inspect
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from denoise.filters import pack
from denoise.methods import (
    METHODS,
    DeclarationError,
    DenoisingMethod,
    Option,
    benchmark_names,
    from_name,
    make,
    method_names,
    register,
)

ROOT = Path(__file__).resolve().parent.parent


class Box(DenoisingMethod):
    """A (2 box_radius + 1)² box filter of each frame, no history: a method
    defined outside the package."""
    name = "box"
    description = "a box filter defined by tests/test_methods.py"
    options = (Option("box_radius", 1, "the box's half width", kind=int, low=1, high=4, step=1, group="box"),)
    benchmark = ("box",)

    def __init__(self, **props):
        super().__init__(**props)
        self.radius = self.props["box_radius"]

    def filter(self, arrays, frame, index, valid):
        packed = pack(arrays.color)
        total = mi.Vector3f(0.0)
        for dy in range(-self.radius, self.radius + 1):
            for dx in range(-self.radius, self.radius + 1):
                total += arrays.gather(packed, arrays.x + dx, arrays.y + dy)
        result = total / (2 * self.radius + 1) ** 2
        dr.eval(result)
        return arrays.tensor(result)


@pytest.fixture
def registered_box():
    """:class:`Box` in the registry for one test."""
    before = dict(METHODS)
    register(Box)
    yield Box
    METHODS.clear()
    METHODS.update(before)



def box_numpy(image: np.ndarray, radius: int) -> np.ndarray:
    padded = np.pad(image.astype(np.float64), ((radius, radius), (radius, radius), (0, 0)), mode="edge")
    h, w = image.shape[:2]
    return sum(padded[radius + dy:radius + dy + h, radius + dx:radius + dx + w]
               for dy in range(-radius, radius + 1) for dx in range(-radius, radius + 1)) / (2 * radius + 1) ** 2


def test_a_method_defined_here_is_listed_and_runs(registered_box, exported, tmp_path, capsys):
    """Registering one class is all it takes: ``--method box`` and its option in
    ``--help``, the command runs it on an exported folder with its parameter,
    and refuses a bad value in one line."""
    from denoise.__main__ import main
    from denoise.methods.listing import method_list
    from export.frames import read_frame
    from imaging.image_io import read_exr_rgb

    with pytest.raises(SystemExit) as exit_code:
        main(["--help"])
    assert exit_code.value.code == 0
    text = capsys.readouterr().out
    assert "  box " in text and "a box filter defined by tests/test_methods.py" in text
    assert "box (box):" in text and "--box-radius" in text and "--method NAME" in text  # NAME: any of the list
    assert list(METHODS)[-1] == "box"
    assert "`box`" in method_list() and "box" in benchmark_names()

    assert main([str(exported), str(tmp_path / "out"), "--method", "box", "--box-radius", "2"]) == 0
    for i in (0, 1):
        result = read_exr_rgb(tmp_path / "out" / f"result_{i}.exr")
        expected = box_numpy(read_frame(exported, i).beauty, 2)
        assert np.max(np.abs(result - expected)) < 1e-5
        assert np.max(np.abs(result - box_numpy(read_frame(exported, i).beauty, 1))) > 1e-3  # the radius counted
    capsys.readouterr()
    assert main([str(exported), str(tmp_path / "bad"), "--method", "box", "--box-radius", "9"]) == 2
    err = capsys.readouterr().err
    assert err == "python -m denoise: error: box: --box-radius must be a whole number from 1 to 4, got 9\n"


def test_a_method_name_is_registered_once(registered_box):
    class Other(Box):
        pass

    with pytest.raises(DeclarationError, match="taken by Box"):
        register(Other)

    class Nameless(DenoisingMethod):
        pass

    with pytest.raises(DeclarationError, match="needs a name"):
        register(Nameless)


def test_the_docs_page_is_the_registry():
    """docs/denoising_methods.md's method list is what ``python -m denoise.methods --write`` makes."""
    from denoise.methods.listing import DOC, with_method_list

    text = DOC.read_text()
    assert text == with_method_list(text), "run python -m denoise.methods --write"


@pytest.mark.parametrize("name", list(METHODS))
def test_each_method_documents_its_options(name):
    """The docs list each option from its declaration (no docstring copies a
    default by hand); a description is one line."""
    from denoise.methods.listing import method_list

    cls = METHODS[name]
    assert "Parameters:" not in inspect.getdoc(cls)
    section = method_list().split(f"### `{name}` ", 1)[1].split("\n### ", 1)[0]
    for option in cls.options:
        assert f"| `{option.flag}` |" in section, option.flag
        if option.kind in (int, float):  # a file name (learned-asvgf's --network) has no range
            assert option.range_text() in section, option.flag
    assert cls.description and "\n" not in cls.description


def test_benchmark_names_make_their_methods():
    """Every benchmark name of the registry makes its method, with what the name says."""
    from denoise.methods.atrous import Atrous
    from denoise.methods.oidn import OIDNMethod
    from denoise.methods.svgf import SVGF

    names = benchmark_names()
    assert len(set(names)) == len(names)
    for name in names:
        from_name(name)
    method = from_name("demod+outliers+atrous+temporal")
    assert isinstance(method, Atrous) and method.temporal and method.demodulate and method.outliers.k == 2.0
    assert not from_name("atrous").temporal
    svgf = from_name("svgf")
    assert isinstance(svgf, SVGF) and svgf.temporal and svgf.demodulate  # temporal by nature, always demodulates
    for quality in ("fast", "balanced", "high"):
        oidn = from_name(f"oidn-{quality}")
        assert isinstance(oidn, OIDNMethod) and oidn.params.quality == quality and not oidn.temporal
    guided = from_name("oidn-guided")
    assert guided.temporal and guided.temporal_params.clamp_radius == 1 and guided.params.quality == "high"
    for bad in ("nosuch", "atrous+svgf", "atrous+later", "oidn-medium"):
        with pytest.raises(Exception, match="unknown method"):
            from_name(bad)


def test_oidn_quality_reaches_its_parameters(tmp_path, capsys):
    """``--oidn-quality`` is OIDNParams.quality (default high); a bad one is one line."""
    from core.errors import UsageError
    from denoise.__main__ import main
    from denoise.methods.oidn import OIDNParams

    assert make("oidn").params == OIDNParams(quality="high")
    assert make("oidn-guided", oidn_quality="fast").params.quality == "fast"
    with pytest.raises(UsageError, match="unknown OIDN quality 'best'; choose from fast, balanced, high"):
        OIDNParams(quality="best")
    assert main([str(tmp_path), str(tmp_path / "out"), "--method", "oidn", "--oidn-quality", "best"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--oidn-quality: invalid choice: 'best'" in err


def test_a_range_changed_in_its_declaration_is_followed_everywhere(monkeypatch, tmp_path, capsys):
    """One declaration: narrowing ``--clip-width``'s range in asvgf's options
    changes ``--help``, the error of ``python -m denoise``, the generated docs
    and the live page's slider, and nothing else needs editing."""
    from dataclasses import replace

    from denoise.__main__ import main
    from denoise.live.methods import sliders_of
    from denoise.methods.asvgf import ASVGF
    from denoise.methods.listing import method_list

    narrowed = tuple(replace(o, high=5.0, span=(o.span[0], 5.0)) if o.key == "clip_width" else o for o in ASVGF.options)
    monkeypatch.setattr(ASVGF, "options", narrowed)

    with pytest.raises(SystemExit):
        main(["--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert "this sigma: a number from 0 to 5 (default fitted" in help_text
    assert main([str(tmp_path), str(tmp_path / "out"), "--method", "asvgf", "--clip-width", "6"]) == 2
    assert capsys.readouterr().err == ("python -m denoise: error: asvgf: --clip-width must be a number from 0 to 5, "
                                       "got 6.0\n")
    assert "| `--clip-width` | fitted (hand-set 1) | a number from 0 to 5 |  | 0.05 to 5, step 0.05 |" in method_list()
    assert next(s for s in sliders_of("asvgf") if s.name == "clip_width").high == 5.0


def test_a_bad_declaration_names_its_line():
    """An option whose default is outside its range, or whose key is not a field name, is one line naming where."""
    with pytest.raises(DeclarationError, match=r"test_methods.py:\d+: option 'width': its default is out of"):
        Option("width", 9, "a width", kind=int, low=1, high=4)
    with pytest.raises(DeclarationError, match=r"test_methods.py:\d+: option '--width': the key must be"):
        Option("--width", 1, "a width", kind=int)


def test_a_flag_declared_differently_names_both_declarations(registered_box):
    """A method of one's own whose ``--radius`` has other help than bilateral's: one line naming both."""
    class Wide(DenoisingMethod):
        name, description = "wide", "a method with its own --radius"
        options = (Option("radius", 2, "another radius", kind=int, low=0, high=9),)

    with pytest.raises(DeclarationError) as error:
        register(Wide)
    text = str(error.value)
    assert "\n" not in text and "test_methods.py:" in text and "bilateral at " in text and "bilateral.py:" in text
    assert "wide" not in METHODS


def test_one_name_one_meaning_in_every_command(tmp_path, capsys):
    """``bilateral`` is the filter without history wherever a method is named
    (``python -m denoise --method``, the benchmark, ``denoise.score --compare``,
    the live page: all :func:`resolve`); ``bilateral+temporal`` accumulates.
    A flag the name contradicts or leaves unused is one line."""
    from denoise.__main__ import _parser, check_options_apply
    from denoise.live.methods import METHOD_NAMES

    assert not from_name("bilateral").temporal and from_name("bilateral+temporal").temporal
    assert not make("bilateral").temporal and make("bilateral+temporal").temporal  # the Python API too
    parser, _ = _parser()
    for name in ("bilateral", "bilateral+temporal", "atrous", "atrous+temporal", "svgf", "oidn-fast"):
        assert name in method_names() and name in METHOD_NAMES
        assert parser.parse_args(["a", "b", "--method", name]).method == name
    assert parser.parse_args(["a", "b"]).method == "atrous+temporal"  # the default accumulates, as before
    for name, flags, message in (("bilateral", {"alpha": 0.5}, "--alpha is an option of the temporal accumulation"),
                                 ("atrous+temporal", {"temporal": False}, "accumulates by its name; use atrous"),
                                 ("atrous", {"temporal": False}, "has no history already")):
        with pytest.raises(Exception, match=message):
            check_options_apply(name, flags)
    check_options_apply("svgf", {"temporal": False})


@pytest.mark.parametrize("name", ["demod+outliers+atrous+temporal", "outliers+bilateral", "demod+svgf", "oidn",
                                  "oidn-fast", "oidn+temporal", "atrous+temporal"])
def test_denoise_takes_every_name_resolve_takes(name):
    """``python -m denoise --method`` takes the names of every command (docs/scores.md), prefixes included."""
    from denoise.__main__ import _parser
    from denoise.methods import resolve

    resolve(name)
    assert _parser()[0].parse_args(["in", "out", "--method", name]).method == name


def test_an_unknown_method_name_is_one_line(tmp_path, capsys):
    from denoise.__main__ import main

    assert main([str(tmp_path), str(tmp_path / "out"), "--method", "atrous+later"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("python -m denoise: error: unknown method 'atrous+later'; known:")


@pytest.mark.parametrize(("name", "quality", "refused"), [("oidn-fast", "high", True), ("oidn-balanced", "fast", True),
                                                          ("oidn-fast", "fast", False), ("oidn", "fast", False)])
def test_an_option_that_contradicts_the_preset_is_refused(name, quality, refused, tmp_path, capsys):
    """``oidn-fast`` means --oidn-quality fast in every command: another quality is one line."""
    from denoise.__main__ import main

    code = main([str(tmp_path / "none"), str(tmp_path / "out"), "--method", name, "--oidn-quality", quality])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    if refused:
        assert err == (f"python -m denoise: error: --oidn-quality {quality}: {name} means --oidn-quality "
                       f"{name.split('-')[1]} (use --method oidn --oidn-quality {quality}, or leave --oidn-quality "
                       "out)\n")
    else:  # past the method's checks: the missing folder is the error
        assert "none" in err and "oidn" not in err, err


def test_the_live_page_lists_every_method_name():
    """The live page offers every ``python -m denoise --method`` name (``oidn`` included) and raw."""
    from denoise.live.methods import METHOD_NAMES, page_names

    assert set(method_names()) <= set(page_names()) and "oidn" in METHOD_NAMES and METHOD_NAMES[0] == "raw"


def test_a_prefixed_name_runs_in_python_m_denoise(exported, tmp_path):
    from denoise.__main__ import main

    assert main([str(exported), str(tmp_path / "out"), "--method", "demod+outliers+atrous+temporal"]) == 0
    assert (tmp_path / "out" / "result_1.exr").exists()


def test_help_names_the_methods_each_option_applies_to():
    """A --help group's title lists every method with an option in it; an option
    that fewer of them read says which ("--sigma-color ...; bilateral, atrous
    only"): the title alone sent users to asvgf --sigma-color, which it refuses."""
    import re

    from denoise.__main__ import _parser
    from denoise.methods import declared_options

    parser, _ = _parser()
    checked = 0
    for group in parser._action_groups:
        titled = re.fullmatch(r"(.+) \((.+)\)", group.title or "")
        if not titled:
            continue
        for action in group._group_actions:
            readers = [name for name, _ in declared_options()[action.option_strings[0]][1]]
            if readers != titled.group(2).split(", "):
                assert action.help.endswith(f"; {', '.join(readers)} only"), (action.option_strings, action.help)
                checked += 1
    assert checked >= 2  # --sigma-color and --sigma-normal at least


@pytest.mark.parametrize("name, message", [
    ("svgf+temporal", "svgf is temporal by nature; drop +temporal"),
    ("asvgf+temporal", "asvgf is temporal by nature; drop +temporal"),
    ("oidn-guided+temporal", "oidn-guided is temporal by nature; drop +temporal"),
    # a part twice, or out of order, ran as the name written once: two names for one method
    *((name, f"method '{name}': write it [demod+][outliers+]atrous[+temporal], each part once and in that order")
      for name in ("atrous+temporal+temporal", "demod+demod+atrous", "outliers+outliers+atrous",
                   "outliers+demod+atrous", "temporal+atrous", "atrous+demod")),
    # a method temporal by nature is not offered [+temporal], which it refuses
    *((name, f"method '{name}': write it [demod+][outliers+]asvgf, each part once and in that order")
      for name in ("demod+demod+asvgf", "asvgf+demod")),
])
def test_temporal_on_a_method_that_cannot_take_it_is_refused(name, message):
    """svgf+temporal ran as svgf, the same bytes: a name that changes nothing is refused, not ignored."""
    import re

    from core.errors import UsageError
    from denoise.methods import accumulates, method_names, resolve

    with pytest.raises(UsageError, match=re.escape(message)):
        resolve(name)
    assert all(resolve(n) for n in method_names())  # every name a command offers still resolves
    assert resolve("atrous+temporal")[1]["temporal"] and not accumulates(resolve("svgf")[0])
