"""Render settings that a scene file carries in its header comment.

A scene meant to be seen with shadows and mirrors says so in a comment line
before its first section::

    # render: -bounces 3 -shadows

The flags are the course binary's render flags (``-size W H``, ``-bounces N``,
``-shadows``, ``-jitter``, ``-filter``). ``render.py SCENE`` and ``python -m
converters`` use them wherever the command line leaves a setting at its
default; a value given on the command line that differs from the default
wins. The course binary's own mode (``render.py -input FILE ...``) reads no
header, exactly like the course binary, which skips comments.
"""
from __future__ import annotations

import re
import shlex
from pathlib import Path

from core.errors import SceneError

#: The settings a header may set and their defaults (those of the course binary)
DEFAULTS = {"width": 800, "height": 800, "bounces": 0, "shadows": False, "jitter": False, "filter": False}

_HEADER = re.compile(r"#\s*render:(.*)")
#: flag -> (setting names, number of values)
_FLAGS = {"-size": (("width", "height"), 2), "-bounces": (("bounces",), 1),
          "-shadows": (("shadows",), 0), "-jitter": (("jitter",), 0), "-filter": (("filter",), 0)}


def read_scene_flags(path: str | Path) -> dict:
    """The settings in ``path``'s ``# render:`` header lines (comments before
    the first non-comment line), e.g. ``{"bounces": 3, "shadows": True}``."""
    settings: dict = {}
    try:
        with open(path, encoding="utf-8", errors="replace") as file:
            lines = [line for _, line in zip(range(200), file)]
    except OSError:
        return settings  # the scene loader reports a missing file with its own message
    for number, line in enumerate(lines, start=1):
        stripped = line.strip()
        if stripped and not stripped.startswith("#"):
            break
        match = _HEADER.match(stripped)
        if match:
            column = line.index("render:") + len("render:") + 1
            settings.update(_parse(path, number, column, match.group(1)))
    return settings


def _parse(path, number: int, column: int, text: str) -> dict:
    def fail(message: str):
        raise SceneError(path, number, column, f"in the '# render:' header: {message}")

    try:
        words = shlex.split(text)
    except ValueError as error:
        fail(str(error))
    settings: dict = {}
    position = 0
    while position < len(words):
        flag = words[position]
        if flag not in _FLAGS:
            fail(f"unknown flag {flag!r} (known: {' '.join(_FLAGS)})")
        names, count = _FLAGS[flag]
        values = words[position + 1:position + 1 + count]
        if len(values) < count:
            fail(f"{flag} wants {count} number{'s' if count > 1 else ''}")
        if count == 0:
            settings[names[0]] = True
        for name, value in zip(names, values):
            try:
                number_value = int(value)
            except ValueError:
                fail(f"{flag} wants whole numbers, got {value!r}")
            if number_value < (0 if name == "bounces" else 1):
                fail(f"{flag} {value} is out of range")
            settings[name] = number_value
        position += 1 + count
    return settings


def with_scene_flags(path: str | Path, settings: dict) -> dict:
    """``settings`` (keys as in :data:`DEFAULTS`, others passed through) with
    the header's values wherever ``settings`` holds the default."""
    header = read_scene_flags(path)
    return {**settings, **{name: value for name, value in header.items()
                           if settings.get(name, DEFAULTS[name]) == DEFAULTS[name]}}
