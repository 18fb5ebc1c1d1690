"""Validation variants of a scene: functions over its description.

Each takes a :func:`converters.description.scene_dict` description and
returns a new one, leaving its input as it was (the nodes it changes are
copied). They exist to compare ``whitted`` with Mitsuba's path tracer and to
isolate one term of the course's model; the course's own renders use none of
them. Apply them in any order, e.g.
``without_background(without_ambient(with_path_tracer(description)))``.
"""
from __future__ import annotations

from collections.abc import Callable

Variant = Callable[[dict], dict]


def with_path_tracer(description: dict) -> dict:
    """Mitsuba's ``path`` integrator in place of ``whitted``, following as many
    mirror bounces: depth 1 sees emitters, 2 adds direct light, +1 per bounce.
    No Russian roulette; the AOVs and ray counts (whitted's) are dropped."""
    integrator = description["integrator"]
    if integrator["type"] != "whitted":
        raise ValueError(f"with_path_tracer wants a whitted description, got {integrator['type']!r}")
    return dict(description, integrator={"type": "path", "max_depth": int(integrator["bounces"]) + 2,
                                         "rr_depth": 1000, "hide_emitters": False})


def without_ambient(description: dict) -> dict:
    """No ambient term (whitted's; the path tracer has none)."""
    integrator = {name: value for name, value in description["integrator"].items() if name != "ambient"}
    return dict(description, integrator=integrator)


def without_ray_epsilon(description: dict) -> dict:
    """whitted without the course's "skip hits within epsilon" for secondary
    rays: the path tracer's visibility rule, for comparing light transport alone."""
    integrator = {name: value for name, value in description["integrator"].items() if name != "ray_epsilons"}
    return dict(description, integrator=integrator)


def with_mirror_sampling(description: dict) -> dict:
    """Every ``phong`` BSDF samples only the lobes a Whitted tracer follows
    (``sampling="mirror"``, see the phong plugin), so that a path tracer
    renders Whitted's light paths."""
    return {key: dict(node, sampling="mirror") if isinstance(node, dict) and node.get("type") == "phong" else node
            for key, node in description.items()}


def without_background(description: dict) -> dict:
    """No background emitter (colour or cube map)."""
    return {key: node for key, node in description.items() if key != "background"}


def apply(description: dict, variants: tuple[Variant, ...] | list[Variant] = ()) -> dict:
    """``description`` with ``variants`` applied in order."""
    for variant in variants:
        description = variant(description)
    return description
