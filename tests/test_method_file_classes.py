"""A method file's classes of faults (docs/own_method.md), each one line naming the file
and line, exit 2: option declarations argparse would reject or misprint, exceptions
that are not ``Exception``s (or whose ``str()`` fails), and a filter that swallows
Ctrl-C, which must still stop the command quickly with nothing written after the signal."""
from __future__ import annotations

import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from helpers import assert_loading_is_one_line, live_server_stopping

ROOT = Path(__file__).resolve().parent.parent


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
    assert_loading_is_one_line(*DECLARATIONS[case], tmp_path, capsys)


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


#: what filter() raises (line 12), with a class defined on line 5, and the one line's end
RAISED = {
    "GeneratorExit": ("", "raise GeneratorExit", r"filter\(\) raised GeneratorExit"),
    "BaseException subclass": ("class Odd(BaseException):\n    pass", "raise Odd('odd')",
                               r"filter\(\) raised Odd: odd"),
    "str() raises": ("class Bad(Exception):\n    def __str__(self):\n        raise RuntimeError('boom')",
                     "raise Bad()", r"filter\(\) raised Bad: \(its message could not be made"),
}


@pytest.mark.parametrize("case", list(RAISED))
def test_any_exception_of_a_filter_is_one_line(case, exported, tmp_path, capsys, registry):
    from denoise.__main__ import main

    head, body, expected = RAISED[case]
    path = tmp_path / "my_filter.py"
    path.write_text(method_file(body, head=head))
    out = tmp_path / "out"
    assert main([str(exported), str(out), "--method-file", str(path), "--method", "mine"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert re.search(r"^python -m denoise: error: mine \(.*my_filter.py:\d+\): ", err), err
    assert re.search(expected, err), err
    assert not (out / "result_0.exr").exists()


@pytest.mark.parametrize(("source", "expected"), [
    ("import sys\nraise GeneratorExit\n", r"my_filter.py:2: GeneratorExit"),
    ("class Odd(BaseException):\n    pass\n\n\nraise Odd('x')\n", r"my_filter.py:5: Odd: x"),
    ("class Bad(Exception):\n    def __str__(self):\n        raise RuntimeError('boom')\n\n\nraise Bad()\n",
     r"my_filter.py:6: Bad: \(its message could not be made"),
])
def test_any_exception_at_import_is_one_line(source, expected, tmp_path, capsys, registry):
    from denoise.__main__ import main

    path = tmp_path / "my_filter.py"
    path.write_text(source)
    assert main(["--method-file", str(path), "--help"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert re.search(f"^python -m denoise: error: {re.escape(str(tmp_path))}/{expected}", err), err


def test_a_base_exception_in_the_benchmark_is_one_line(tmp_path):
    """python -m benchmarks.denoise --methods mine: the same line (a command of its own)."""
    path = tmp_path / "my_filter.py"
    path.write_text(method_file("raise GeneratorExit"))
    done = subprocess.run([sys.executable, "-m", "benchmarks.denoise", "--quick", "--no-timing", "--sequences",
                           "glossy_shadow", "--work", str(tmp_path / "bench"), "--method-file", str(path),
                           "--methods", "mine"], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr[-3000:]
    assert re.search(r"error: mine \(.*my_filter.py:12\): filter\(\) raised GeneratorExit", done.stderr), done.stderr


def stop_while_filtering(signum: int, body: str, exported: Path, tmp_path: Path) -> None:
    """``python -m denoise`` with a method whose filter runs ``body`` after marking that it
    started: the signal then stops the command within 2 s (130 / 143, one line), with
    nothing written after it, not even a temporary file."""
    mark = tmp_path / "filtering"
    path = tmp_path / "my_filter.py"
    path.write_text(method_file(f"open({str(mark)!r}, 'w').close()\n{body}"))
    out = tmp_path / "out"
    process = subprocess.Popen([sys.executable, "-m", "denoise", str(exported), str(out), "--method-file", str(path),
                                "--method", "mine"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True)
    try:
        deadline = time.monotonic() + 240
        while not mark.exists() and process.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert mark.exists(), process.communicate(timeout=10)
        time.sleep(0.3)
        process.send_signal(signum)
        sent = time.monotonic()
        err = process.communicate(timeout=15)[1]
        took = time.monotonic() - sent
    finally:
        if process.poll() is None:
            process.kill()
            process.wait(10)
    assert process.returncode == 128 + signum and err.count("\n") == 1 and "Traceback" not in err, err
    assert took < 2.0, took
    assert not list(out.glob("*")) if out.exists() else True


@pytest.mark.timed
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_filter_that_swallows_the_stop_signal_still_stops(signum, exported, tmp_path):
    """The filter catches the interruption and returns: the command still stops at once."""
    stop_while_filtering(signum, "        try:\n            time.sleep(100)\n        except BaseException:\n"
                         "            pass\n        return arrays.tensor(arrays.color)", exported, tmp_path)


@pytest.mark.timed
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_filter_that_never_lets_the_stop_signal_out_still_stops(signum, exported, tmp_path):
    """The filter loops for ever, swallowing every interruption: the handler's watchdog ends
    the command once its grace period is over."""
    stop_while_filtering(signum, "        while True:\n            try:\n                time.sleep(0.2)\n"
                         "            except BaseException:\n                pass", exported, tmp_path)


@pytest.mark.parametrize("raised", ["GeneratorExit", "Odd('odd')"])
def test_a_base_exception_when_the_live_page_switches_to_the_method_is_one_line(raised, tmp_path):
    """python -m denoise.live: the page switches from svgf to the method, whose filter raises
    an exception that is not an Exception: the server stops in the one line, exit 2."""
    from core.libllvm import find_libllvm

    if find_libllvm() is None:
        pytest.skip("no usable libLLVM: the live page needs a JIT variant")
    path = tmp_path / "my_filter.py"
    path.write_text(method_file(f"raise {raised}", head="class Odd(BaseException):\n    pass"))
    code, err = live_server_stopping(path, "svgf", switch_to="mine")
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err, (code, err)
    assert re.search(r"^python -m denoise.live: error: mine \(.*my_filter.py:\d+\): filter\(\) raised "
                     r"(GeneratorExit|Odd: odd)$", err), err
