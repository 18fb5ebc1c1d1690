"""The scene error type, re-exported from :mod:`core.errors` (its one home)."""
from core.errors import SceneError, describe

__all__ = ["SceneError", "describe"]
