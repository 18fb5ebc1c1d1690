"""What the viewer controls (camera, first point light, method, sliders,
pause) and the check of every message the page sends.

A message is one JSON object of at most :data:`MESSAGE_LIMIT` bytes with a
known ``type`` and exactly that type's keys (:data:`MESSAGES`); numbers are
finite and in their range, names are among the known ones. A message that
fails any check raises :class:`MessageError` (its text goes back to the
page) and changes nothing.
"""
from __future__ import annotations

import dataclasses
import math
import re
import threading

import numpy as np

from converters.model import Camera
from core.json_input import JSONInputError, json_kind, parse_json, shown

from .methods import METHOD_NAMES, SLIDERS

#: the largest message accepted, in bytes (the page's are below 200)
MESSAGE_LIMIT = 2048
#: the frame sizes the page offers (``WxH``); the size the server started with is kept until one is chosen
SIZES = ("320x180", "640x360", "1280x720")
SIZE_NAME = re.compile(r"[1-9][0-9]{0,3}x[1-9][0-9]{0,3}")
#: per message type: key -> (low, high) for numbers, bool, or "method"/"slider" for names
MESSAGES = {
    "orbit": {"dx": (-180.0, 180.0), "dy": (-180.0, 180.0)},  # degrees about the pivot
    "dolly": {"amount": (-1.0, 1.0)},  # fraction of the distance to the pivot, forward positive
    "pan": {"dx": (-1.0, 1.0), "dy": (-1.0, 1.0)},  # fraction of the view's half-width at the pivot
    "light": {"dx": (-1.0, 1.0), "dy": (-1.0, 1.0), "dz": (-1.0, 1.0)},  # along the view's axes, same unit
    "method": {"name": "method"},
    "size": {"name": "size"},  # one of SIZES
    "param": {"name": "slider", "value": (-1e9, 1e9)},  # the value is then checked against the slider's range
    "pause": {"paused": bool},
    "step": {},
    "reset_history": {},
    "reset_view": {},
    "ack": {"frame": (0, 2 ** 53)},
}
#: the pivot stays at least this fraction of its first distance in front of the camera
MIN_PIVOT_DISTANCE = 1e-3
#: ... and at most this multiple of it behind (each dolly out doubles the distance at most)
MAX_PIVOT_DISTANCE = 1e3
#: pitch stays this many degrees away from straight up or down
PITCH_MARGIN = 1.0


class MessageError(ValueError):
    """A message the page sent that is not acceptable; the text says why."""


def parse_message(text: str | bytes, method: str) -> dict:
    """The checked message in ``text``; ``method`` is the current method (its
    sliders are the names ``param`` accepts)."""
    if isinstance(text, bytes):
        raise MessageError("expected a text message (JSON), got binary data")
    try:
        message = parse_json(text, MESSAGE_LIMIT)
    except JSONInputError as error:
        raise MessageError(f"not JSON: {error}") from None
    if not isinstance(message, dict):
        raise MessageError(f"expected a JSON object, got {json_kind(message)}")
    kind = message.get("type")
    if not isinstance(kind, str) or kind not in MESSAGES:
        raise MessageError(f"unknown message type {kind!r}; known: {', '.join(MESSAGES)}")
    schema = MESSAGES[kind]
    keys = set(message) - {"type"}
    if keys != set(schema):
        extra, missing = sorted(keys - set(schema)), sorted(set(schema) - keys)
        raise MessageError(f"{kind}: " + "; ".join(
            ([f"unknown keys {', '.join(map(shown, extra))}"] if extra else [])
            + ([f"missing keys {', '.join(missing)}"] if missing else [])))
    for key, rule in schema.items():
        value = message[key]
        if rule is bool:
            if not isinstance(value, bool):
                raise MessageError(f"{kind}.{key}: expected true or false, got {shown(value)}")
        elif rule == "method":
            if not isinstance(value, str) or value not in METHOD_NAMES:
                raise MessageError(f"{kind}.{key}: unknown method {str(value)[:40]!r}; "
                                   f"known: {', '.join(METHOD_NAMES)}")
        elif rule == "size":
            if not isinstance(value, str) or not SIZE_NAME.fullmatch(value):
                raise MessageError(f"{kind}.{key}: expected WIDTHxHEIGHT, one of {', '.join(SIZES)}, "
                                   f"got {str(value)[:40]!r}")
        elif rule == "slider":
            names = [s.name for s in SLIDERS[method]]
            if not isinstance(value, str) or value not in names:
                raise MessageError(f"{kind}.{key}: {method} has no parameter {str(value)[:40]!r}"
                                   f" (it has: {', '.join(names) or 'none'})")
        else:
            low, high = rule
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                    or not low <= value <= high:
                raise MessageError(f"{kind}.{key}: expected a number in [{low:g}, {high:g}], got {shown(value)}")
    if kind == "param":
        slider = next(s for s in SLIDERS[method] if s.name == message["name"])
        value = message["value"]
        if not slider.low <= value <= slider.high or (slider.whole and value != int(value)):
            kind_text = "a whole number" if slider.whole else "a number"
            raise MessageError(f"param {slider.name}: expected {kind_text} in [{slider.low:g}, {slider.high:g}], "
                               f"got {value!r}")
    return message


def _unit(v) -> np.ndarray:
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


def _rotate(v: np.ndarray, axis: np.ndarray, degrees: float) -> np.ndarray:
    """Rodrigues' rotation of ``v`` about unit ``axis``."""
    t = math.radians(degrees)
    return v * math.cos(t) + np.cross(axis, v) * math.sin(t) + axis * (axis @ v) * (1 - math.cos(t))


@dataclasses.dataclass(frozen=True)
class View:
    """What one frame renders: the camera, the first point light's position
    (None without one), the method, its slider values and the frame size."""
    camera: Camera
    light: tuple[float, float, float] | None
    method: str
    values: tuple[tuple[str, float], ...]
    size: tuple[int, int]


class Session:
    """The viewer's state, changed by checked messages (:meth:`apply`) from the
    server's thread and read by the frame loop (:meth:`view`)."""

    def __init__(self, camera: Camera, light, pivot_distance: float, method: str, size: tuple[int, int] = (320, 180)):
        self.first_camera, self.first_light = camera, None if light is None else tuple(map(float, light))
        self.first_distance = pivot_distance
        self.method = method
        self.size = self.first_size = (int(size[0]), int(size[1]))
        self.values: dict[str, dict[str, float]] = {name: {} for name in METHOD_NAMES}
        self.paused = False
        self.steps = 0  # single steps asked for while paused
        self.history_resets = 0  # counts reset_history messages (and method changes)
        self.changed = threading.Condition()
        self.acked: int | None = None  # the last frame the page showed (None: none since it connected)
        self.published = -1  # the last frame handed to the viewer: no acknowledgement goes beyond it
        self.connected = False  # a viewer is there: frames are rendered only then
        self.reset_view()

    def connect(self, connected: bool) -> None:
        """A viewer came (True) or went; frames sent before it came count as shown."""
        with self.changed:
            self.connected, self.acked = connected, None
            self.changed.notify_all()

    def reset_view(self) -> None:
        self.camera, self.light, self.distance = self.first_camera, self.first_light, self.first_distance

    def view(self) -> View:
        with self.changed:
            return View(self.camera, self.light, self.method, tuple(sorted(self.values[self.method].items())),
                        self.size)

    def apply(self, message: dict) -> None:
        """Applies a message from :func:`parse_message` and wakes the frame loop."""
        with self.changed:
            getattr(self, "_" + message["type"])(**{k: v for k, v in message.items() if k != "type"})
            self.changed.notify_all()

    # -- one method per message type ----------------------------------------------
    def _axes(self):
        forward = _unit(self.camera.direction)
        horizontal = _unit(np.cross(forward, self.camera.up))
        return forward, horizontal, np.cross(horizontal, forward)

    def _half_width(self) -> float:
        return self.distance * math.tan(math.radians(self.camera.angle) / 2)

    def _orbit(self, dx: float, dy: float) -> None:
        forward, horizontal, _ = self._axes()
        center = np.asarray(self.camera.center, np.float64)
        pivot = center + forward * self.distance
        world_up = _unit(self.camera.up)
        # pitch first, kept off the poles so the up vector stays usable
        pitch = math.degrees(math.asin(float(np.clip(forward @ world_up, -1, 1))))
        dy = float(np.clip(dy, -90 + PITCH_MARGIN - pitch, 90 - PITCH_MARGIN - pitch))
        offset = _rotate(center - pivot, horizontal, -dy)
        direction = _rotate(forward, horizontal, -dy)
        offset, direction = _rotate(offset, world_up, -dx), _rotate(direction, world_up, -dx)
        self.camera = dataclasses.replace(self.camera, center=tuple(pivot + offset), direction=tuple(direction))

    def _dolly(self, amount: float) -> None:
        forward, _, _ = self._axes()
        step = min(amount * self.distance, self.distance - MIN_PIVOT_DISTANCE * self.first_distance)
        step = max(step, self.distance - MAX_PIVOT_DISTANCE * self.first_distance)
        center = np.asarray(self.camera.center, np.float64) + forward * step
        self.distance -= step
        self.camera = dataclasses.replace(self.camera, center=tuple(center))

    def _pan(self, dx: float, dy: float) -> None:
        _, horizontal, up = self._axes()
        move = (horizontal * dx + up * dy) * self._half_width()
        self.camera = dataclasses.replace(self.camera, center=tuple(np.asarray(self.camera.center) + move))

    def _light(self, dx: float, dy: float, dz: float) -> None:
        if self.light is None:
            raise MessageError("light: the scene has no point light to move")
        forward, horizontal, up = self._axes()
        move = (horizontal * dx + up * dy + forward * dz) * self._half_width()
        self.light = tuple(float(v) for v in np.asarray(self.light) + move)

    def _method(self, name: str) -> None:
        self.method = name
        self.history_resets += 1

    def _size(self, name: str) -> None:
        width, height = (int(v) for v in name.split("x"))
        if name not in SIZES and (width, height) != self.first_size:
            first = "{}x{}".format(*self.first_size)
            started = "" if first in SIZES else f", and {first}, the size the server started with"
            raise MessageError(f"size.name: unknown size {name!r}; known: {', '.join(SIZES)} (those the page "
                               f"lists){started}")
        if (width, height) != self.size:
            self.size = (width, height)
            self.history_resets += 1

    def _param(self, name: str, value: float) -> None:
        self.values[self.method][name] = value

    def _pause(self, paused: bool) -> None:
        self.paused = paused

    def _step(self) -> None:
        self.steps += 1

    def _reset_history(self) -> None:
        self.history_resets += 1

    def _reset_view(self) -> None:
        self.reset_view()
        self.history_resets += 1

    def _ack(self, frame: int) -> None:
        """A frame the page showed; a number beyond the frames sent counts as the
        last one sent, so no message lets the frame loop run ahead of the page."""
        self.acked = max(self.acked if self.acked is not None else -1, min(int(frame), self.published))
