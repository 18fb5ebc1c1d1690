"""The one reader of every JSON input (sequence specs, the asvgf parameter
file, records read back, the live page's messages): UTF-8 text of a bounded
size, nesting and number length, no key given twice, finite numbers, no
NaN/Infinity literals unless the caller allows them.

Every problem is a :class:`JSONInputError` whose text is one line saying
what is wrong (``FILE: what`` from :func:`read_json`); callers re-raise it as
their own :class:`~core.errors.ToolkitError` kind or reply with it. The
values' types are the consumer's to check, naming the key.
"""
from __future__ import annotations

import codecs
import itertools
import json
import math
import re
from pathlib import Path

from .errors import ToolkitError
from .inputs import NotAnInputFile, read_input

#: the deepest nesting accepted (no input of ours nests more than a few levels)
MAX_DEPTH = 64
#: the longest integer accepted, in digits (Python refuses to convert over 4300)
MAX_DIGITS = 100
#: a string in JSON, to be skipped when counting brackets
STRING = re.compile(r'"(?:[^"\\]|\\.)*"', re.DOTALL)
BRACKETS = re.compile(r"[\[\]{}]")


class JSONInputError(ToolkitError, ValueError):
    """A JSON input that is not acceptable; the text says why (one line)."""


def _depth(text: str) -> int:
    steps = (1 if c in "[{" else -1 for c in BRACKETS.findall(STRING.sub("", text)))
    return max(itertools.accumulate(steps, initial=0))


def _integer(text: str) -> int:
    digits = len(text.lstrip("-"))
    if digits > MAX_DIGITS:
        raise JSONInputError(f"an integer of {digits} digits (at most {MAX_DIGITS})")
    return int(text)


def _float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise JSONInputError(f"the number {text[:40]} is too large for a float")
    return value


def _object(pairs: list) -> dict:
    result = {}
    for key, value in pairs:
        if key in result:
            raise JSONInputError(f"key {json.dumps(key)[:60]} given twice in one object")
        result[key] = value
    return result


def _no_surrogates(value) -> None:
    """A lone surrogate (``"\\ud800"``) is no character: later encoding fails."""
    if isinstance(value, str):
        value.encode("utf-8")
    elif isinstance(value, dict):
        for key, item in value.items():
            key.encode("utf-8")
            _no_surrogates(item)
    elif isinstance(value, list):
        for item in value:
            _no_surrogates(item)


def parse_json(data: str | bytes, limit: int, constants: bool = False):
    """The value of the JSON text ``data`` (bytes: UTF-8, a BOM allowed) of at
    most ``limit`` bytes; ``constants``: NaN, Infinity and -Infinity are read
    as floats. Raises :class:`JSONInputError`."""
    if isinstance(data, str):
        try:
            size = len(data.encode("utf-8"))
        except UnicodeEncodeError:
            raise JSONInputError("text with a lone surrogate (not Unicode)") from None
    else:
        size = len(data)
    if size > limit:
        raise JSONInputError(f"larger than {limit} bytes")
    if isinstance(data, bytes):
        if data.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)) or b"\0" in data[:4]:
            raise JSONInputError("UTF-16 or UTF-32 text; save it as UTF-8")
        try:
            data = data.decode("utf-8-sig")
        except UnicodeDecodeError as error:
            raise JSONInputError(f"not UTF-8 text (byte 0x{data[error.start]:02x} at offset {error.start}); "
                                 f"save it as UTF-8") from None
    depth = _depth(data)
    if depth > MAX_DEPTH:
        raise JSONInputError(f"nested {depth} levels deep (at most {MAX_DEPTH})")

    def constant(name: str) -> float:
        if not constants:
            raise JSONInputError(f"{name} is not a JSON number")
        return float(name)

    try:
        value = json.loads(data, parse_int=_integer, parse_float=_float, parse_constant=constant,
                           object_pairs_hook=_object)
        _no_surrogates(value)
    except json.JSONDecodeError as error:
        raise JSONInputError(f"line {error.lineno} column {error.colno}: {error.msg}") from None
    except UnicodeEncodeError:
        raise JSONInputError("a string with a lone surrogate (\\ud800-\\udfff), not a character") from None
    except RecursionError:
        raise JSONInputError(f"nested too deeply (at most {MAX_DEPTH})") from None
    return value


def read_json(path: Path, limit: int, constants: bool = False):
    """The value of the JSON file ``path`` (:func:`parse_json`); every problem,
    an unreadable file included, is a :class:`JSONInputError` ``PATH: what``."""
    try:
        return parse_json(read_input(Path(path), limit), limit, constants)
    except JSONInputError as error:
        raise JSONInputError(f"{path}: {error}") from None
    except NotAnInputFile as error:
        raise JSONInputError(f"{path}: {error}") from None
    except OSError as error:
        raise JSONInputError(f"{path}: {error.strerror or error}") from None


def json_kind(value) -> str:
    """What ``value``, parsed from JSON, is, in JSON's words (``null``, ``an array``)."""
    if isinstance(value, bool) or value is None:
        return json.dumps(value)
    return {dict: "an object", list: "an array", str: "a string"}.get(type(value), "a number")


def shown(value) -> str:
    """``value``, parsed from JSON, as JSON text (``null``, ``"x"``, ``[1, 2]``) for an error
    message, cut to 40 characters: what the user wrote, not Python's spelling of it."""
    text = json.dumps(value, default=str)
    return text if len(text) <= 40 else text[:37] + "..."
