"""The checks of a method's texts, made when its file loads: what argparse and
``--help`` print of an :class:`~denoise.methods.base.Option` (its help, unit,
group, metavar, default text and choices) and a method's description must be
one line of printable text, and an option's action one that makes a switch.
"""
from __future__ import annotations

import re

#: the argparse actions an option may have: a switch that sets its key to True or to False
ACTIONS = ("store_true", "store_false")
#: what a metavar may be (argparse wraps the usage line at spaces and brackets)
METAVAR = re.compile(r"[A-Za-z0-9_.-]+")


def printable(value: object) -> str:
    """``repr(value)``, cut short, for a message about a declaration."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def one_line_text(value: object) -> bool:
    """``value`` is a ``str`` of printable characters (no newline, tab or escape sequence)."""
    return isinstance(value, str) and value.isprintable()


def text_problem(option) -> str | None:
    """What is wrong with the texts of ``option`` (its help, unit, group, metavar,
    default_text and choices), or None: each one line of printable text."""
    for name, value, needed in (("help", option.help, True), ("unit", option.unit, True),
                                ("group", option.group, False), ("default_text", option.default_text, False)):
        if (needed or value is not None) and not one_line_text(value):
            return f"{name} must be one line of printable text, got {printable(value)}"
    if option.metavar is not None and not (isinstance(option.metavar, str) and METAVAR.fullmatch(option.metavar)):
        return f"metavar must be letters, digits, '_', '-' or '.', got {printable(option.metavar)}"
    if option.choices is not None:
        try:
            choices = list(option.choices)
        except TypeError:
            return f"choices must be a tuple of values, got {printable(option.choices)}"
        bad = next((c for c in choices if not isinstance(c, (str, int, float)) or isinstance(c, bool)
                    or not one_line_text(str(c)) or any(ch.isspace() for ch in str(c))), None)
        if bad is not None or not choices:
            return f"choices must be words or numbers without spaces, got {printable(bad if choices else choices)}"
    return None


def description_problem(cls: type) -> str | None:
    """What is wrong with a method class's ``description``, or None: one line of printable text
    (one without any is :func:`denoise.methods.register`'s to refuse)."""
    if cls.description and (not one_line_text(cls.description) or not cls.description.strip()):
        return f"the description must be one line of printable text, got {printable(cls.description)}"
    return None
