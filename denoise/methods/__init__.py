"""The denoising methods, one class per module, and the one registry of them.

``python -m denoise --method`` and its ``--help``, the names that
``python -m benchmarks.denoise`` runs and the method list of
docs/denoising_methods.md (``python -m denoise.methods``) all come from
:data:`METHODS`. Adding a method: a module with a :class:`DenoisingMethod`
subclass, imported here and passed to :func:`register` below.
"""
from __future__ import annotations

import re
import sys
from pathlib import Path

if sys.argv[:1] == ["-m"]:  # first: `python -m denoise.methods` imports this before its __main__
    from core.launcher import start_before_package
    start_before_package(__name__)

from core.errors import UsageError

from ..filters import OutlierParams
from .asvgf import ASVGF
from .atrous import Atrous
from .base import DeclarationError, DenoisingMethod, MethodError, Option, SpatialFilterMethod, temporal_options
from .bilateral import Bilateral
from .learned_asvgf import LearnedASVGF
from .learned_mixture import LearnedMixture
from .oidn import OIDNMethod
from .oidn_guided import OIDNGuided
from .svgf import SVGF

__all__ = ["METHODS", "DeclarationError", "DenoisingMethod", "MethodError", "Option", "SpatialFilterMethod",
           "benchmark_names", "declared_options", "from_name", "make", "method_names", "register", "resolve"]

#: what a method's name may be: lower-case words joined by '_' or '-' ('+' joins names)
NAME = re.compile(r"[a-z0-9][a-z0-9_-]*")
#: the words of names that are no method's: the noisy input, and what joins a method's name
RESERVED = frozenset({"raw", "temporal", "demod", "outliers"})

#: every method by its ``name``, in the order ``--help`` and the docs list them
METHODS: dict[str, type[DenoisingMethod]] = {}


def declared_options() -> dict[str, tuple[Option, list[tuple[str, Option]]]]:
    """Every registered option by flag, the common ones first: (its first
    declaration, [(method name, that method's declaration)])."""
    declared: dict[str, tuple[Option, list]] = {o.flag: (o, []) for o in DenoisingMethod.common_options}
    for name, cls in METHODS.items():
        for option in cls.options:
            declared.setdefault(option.flag, (option, []))[1].append((name, option))
    return declared


def _shared(option: Option) -> tuple:
    """What methods that share a flag must declare alike (defaults, ranges and sliders may differ)."""
    return option.key, option.kind, option.help, option.unit, option.group, option.action, option.choices


def register(cls: type[DenoisingMethod]) -> type[DenoisingMethod]:
    """Adds ``cls`` under ``cls.name`` (usable as a class decorator, as
    ``mi.register_integrator`` is a call); a flag that another method declares
    differently is a :class:`DeclarationError` naming both declarations."""
    if not isinstance(cls, type) or not issubclass(cls, DenoisingMethod):
        raise DeclarationError(f"{cls!r}: a method is a subclass of denoise.methods.DenoisingMethod")
    if not cls.name or not cls.description:
        raise DeclarationError(f"{cls.__name__}: a method needs a name and a one-line description")
    if not isinstance(cls.name, str) or not NAME.fullmatch(cls.name):
        raise DeclarationError(f"{cls.__name__}: the method name {cls.name!r} must be lower-case letters, digits, "
                               "'_' and '-', starting with a letter or digit ('+' joins names: atrous+temporal)")
    if cls.name in RESERVED:
        raise DeclarationError(f"{cls.__name__}: the method name {cls.name!r} is a word of every command's "
                               f"method names ({', '.join(sorted(RESERVED))}); choose another")
    taken = _names().get(cls.name, (cls, {}))[0]
    if taken is not cls:
        raise DeclarationError(f"{cls.__name__}: the method name {cls.name!r} is taken by {taken.__name__} "
                               f"({cls.name} already names it in every command); choose another")
    if not isinstance(cls.options, tuple) or not all(isinstance(o, Option) for o in cls.options):
        raise DeclarationError(f"{cls.__name__}: options must be a tuple of denoise.methods.Option")
    if issubclass(cls, SpatialFilterMethod) and not {"alpha", "k"} & {o.key for o in cls.options}:
        cls.options = cls.options + temporal_options(cls.temporal_defaults)  # what its accumulation reads
    keys: dict[str, Option] = {}
    for option in cls.options:
        first = keys.setdefault(option.key, option)
        if first is not option:
            raise DeclarationError(f"{option.origin}: {cls.__name__} declares the option {option.key!r} twice "
                                   f"(first at {first.origin})")
    declared = declared_options()
    for option in cls.options:
        if option.flag in declared:
            first, users = declared[option.flag]
            other, where = (users[0] if users else ("every method", first))
            if other != cls.name and _shared(where) != _shared(option):
                raise DeclarationError(f"{option.origin}: {cls.__name__} declares {option.flag} differently from "
                                       f"{other} at {where.origin} (same key, kind, help, unit and group needed)")
    METHODS[cls.name] = cls
    return cls


def make(name: str, **props) -> DenoisingMethod:
    """The method ``name`` with parameters ``props`` (option keys, e.g.
    ``levels=3``): a name means what it means in every command (:func:`resolve`:
    ``atrous`` without history, ``atrous+temporal`` with it)."""
    return from_name(name, **props)


def _names() -> dict[str, tuple[type[DenoisingMethod], dict]]:
    """Benchmark method words: every name, and ``NAME-PRESET`` for each preset."""
    names = {}
    for cls in METHODS.values():
        names[cls.name] = (cls, {})
        for preset, props in cls.presets.items():
            names.setdefault(f"{cls.name}-{preset}", (cls, props))
    return names


def resolve(name: str) -> tuple[type[DenoisingMethod], dict]:
    """The class and parameters of a benchmark name ``[demod+][outliers+]METHOD[-PRESET][+temporal]``,
    e.g. ``atrous+temporal``, ``oidn-fast``, ``demod+outliers+atrous+temporal``:
    ``demod`` demodulates, ``outliers`` clamps outliers at the usual K, and a method
    whose ``temporal_by_nature`` is set is temporal without ``+temporal``."""
    parts = name.split("+")
    names = _names()
    found = [p for p in parts if p in names]
    unknown = set(parts) - set(names) - {"temporal", "demod", "outliers"}
    if len(found) != 1 or unknown:
        raise UsageError(f"unknown method {name!r}; known: {', '.join(names)} (also with demod+ or outliers+ "
                         "before and +temporal after, e.g. demod+atrous+temporal)")
    at = parts.index(found[0])
    prefix, suffix = parts[:at], parts[at + 1:]
    cls, props = names[found[0]]
    if prefix not in ([], ["demod"], ["outliers"], ["demod", "outliers"]) or suffix not in ([], ["temporal"]):
        temporal = "[+temporal]" if accumulates(cls) else ""  # offered where the name takes it
        raise UsageError(f"method {name!r}: write it [demod+][outliers+]{found[0]}{temporal}, each part once "
                         "and in that order")
    if "temporal" in parts and not accumulates(cls):  # it would change nothing: the same bytes as without
        raise UsageError(f"method {name!r}: {found[0]} " + ("is temporal by nature; drop +temporal"
                                                            if cls.temporal_by_nature else "has no temporal step"))
    return cls, dict(props, temporal="temporal" in parts or cls.temporal_by_nature, demodulate="demod" in parts,
                     outliers=OutlierParams().k if "outliers" in parts else None)


def check_method_names(flag: str, names: list[str], also: dict[str, str] | None = None) -> None:
    """Each of ``names`` given once, and each a method's name (:func:`resolve`) or a key
    of ``also`` (the other names the command takes, with what each is); else a one-line
    :class:`UsageError` naming ``flag`` (``--methods``, ``--compare``)."""
    also = also or {}
    twice = sorted({name for name in names if names.count(name) > 1})
    if twice:
        raise UsageError(f"{flag}: {', '.join(twice)} named twice (each method is judged once)")
    for name in names:
        if name not in also:
            try:
                resolve(name)
            except UsageError as error:
                others = "".join(f", or {key} ({what})" for key, what in also.items())
                raise UsageError(f"{flag}: {error}{others}") from None


def from_name(name: str, **props) -> DenoisingMethod:
    """The method of a benchmark name (:func:`resolve`), ``props`` overriding its parameters."""
    cls, named = resolve(name)
    return cls(**{**named, **props})


def accumulates(cls: type[DenoisingMethod]) -> bool:
    """Whether ``NAME+temporal`` adds the clamped temporal accumulation to ``cls``:
    it has one (options of it) and is not temporal by nature."""
    return not cls.temporal_by_nature and any(o.temporal for o in cls.options)


def method_names() -> tuple[str, ...]:
    """Every name a command takes (``python -m denoise --method``, the
    benchmark's ``--methods``, ``denoise.score --compare``, the live page), one
    meaning each: ``NAME`` and ``NAME-PRESET`` as :func:`resolve` makes them
    (no history unless the method is temporal by nature), and ``NAME+temporal``
    with the clamped temporal accumulation where the method has one and is not."""
    names = []
    for cls in METHODS.values():
        names += [cls.name] + ([f"{cls.name}+temporal"] if accumulates(cls) else [])
        names += [f"{cls.name}-{preset}" for preset in cls.presets]
    return tuple(names)


def data_files(keep: tuple[Path, ...] = ()) -> dict[str, Path]:
    """Every registered method's :attr:`~DenoisingMethod.data_files` but ``keep``
    (a command's own output, as fit's parameters), labelled for
    :func:`core.inputs.check_outside`: outputs never land on them."""
    files = {}
    for cls in METHODS.values():
        for path in cls.data_files:
            if path not in keep:
                files.setdefault(path, f"file {path.name} that {cls.name} reads")
    return {label: path for path, label in files.items()}


def benchmark_names() -> tuple[str, ...]:
    """The names ``python -m benchmarks.denoise`` runs, method by method."""
    return tuple(name for cls in METHODS.values() for name in cls.benchmark)


#: the methods of this package, in the order of ``--help``
for method in (Bilateral, Atrous, SVGF, ASVGF, LearnedASVGF, LearnedMixture, OIDNMethod, OIDNGuided):
    register(method)
