"""The method list of docs/denoising_methods.md, made from the registry
(``python -m denoise.methods --write`` puts it between the page's markers)."""
from __future__ import annotations

import inspect
import re
from pathlib import Path

from . import METHODS, DenoisingMethod, Option

DOC = Path(__file__).resolve().parents[2] / "docs" / "denoising_methods.md"
START, END = "<!-- methods:start -->", "<!-- methods:end -->"


def _default(option: Option) -> str:
    if option.default_text is not None:
        return option.default_text
    if option.action is not None or option.default is None:
        return "off"
    return f"`{option.default:g}`" if isinstance(option.default, float) else f"`{option.default}`"


def _range(option: Option) -> str:
    if option.choices:
        return ", ".join(f"`{c}`" for c in option.choices)
    if option.kind in (int, float):
        return option.range_text()
    return ""


def _options_table(options: tuple[Option, ...]) -> list[str]:
    """Each option's flag, default, range, unit and meaning, from its declaration."""
    lines = ["| option | default | range | unit | live slider | meaning |", "|---|---|---|---|---|---|"]
    for o in options:
        slider = "" if o.step is None else "{:g} to {:g}, step {:g}".format(*o.slider_range(), o.step)
        lines.append(f"| `{o.flag}` | {_default(o)} | {_range(o)} | {o.unit} | {slider} | {o.help} |")
    return lines


def method_list() -> str:
    """The generated part of the page: a table of the registered methods, the
    options every method has, then per method its docstring and options."""
    lines = [START, "<!-- made by `python -m denoise.methods --write` from denoise/methods/; do not edit -->", "",
             "| `--method` | what it does | benchmark names |", "|---|---|---|"]
    for name, cls in METHODS.items():
        lines.append(f"| `{name}` | {cls.description} | {', '.join(f'`{b}`' for b in cls.benchmark)} |")
    lines += ["", "### Every method", "", inspect.getdoc(DenoisingMethod), "",
              *_options_table(DenoisingMethod.common_options)]
    for name, cls in METHODS.items():
        lines += ["", f"### `{name}` ({cls.__module__}.{cls.__qualname__})", "", inspect.getdoc(cls), "",
                  *_options_table(cls.options)]
    return "\n".join(lines + ["", END])


def with_method_list(text: str) -> str:
    """``text`` (the page) with its generated part made anew."""
    if START not in text or END not in text:
        raise ValueError(f"the page has no {START} ... {END} section")
    return re.sub(re.escape(START) + ".*?" + re.escape(END), lambda _: method_list(), text, flags=re.S)
