"""The course scene format's tokens and the reading of single values.

:class:`TokenReader` is the lexical half of the parser: tokens with their
``line:col``, numbers (ASCII decimal, finite, within float32), integers,
vectors, paths and ``{ key value ... }`` blocks, each refused as a
:class:`SceneError` naming what was expected and what was found. The grammar
of sections is :mod:`converters.course_scene`'s.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from core.errors import SceneError, describe
from core.numbers import DECIMAL, WHOLE

TOKEN_PATTERN = re.compile(r"[{}]|[^\s{}]+")

#: The renderer stores every number as float32: larger magnitudes are not representable
FLOAT32_MAX = float(np.finfo(np.float32).max)


@dataclass(frozen=True)
class Token:
    text: str | None  # None: the end of the file
    line: int
    col: int


def tokenize(text: str) -> list[Token]:
    tokens = []
    for line_no, line in enumerate(text.splitlines(), start=1):
        code = line.split("#", 1)[0]
        tokens.extend(Token(m.group(), line_no, m.start() + 1) for m in TOKEN_PATTERN.finditer(code))
    return tokens


class TokenReader:
    """Reads values from the tokens of ``text``; errors name ``path``."""

    def __init__(self, path: Path, text: str):
        self.path = path
        self.tokens = tokenize(text)
        self.pos = 0
        self.end = Token(None, text.count("\n") + 1, 1)

    def peek(self) -> Token:
        return self.tokens[self.pos] if self.pos < len(self.tokens) else self.end

    def next(self) -> Token:
        token = self.peek()
        self.pos += 1
        return token

    def error(self, token: Token, expected: str) -> SceneError:
        return SceneError(self.path, token.line, token.col, f"expected {expected}, found {describe(token.text)}")

    def expect(self, text: str) -> Token:
        token = self.next()
        if token.text != text:
            raise self.error(token, repr(text))
        return token

    def number(self) -> float:
        token = self.next()
        try:
            value = float(token.text)
        except (TypeError, ValueError):
            raise self.error(token, "a number") from None
        if not math.isfinite(value):
            raise self.error(token, "a finite number")
        if not DECIMAL.fullmatch(token.text):  # Python also reads 1_0 and other scripts' digits
            raise self.error(token, "a number in ASCII decimal digits")
        if abs(value) > FLOAT32_MAX:
            raise self.error(token, f"a number of magnitude at most {FLOAT32_MAX:.7g} (float32)")
        return value

    def finite32(self, token: Token, what: str, values) -> None:
        """A value derived from the scene (not typed by the user) must also fit float32."""
        values = np.asarray(values, np.float64)
        if not np.all(np.isfinite(values)) or np.any(np.abs(values) > FLOAT32_MAX):
            shown = " ".join(f"{v:g}" for v in values.ravel()[:3])
            raise SceneError(self.path, token.line, token.col,
                             f"expected {what} within float32 range (magnitude at most {FLOAT32_MAX:.7g}), "
                             f"found {shown}")

    def integer(self, minimum: int = 0) -> int:
        token = self.next()
        try:
            if not WHOLE.fullmatch(token.text):
                raise ValueError(token.text)
            value = int(token.text)
        except (TypeError, ValueError):
            raise self.error(token, "an integer") from None
        if value < minimum:
            raise self.error(token, f"an integer >= {minimum}")
        return value

    def vector(self) -> tuple[float, float, float]:
        return (self.number(), self.number(), self.number())

    def path_value(self) -> Path:
        token = self.next()
        if token.text is None or token.text in "{}":
            raise self.error(token, "a file path")
        return self.path.parent / token.text

    def fields(self, spec: dict[str, callable], required: set[str]) -> tuple[dict, Token]:
        """Reads ``{ key value ... }`` with keys in any order, each at most once."""
        self.expect("{")
        values: dict = {}
        while True:
            token = self.next()
            if token.text == "}":
                break
            if token.text not in spec:
                keys = ", ".join(sorted(spec))
                raise self.error(token, f"one of {keys} or '}}'")
            if token.text in values:
                raise self.error(token, f"each key once, but {token.text} is repeated")
            values[token.text] = spec[token.text]()
        missing = sorted(required - values.keys())
        if missing:
            raise self.error(token, f"{', '.join(missing)} before '}}'")
        return values, token
