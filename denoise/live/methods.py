"""The methods the live page offers and the sliders of each, from the method
registry (:mod:`denoise.methods`): the one place that turns a method name and
slider values into a :class:`~denoise.methods.DenoisingMethod`.

Names are ``raw`` (no denoising) and the registry's benchmark names: every
``python -m denoise --method`` with its temporal variants and presets. A
method's sliders are its options declared with a slider ``step``
(:class:`denoise.methods.Option`), over the ends the declaration gives, so a
new method's options appear as sliders from their declarations alone.
"""
from __future__ import annotations

from dataclasses import dataclass

from denoise.methods import DenoisingMethod, benchmark_names, method_names, resolve
from denoise.svgf_common import levels_for

RAW = "raw"


def page_names() -> list[str]:
    """What the page lists, in its order: ``raw``, the benchmark's names, then
    every other name ``python -m denoise --method`` lists (``oidn``, a method of one's own)."""
    names = [RAW] + [name for name in benchmark_names() if not name.startswith(("demod+", "outliers+"))]
    return names + [name for name in method_names() if name not in names]

@dataclass(frozen=True)
class Slider:
    """One parameter: ``name`` is the method's option key."""
    name: str
    low: float
    high: float
    step: float
    whole: bool = False

    def as_json(self, method: DenoisingMethod) -> dict:
        return {"name": self.name, "low": self.low, "high": self.high, "step": self.step,
                "value": method.props[self.name]}


def sliders_of(name: str) -> tuple[Slider, ...]:
    cls, props = resolve(name)  # an option of the accumulation has no slider where there is none
    return tuple(Slider(o.key, *o.slider_range(), o.step, o.kind is int) for o in cls.options
                 if o.step is not None and (props["temporal"] or not o.temporal))


#: what the page lists and the sliders of each (:func:`refresh` after registering a method)
METHOD_NAMES: list[str] = []
SLIDERS: dict[str, tuple[Slider, ...]] = {}


def refresh() -> None:
    """:data:`METHOD_NAMES` and :data:`SLIDERS` made anew from the registry, in place."""
    METHOD_NAMES[:] = page_names()
    SLIDERS.clear()
    SLIDERS.update({RAW: (), **{name: sliders_of(name) for name in METHOD_NAMES if name != RAW}})


refresh()


def method_for(name: str, width: int, values: dict[str, float]) -> DenoisingMethod | None:
    """Method ``name`` with slider ``values`` (key -> value, each already checked
    against its :class:`Slider`'s range); None for ``raw``. Levels computed from the
    image's width (SVGF's default) are made explicit, so the page shows them."""
    if name == RAW:
        return None
    cls, props = resolve(name)
    if any(o.key == "levels" and o.default is None for o in cls.options):
        props["levels"] = levels_for(width)
    whole = {s.name: s.whole for s in SLIDERS[name]}
    props.update({key: int(value) if whole[key] else float(value) for key, value in values.items()})
    return cls(**props)


def retuned(method: DenoisingMethod, name: str, width: int, values: dict[str, float]) -> DenoisingMethod:
    """Method ``name`` with new slider ``values`` that goes on from ``method``'s history."""
    new = method_for(name, width, values)
    new.previous, new.previous_ids, new.history = method.previous, method.previous_ids, method.history
    return new


def describe(name: str, width: int, values: dict[str, float]) -> list[dict]:
    """The sliders of ``name`` with their current values, for the page."""
    method = method_for(name, width, values)
    return [s.as_json(method) for s in SLIDERS[name]] if method is not None else []
