"""The one error type that bad scene input produces."""
from __future__ import annotations

from pathlib import Path


class SceneError(Exception):
    """A problem in a scene, mesh or cube-map file, located as ``file:line:col``.

    ``str(error)`` is the one line shown to the user, e.g.
    ``scene.txt:12:5: expected a number, found 'radius'``.
    """

    def __init__(self, path: str | Path, line: int, col: int, message: str):
        self.path, self.line, self.col, self.message = str(path), line, col, message
        super().__init__(f"{self.path}:{line}:{col}: {message}")


def describe(text: str | None) -> str:
    """How a found token is quoted in messages."""
    if text is None:
        return "end of file"
    if len(text) > 40:
        text = text[:37] + "..."
    return repr(text)
