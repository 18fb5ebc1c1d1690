"""A method of one's own in one's own file: ``--method-file my_filter.py``.

:func:`load_method_file` runs the file as a module and registers each
:class:`~denoise.methods.DenoisingMethod` subclass it defines (a file may also
call :func:`denoise.methods.register` itself, as ``mi.register_integrator`` is
called). Every command that names methods reads its ``--method-file`` options
with :func:`method_files` before it builds its parser, so the file's methods and
options appear in ``--help`` like the built-in ones. Whatever is wrong with the
file is one :class:`DeclarationError` line naming the file and line.
"""
from __future__ import annotations

import argparse
import inspect
import sys
import traceback
import types
from pathlib import Path

from core.entry import check_stopped, interruption, message_of, stop_received

from . import METHODS, DeclarationError, DenoisingMethod, register
from .declarations import description_problem

FLAG = "--method-file"
#: the methods of each file loaded in this process: a second command reuses them
LOADED: dict[Path, list[type[DenoisingMethod]]] = {}


def _line_of(error: BaseException, path: Path) -> int:
    """The last line of ``path`` in ``error``'s traceback (1 where none is)."""
    lines = [f.lineno for f in traceback.extract_tb(error.__traceback__) if Path(f.filename) == path]
    return lines[-1] if lines else 1


def _class_line(cls: type) -> int:
    """The line of ``cls``'s ``class`` statement (1 where it cannot be found)."""
    try:
        return inspect.getsourcelines(cls)[1]
    except (OSError, TypeError):
        return 1


def load_method_file(path: Path) -> list[type[DenoisingMethod]]:
    """Runs ``path`` and registers the methods it defines; returns them (a file
    loaded before in this process is not run again: its methods are registered)."""
    path = Path(path).resolve()
    if path in LOADED:
        for cls in LOADED[path]:
            if METHODS.get(cls.name) is not cls:
                register(cls)
        return LOADED[path]
    try:
        source = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as error:
        raise DeclarationError(f"{path}: cannot read the method file ({error.__class__.__name__}: {error})") from None
    try:
        code = compile(source, str(path), "exec")
    except SyntaxError as error:
        raise DeclarationError(f"{path}:{error.lineno or 1}: syntax error: {error.msg}") from None
    module = types.ModuleType(f"method_file_{path.stem}")
    module.__file__ = str(path)
    sys.modules[module.__name__] = module  # inspect and dataclasses look classes' modules up there
    before = set(METHODS)
    try:
        exec(code, module.__dict__)  # noqa: S102  the user's own method file, named on their command line
    except DeclarationError:
        raise
    except BaseException as error:  # any exception (or exit()) at import: where, and what; Ctrl-C stays one
        if interruption(error) is not None or stop_received() is not None:
            raise
        raise DeclarationError(f"{path}:{_line_of(error, path)}: {message_of(error)}") from None
    check_stopped()  # a file that caught the interruption while it ran
    defined = [value for value in vars(module).values() if isinstance(value, type)
               and issubclass(value, DenoisingMethod) and value.__module__ == module.__name__ and value.name]
    if not defined and set(METHODS) == before:
        raise DeclarationError(f"{path}:1: no method class (a subclass of denoise.methods.DenoisingMethod with a "
                               "name and a description)")
    for cls in defined + [METHODS[name] for name in METHODS if name not in before]:
        problem = description_problem(cls)
        if problem:
            raise DeclarationError(f"{path}:{_class_line(cls)}: {cls.__name__}: {problem}")
    for cls in defined:
        if METHODS.get(cls.name) is not cls:
            try:
                register(cls)
            except DeclarationError as error:
                text = str(error)
                raise DeclarationError(text if text.startswith(str(path)) else
                                       f"{path}:{inspect.getsourcelines(cls)[1]}: {text}") from None
    LOADED[path] = defined + [METHODS[name] for name in METHODS if name not in before and METHODS[name] not in defined]
    return LOADED[path]


def method_files(argv: list[str] | None) -> list[Path]:
    """The ``--method-file`` values of ``argv`` (``sys.argv[1:]`` for None),
    read before the full parser exists; arguments after ``--`` are not options."""
    words = sys.argv[1:] if argv is None else list(argv)
    words = words[:words.index("--")] if "--" in words else words
    found = []
    for i, word in enumerate(words):
        if word == FLAG and i + 1 < len(words):
            found.append(Path(words[i + 1]))
        elif word.startswith(FLAG + "="):
            found.append(Path(word.split("=", 1)[1]))
    return found


def load_method_files(argv: list[str] | None) -> None:
    """Loads every ``--method-file`` of ``argv``."""
    for path in method_files(argv):
        load_method_file(path)


def add_method_file_option(parser: argparse.ArgumentParser) -> None:
    """The ``--method-file`` option, for ``--help`` (its values are read by :func:`method_files`)."""
    parser.add_argument(FLAG, action="append", type=Path, default=[], metavar="FILE.py",
                        help="a file with a method of your own (a DenoisingMethod subclass); may be repeated")
