"""A method file's classes of faults (docs/own_method.md), each one line naming the file
and line, exit 2: option declarations argparse would reject or misprint, exceptions
that are not ``Exception``s (or whose ``str()`` fails), and a filter that swallows
Ctrl-C, which must still stop the command quickly with nothing written after the signal."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from denoise.methods import METHODS

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture
def registry():
    """The registry (and the live page's lists) as they were, after the test."""
    from denoise.live.methods import refresh

    before = dict(METHODS)
    yield
    METHODS.clear()
    METHODS.update(before)
    refresh()


def method_file(body: str = "return arrays.tensor(arrays.color)", options: str = "()",
                description: str = "'mine'", head: str = "") -> str:
    """A method file: the options on line 9, filter()'s body on line 12 (``head`` on line 5)."""
    return ("import time\nimport mitsuba as mi\nfrom denoise.methods import DenoisingMethod, Option\n\n"
            f"{head}\n\nclass M(DenoisingMethod):\n    name, description = 'mine', {description}\n"
            f"    options = {options}\n\n    def filter(self, arrays, frame, index, valid):\n        {body}\n")


def one_option(text: str) -> str:
    return method_file(options=f"({text},)")


#: declarations argparse cannot take or would print wrongly: (source, the line's expected end)
DECLARATIONS = {
    "bogus action": (one_option("Option('w', False, 'h', kind=None, action='bogus')"), r"my_filter.py:9: .*action"),
    "version action": (one_option("Option('w', False, 'h', kind=None, action='version')"), r"my_filter.py:9: .*action"),
    "help action": (one_option("Option('w', False, 'h', kind=None, action='help')"), r"my_filter.py:9: .*action"),
    "escape in metavar": (one_option("Option('w', 1.0, 'h', metavar='\\x1b[31mW')"),
                          r"my_filter.py:9: option 'w': .*metavar"),
    "newline in help": (one_option("Option('w', 1.0, 'one\\ntwo')"), r"my_filter.py:9: option 'w': .*help"),
    "help not text": (one_option("Option('w', 1.0, 3)"), r"my_filter.py:9: option 'w': .*help"),
    "newline in description": (method_file(description="'one\\ntwo'"), r"my_filter.py:7: M: .*description"),
    "description not text": (method_file(description="3"), r"my_filter.py:7: M: .*description"),
}


@pytest.mark.parametrize("case", list(DECLARATIONS))
def test_a_declaration_argparse_cannot_take_is_one_line(case, tmp_path, capsys, registry):
    from denoise.__main__ import main

    source, expected = DECLARATIONS[case]
    path = tmp_path / "my_filter.py"
    path.write_text(source)
    assert main(["--method-file", str(path), "--help"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err and "\x1b" not in err, err
    assert re.search(f"^python -m denoise: error: {re.escape(str(tmp_path))}/{expected}", err), err


@pytest.mark.parametrize("option", ["Option('w', 1.0, 'h %')", "Option('w', 1.0, 'h', unit='%')",
                                    "Option('w', 1.0, 'h', default_text='%(default)s %')"])
def test_a_percent_sign_in_help_text_is_printed_as_written(option, tmp_path, capsys, registry):
    from denoise.__main__ import main

    path = tmp_path / "my_filter.py"
    path.write_text(one_option(option))
    with pytest.raises(SystemExit) as done:
        main(["--method-file", str(path), "--help"])
    assert done.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "--w W" in text and ("h %" in text or "in %" in text or "(default %(default)s %)" in text), text
