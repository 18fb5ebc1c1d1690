"""AOV names of the ``whitted`` integrator (importable before a variant is set)."""
from __future__ import annotations

#: AOV name -> film channels, in the order the integrator writes them
AOV_CHANNELS = {
    "depth": ("depth.Y",),
    "normal": ("normal.X", "normal.Y", "normal.Z"),
    "position": ("position.X", "position.Y", "position.Z"),
    "albedo": ("albedo.R", "albedo.G", "albedo.B"),
    "id": ("id.Y",),
}

#: Prefix of the shape ids the scene converter assigns: ``object_<index>``
OBJECT_ID_PREFIX = "object_"


def parse_aovs(text: str) -> list[str]:
    names = [name.strip() for name in text.split(",") if name.strip()]
    unknown = [name for name in names if name not in AOV_CHANNELS]
    if unknown:
        raise ValueError(f"whitted: unknown AOV {unknown[0]!r}; choose from {', '.join(AOV_CHANNELS)}")
    return list(dict.fromkeys(names))
