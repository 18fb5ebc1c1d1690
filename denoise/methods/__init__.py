"""The denoising methods, one class per module, and the one registry of them.

``python -m denoise --method`` and its ``--help``, the names that
``python -m benchmarks.denoise`` runs and the method list of
docs/denoising_methods.md (``python -m denoise.methods``) all come from
:data:`METHODS`. Adding a method: a module with a :class:`DenoisingMethod`
subclass, imported here and passed to :func:`register` below.
"""
from __future__ import annotations

from core.errors import UsageError

from ..filters import OutlierParams
from .asvgf import ASVGF
from .atrous import Atrous
from .base import DenoisingMethod, Option, SpatialFilterMethod
from .bilateral import Bilateral
from .oidn import OIDNMethod
from .oidn_guided import OIDNGuided
from .svgf import SVGF

__all__ = ["METHODS", "DenoisingMethod", "Option", "SpatialFilterMethod", "benchmark_names", "from_name",
           "make", "register", "resolve"]

#: every method by its ``name``, in the order ``--help`` and the docs list them
METHODS: dict[str, type[DenoisingMethod]] = {}


def register(cls: type[DenoisingMethod]) -> type[DenoisingMethod]:
    """Adds ``cls`` under ``cls.name`` (usable as a class decorator)."""
    if not cls.name or not cls.description:
        raise TypeError(f"{cls.__name__}: a method needs a name and a one-line description")
    if cls.name in METHODS and METHODS[cls.name] is not cls:
        raise TypeError(f"{cls.__name__}: the method name {cls.name!r} is taken by {METHODS[cls.name].__name__}")
    METHODS[cls.name] = cls
    return cls


#: the methods of this package, in the order of ``--help``
for method in (Bilateral, Atrous, SVGF, ASVGF, OIDNMethod, OIDNGuided):
    register(method)


def make(name: str, **props) -> DenoisingMethod:
    """The method ``name`` with parameters ``props`` (option keys, e.g. ``levels=3``)."""
    if name not in METHODS:
        raise UsageError(f"unknown method {name!r}; choose from {', '.join(METHODS)}")
    return METHODS[name](**props)


def configured(name: str, values: dict) -> DenoisingMethod:
    """The method ``name`` made from the command line's ``values`` (option key ->
    value, the options given). Every other method is made from them too, so that
    a parameter out of range is an error whichever method reads it."""
    method = make(name, **_own(METHODS[name], values) if name in METHODS else {})
    for other in METHODS.values():
        if other.name != name:
            other(**_own(other, values))
    return method


def _own(cls: type[DenoisingMethod], values: dict) -> dict:
    keys = {o.key for o in cls.all_options()}
    return {k: v for k, v in values.items() if k in keys}


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
    cls, props = names[found[0]]
    return cls, dict(props, temporal="temporal" in parts or cls.temporal_by_nature, demodulate="demod" in parts,
                     outliers=OutlierParams().k if "outliers" in parts else None)


def from_name(name: str, **props) -> DenoisingMethod:
    """The method of a benchmark name (:func:`resolve`), ``props`` overriding its parameters."""
    cls, named = resolve(name)
    return cls(**{**named, **props})


def benchmark_names() -> tuple[str, ...]:
    """The names ``python -m benchmarks.denoise`` runs, method by method."""
    return tuple(name for cls in METHODS.values() for name in cls.benchmark)
