"""The README and docs/ as a reader meets them: every relative link leads to
a file, and every command in a fenced shell block parses with its program's
own argument parser.

Commands are parsed, never run: one child process runs each program's entry
point (``runpy``, as ``python -m`` and ``python render.py`` do) with
``argparse.ArgumentParser.parse_args`` replaced by one that parses and then
stops the program. Bad flags, missing or extra arguments and values the
parser's types refuse fail the way they fail for a user. ``./dev`` commands
are checked against the script's own subcommands, pytest's flags against
``pytest --help``.
"""
from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

#: Pages other helpers write; links to them are reported, not failed, until
#: they exist (after the merge): page -> what it is
PENDING_PAGES = {
    "docs/denoising_methods.md": "the denoising methods, generated from the method registry",
    "docs/live.md": "python -m denoise.live",
    "docs/asvgf.md": "the A-SVGF method",
    "docs/oidn.md": "OIDN 2 as the baseline",
    "docs/scores.md": "python -m course.score and python -m denoise.score",
    "docs/export.md": "python -m export",
}

#: Fenced blocks whose lines are shell commands (an unlabelled block may be a diagram)
SHELL_BLOCKS = {"bash", "sh", "shell", "console"}
FENCE = re.compile(r"^(\s*)(```+|~~~+)\s*([\w+-]*)")
LINK = re.compile(r"!?\[(?:[^\]\[]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
HTML_SOURCE = re.compile(r"<(?:img|a|source|video)\b[^>]*?\b(?:src|href)=\"([^\"]+)\"", re.I)
INLINE_CODE = re.compile(r"(`+).+?\1")
SCHEME = re.compile(r"^[a-z][a-z0-9+.-]*:", re.I)


def pages(root: Path = ROOT) -> list[Path]:
    return [root / "README.md", *sorted((root / "docs").rglob("*.md"))]


def split_fences(text: str) -> tuple[list[tuple[int, str]], list[tuple[int, str, list[tuple[int, str]]]]]:
    """(prose lines, fenced blocks): numbered lines outside fences, and per
    block its first line number, its language and its numbered lines."""
    prose, blocks, block = [], [], None
    for number, line in enumerate(text.splitlines(), 1):
        fence = FENCE.match(line)
        if block is None and fence:
            block = (number, fence.group(3).lower(), [], fence.group(2))
        elif block is not None and line.strip().startswith(block[3]) and not line.strip()[len(block[3]):].strip():
            blocks.append(block[:3])
            block = None
        elif block is not None:
            block[2].append((number, line))
        else:
            prose.append((number, line))
    return prose, blocks


# -- links ----------------------------------------------------------------------------

def links(page: Path) -> list[tuple[int, str]]:
    """The relative link targets of a page outside code: (line, target without its anchor)."""
    prose, _ = split_fences(page.read_text())
    found = []
    for number, line in prose:
        line = INLINE_CODE.sub("", line)
        for target in LINK.findall(line) + HTML_SOURCE.findall(line):
            if SCHEME.match(target) or target.startswith("#"):
                continue
            found.append((number, target.split("#", 1)[0]))
    return found


def broken_links(root: Path = ROOT) -> tuple[list[str], set[str]]:
    """(``page:line: target`` for each link that leads nowhere, the pending pages linked to)."""
    broken, pending = [], set()
    for page in pages(root):
        for number, target in links(page):
            resolved = (page.parent / target).resolve()
            relative = resolved.relative_to(root).as_posix() if resolved.is_relative_to(root) else None
            if resolved.exists() and relative is not None:
                continue
            if relative in PENDING_PAGES:
                pending.add(relative)
                continue
            broken.append(f"{page.relative_to(root)}:{number}: {target}")
    return broken, pending


def test_every_relative_link_resolves():
    broken, _ = broken_links()
    assert not broken, "links to nothing:\n" + "\n".join(broken)


def test_pages_that_other_helpers_write():
    """Skipped, naming them, while a page linked to is still to come."""
    _, pending = broken_links()
    missing = sorted(page for page in pending if not (ROOT / page).exists())
    if missing:
        pytest.skip("linked, written on another branch: " + ", ".join(missing))


def test_a_broken_link_is_found(tmp_path):
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "real.md").write_text("# real\n")
    (tmp_path / "README.md").write_text("[ok](docs/real.md#top) [gone](docs/gone.md)\n"
                                        "`[in code](nowhere.md)` <img src=\"docs/missing.png\">\n"
                                        "```bash\n[in a block](nowhere.md)\n```\n")
    broken, _ = broken_links(tmp_path)
    assert broken == ["README.md:1: docs/gone.md", "README.md:2: docs/missing.png"]


# -- commands -------------------------------------------------------------------------

PYTHON = re.compile(r"(^|/)python(3(\.\d+)?)?$")
ASSIGNMENT = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*=")
OPERATORS = {";", "&&", "||", "|", "&"}


def shell_lines(block: list[tuple[int, str]]) -> list[tuple[int, str]]:
    """A block's commands, ``\\`` continuations joined and ``$`` prompts removed."""
    lines, pending, start = [], "", 0
    for number, line in block:
        if not pending:
            start = number
        stripped = line.strip()
        if stripped.startswith("$ "):
            stripped = stripped[2:]
        if stripped.endswith("\\"):
            pending += stripped[:-1] + " "
            continue
        lines.append((start, pending + stripped))
        pending = ""
    if pending:
        lines.append((start, pending))
    return lines


def clean(token: str) -> str | None:
    """A usage-style token as an argument: ``[--frames`` -> ``--frames``, ``…`` dropped."""
    token = token.strip("[]")
    return None if token in ("", "...", "…") else token


def program_of(words: list[str]) -> tuple[str, str, list[str]] | None:
    """(kind, name, arguments) of one simple command, or None for commands not
    checked here (``cd``, ``mkdir``, ``dask``, ``python -c``, ...)."""
    while words and (ASSIGNMENT.match(words[0]) or words[0] in ("time", "env")):
        words = words[1:]
    if not words:
        return None
    head, rest = words[0], words[1:]
    if head in ("./dev", "dev"):
        return ("dev", rest[0] if rest else "render", rest[1:])
    if head.endswith("render.py"):
        return ("script", "render.py", rest)
    if not PYTHON.search(head) or not rest:
        return None
    if rest[0] == "-m" and len(rest) > 1:
        if rest[1] == "pytest":
            return ("pytest", "pytest", rest[2:])
        return ("module", rest[1], rest[2:])
    if rest[0].endswith("render.py"):
        return ("script", "render.py", rest[1:])
    return None


def commands(page: Path) -> list[dict]:
    """Every checked command of the page's shell blocks: where, what, which arguments."""
    _, blocks = split_fences(page.read_text())
    found = []
    for _, language, block in blocks:
        if language not in SHELL_BLOCKS:
            continue
        for number, line in shell_lines(block):
            lexer = shlex.shlex(line, posix=True, punctuation_chars=True)
            lexer.whitespace_split = True
            try:
                tokens = list(lexer)
            except ValueError as error:
                found.append({"where": f"{page.name}:{number}", "line": line, "error": f"shell syntax: {error}"})
                continue
            segment: list[str] = []
            for token in tokens + [";"]:
                if token not in OPERATORS:
                    if clean(token) is not None:
                        segment.append(clean(token))
                    continue
                program = program_of(segment)
                segment = []
                if program:
                    kind, name, arguments = program
                    found.append({"where": f"{page.name}:{number}", "line": line, "kind": kind, "name": name,
                                  "args": arguments})
    return found


def dev_subcommands() -> set[str]:
    """The subcommands ``./dev``'s case statement accepts."""
    script = (ROOT / "dev").read_text()
    case = script.split('case "$command" in', 1)[1].split("esac", 1)[0]
    return {name for names in re.findall(r"^\s*([a-z|]+)\)", case, flags=re.M) for name in names.split("|")}


def pytest_flags() -> str:
    result = subprocess.run([sys.executable, "-m", "pytest", "--help", "-p", "no:cacheprovider"], cwd=ROOT,
                            capture_output=True, text=True, timeout=120)
    return result.stdout


def unknown_pytest_flags(arguments: list[str], help_text: str) -> list[str]:
    unknown = []
    for argument in arguments:
        if not argument.startswith("-") or argument == "-":
            continue
        flag = argument.split("=", 1)[0] if argument.startswith("--") else argument[:2]
        if not re.search(rf"(^|[\s,]){re.escape(flag)}([\s,=]|$)", help_text, flags=re.M):
            unknown.append(argument)
    return unknown


def parse_in_child(checks: list[dict]) -> list[dict]:
    """Runs :func:`child` on ``checks``; returns each with ``ok`` and ``message``."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), str(ROOT / "tests")]),
               PYTHONDONTWRITEBYTECODE="1")
    result = subprocess.run([sys.executable, "-c", "import test_docs; test_docs.child()"], cwd=ROOT, env=env,
                            input=json.dumps(checks), capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    return json.loads(result.stdout.rsplit("\n", 2)[-2])


#: (page, file name) -> where that page's method file is saved for the commands that name it
SCRATCH: dict[tuple[str, str], Path] = {}


def with_method_files(command: dict) -> dict:
    """``command`` with each ``--method-file NAME`` pointed at the page's own
    Python block, saved under NAME in a scratch folder (the page tells the
    reader to save it so: docs/own_method.md)."""
    args = list(command["args"])
    for i, word in enumerate(args[:-1]):
        if word == "--method-file":
            page = next(p for p in pages() if p.name == command["where"].split(":")[0])
            code = re.search(r"```python\n(.*?)```", page.read_text(), re.S)
            saved = SCRATCH.setdefault((page.name, Path(args[i + 1]).name), Path(tempfile.mkdtemp()) / args[i + 1])
            saved.write_text(code.group(1) if code else "")  # one file per page: its commands share one process
            args[i + 1] = str(saved)
    return dict(command, args=args)


def check(found: list[dict]) -> list[str]:
    """``page:line: command: why`` for every command that does not parse, in page order."""
    found = [dict(c, order=i) for i, c in enumerate(found)]
    failures = [(c["order"], f"{c['where']}: {c['line']}: {c['error']}") for c in found if "error" in c]
    runnable, help_text, subcommands = [], None, dev_subcommands()
    for command in (c for c in found if "error" not in c):
        if command["kind"] == "dev":
            if command["name"] not in subcommands:
                failures.append((command["order"], f"{command['where']}: {command['line']}: ./dev has no "
                                 f"subcommand {command['name']!r} ({', '.join(sorted(subcommands))})"))
            elif command["name"] == "render":
                runnable.append(dict(command, kind="script", name="render.py"))
            elif command["name"] == "test":
                runnable.append(dict(command, kind="pytest"))
            continue
        runnable.append(command)
    for command in runnable:
        if command["kind"] == "pytest":
            help_text = help_text if help_text is not None else pytest_flags()
            unknown = unknown_pytest_flags(command["args"], help_text)
            if unknown:
                failures.append((command["order"], f"{command['where']}: {command['line']}: pytest has no flag "
                                 f"{unknown[0]}"))
    to_parse = [with_method_files(c) for c in runnable if c["kind"] != "pytest"]
    parsed = parse_in_child(to_parse) if to_parse else []
    failures += [(c["order"], f"{c['where']}: {c['line']}: {c['message']}") for c in parsed if not c["ok"]]
    return [line for _, line in sorted(failures)]


def test_every_command_in_the_docs_parses():
    found = [command for page in pages() for command in commands(page)]
    assert len(found) >= 10, "the pages' command blocks were not found"
    failures = check(found)
    assert not failures, "commands that do not parse:\n" + "\n".join(failures)


def test_a_misspelt_flag_and_a_missing_argument_are_found(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("```bash\n"
                    "python render.py scene06 --varient scalar_rgb   # misspelt\n"
                    "./dev render showcase -size 64 64 && python -m converters scenes/showcase.txt -o \\\n"
                    "    x.xml -sise 4 4\n"
                    "python -m denoise out/seq/lamps\n"
                    "./dev tests -x\n"
                    "./dev test -x --no-such-pytest-flag\n"
                    "python -m export [--frames 2] scenes/sequences/dolly_lamps.json out/seq/lamps\n"
                    "```\n")
    found = commands(page)
    assert [(c["kind"], c["name"]) for c in found] == [
        ("script", "render.py"), ("dev", "render"), ("module", "converters"), ("module", "denoise"),
        ("dev", "tests"), ("dev", "test"), ("module", "export")]
    failures = check(found)
    assert len(failures) == 5, "\n".join(failures)
    assert "--varient" in failures[0] and failures[0].startswith("page.md:2:")
    assert "-sise" in failures[1] and failures[1].startswith("page.md:3:")
    assert "required" in failures[2] and failures[2].startswith("page.md:5: python -m denoise out/seq/lamps:")
    assert "./dev has no subcommand 'tests'" in failures[3]
    assert "--no-such-pytest-flag" in failures[4]


# -- the child: parse, never run ---------------------------------------------------------

class Parsed(BaseException):
    """Raised instead of returning from the outermost ``parse_args``: the program stops there."""


def child() -> None:
    """Reads checks as JSON on stdin, parses each with its program's own
    parser, prints the checks with ``ok`` and ``message`` as the last line."""
    import argparse
    import contextlib
    import importlib.util
    import io
    import runpy

    original_parse_args = argparse.ArgumentParser.parse_args
    original_known = argparse.ArgumentParser.parse_known_args
    depth = [0]

    def parse_args(self, args=None, namespace=None):
        if depth[0]:
            return original_parse_args(self, args, namespace)
        depth[0] += 1
        try:
            original_parse_args(self, args, namespace)
        finally:
            depth[0] -= 1
        raise Parsed()

    def parse_known_args(self, args=None, namespace=None):
        if depth[0]:
            return original_known(self, args, namespace)
        depth[0] += 1
        try:
            original_known(self, args, namespace)
        finally:
            depth[0] -= 1
        raise Parsed()

    argparse.ArgumentParser.parse_args = parse_args
    argparse.ArgumentParser.parse_known_args = parse_known_args
    checks = json.loads(sys.stdin.read())
    for check in checks:
        if check["kind"] == "module":
            spec = importlib.util.find_spec(check["name"])
            if spec is None:
                check.update(ok=False, message=f"no module {check['name']}")
                continue
            if spec.submodule_search_locations:  # a package: python -m runs its __main__
                spec = importlib.util.find_spec(check["name"] + ".__main__")
            source = Path(spec.origin).read_text() if spec and spec.origin else ""
            # a thin __main__ hands over to a module of its package (export.cli)
            for imported in re.findall(r"^\s*from ([\w.]+) import main\b", source, re.M):
                found = importlib.util.find_spec(imported, package=check["name"])
                if found is not None and found.origin:
                    source += Path(found.origin).read_text()
            if "argparse" not in source and "ArgumentParser" not in source:
                if check["args"]:
                    check.update(ok=False, message=f"{check['name']} takes no arguments (it has no parser)")
                else:
                    check.update(ok=True, message="")
                continue
        out, err = io.StringIO(), io.StringIO()
        sys.argv = [check["name"], *check["args"]]
        code = None
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                if check["kind"] == "module":
                    runpy.run_module(check["name"], run_name="__main__", alter_sys=True)
                else:
                    runpy.run_path(str(ROOT / check["name"]), run_name="__main__")
                code = "returned without parsing its arguments"
            except Parsed:
                code = 0
            except SystemExit as stop:
                code = stop.code if isinstance(stop.code, int) else (0 if stop.code is None else 1)
        message = (err.getvalue().strip().splitlines() or [f"exit status {code}"])[-1]
        check.update(ok=code == 0, message="" if code == 0 else message)
    sys.stdout.write("\n" + json.dumps(checks) + "\n")


# -- generated sections ------------------------------------------------------------------

def test_replace_section_keeps_the_rest_of_the_page(tmp_path):
    from core.markdown import read_section, replace_section

    page = tmp_path / "results.md"
    page.write_text("# Title\n\nprose before\n\n<!-- a:start -->\nold\n<!-- a:end -->\n\nprose after\n")
    replace_section(page, "a", "new\ntable\n")
    assert page.read_text() == ("# Title\n\nprose before\n\n<!-- a:start -->\nnew\ntable\n<!-- a:end -->\n\n"
                                "prose after\n")
    replace_section(page, "b", "appended")
    assert page.read_text().endswith("prose after\n\n<!-- b:start -->\nappended\n<!-- b:end -->\n")
    assert read_section(page, "a") == "new\ntable\n" and read_section(page, "c") is None
    fresh = tmp_path / "new" / "page.md"
    replace_section(fresh, "a", "x")
    assert fresh.read_text() == "<!-- a:start -->\nx\n<!-- a:end -->\n"


@pytest.mark.parametrize("text", ["<!-- a:start -->\nno end\n", "<!-- a:end -->\n<!-- a:start -->\n",
                                  "<!-- a:start -->\n<!-- a:end -->\n<!-- a:start -->\n<!-- a:end -->\n"])
def test_replace_section_refuses_broken_markers(tmp_path, text):
    from core.errors import OutputError
    from core.markdown import replace_section

    page = tmp_path / "page.md"
    page.write_text(text)
    with pytest.raises(OutputError, match="section 'a' has"):
        replace_section(page, "a", "new")
    assert page.read_text() == text


def test_a_failed_write_leaves_the_old_page(tmp_path, monkeypatch):
    from core import markdown

    page = tmp_path / "page.md"
    page.write_text("<!-- a:start -->\nold\n<!-- a:end -->\n")

    def full_disk(*args):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(markdown.os, "replace", full_disk)
    with pytest.raises(markdown.OutputError, match=f"{page}: no space left on device$"):  # one line naming the page
        markdown.replace_section(page, "a", "new")
    assert page.read_text() == "<!-- a:start -->\nold\n<!-- a:end -->\n"
    assert [p.name for p in tmp_path.iterdir()] == ["page.md"]
