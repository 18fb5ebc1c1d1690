"""Numbers as the course writes them: ASCII decimal, optionally signed, with
an optional decimal exponent. Python's ``float`` and ``int`` also read
``1_000`` and other scripts' digits (``٣٠``, ``３０``), which no course scene or
command line has; the scene parser and the command lines check against these.
"""
from __future__ import annotations

import re

#: a decimal number: ``3``, ``-0.5``, ``.5``, ``1.``, ``2e-3``
DECIMAL = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
#: a whole number: ``12``, ``-3``
WHOLE = re.compile(r"[+-]?[0-9]+")
_NON_FINITE = re.compile(r"[+-]?(?:inf|infinity|nan)", re.IGNORECASE)


def ascii_int(text: str) -> int:
    """An argparse ``type``: a :data:`WHOLE` number."""
    if not WHOLE.fullmatch(text.strip()):
        raise ValueError(text)
    return int(text)


def ascii_float(text: str) -> float:
    """An argparse ``type``: a :data:`DECIMAL` number (``inf``/``nan`` are left
    to the range checks, which name them)."""
    if not (DECIMAL.fullmatch(text.strip()) or _NON_FINITE.fullmatch(text.strip())):
        raise ValueError(text)
    return float(text)


ascii_int.__name__, ascii_float.__name__ = "int", "float"  # argparse's message: "invalid int value: '８'"
