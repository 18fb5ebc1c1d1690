"""Shared test helpers: rendering a parsed scene and comparing 8-bit images."""
from __future__ import annotations

import re

import numpy as np

from converters.description import RenderOptions, scene_dict
from converters.model import Scene
from converters.scene_variants import apply
from converters.to_mitsuba import load_scene_dict
from imaging.colour import to_course_8bit
from imaging.metrics import MAX_BAD_FRACTION, bad_fraction, bad_pixels  # noqa: F401 (the course's bar, re-exported)


def render_layers(scene: Scene, variants=(), **options) -> dict[str, np.ndarray]:
    """Renders with the active variant; returns beauty and the requested AOVs.
    ``variants``: :mod:`converters.scene_variants` functions, applied in order."""
    import mitsuba as mi

    from renderer.job import split_layers

    opts = RenderOptions(**options)
    image = np.array(mi.render(load_scene_dict(apply(scene_dict(scene, opts), variants))), np.float32)
    return split_layers(image, opts.aovs)


def encode(image: np.ndarray) -> np.ndarray:
    return to_course_8bit(image)


def assert_loading_is_one_line(source: str, expected: str, tmp_path, capsys) -> None:
    """``source`` saved as ``my_filter.py`` and given to ``python -m denoise
    --method-file ... --help``: exit 2 and one line, no traceback, whose text
    after the folder matches the regular expression ``expected``."""
    from denoise.__main__ import main

    path = tmp_path / "my_filter.py"
    path.write_text(source)
    assert main(["--method-file", str(path), "--help"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err and "\x1b" not in err, err
    assert re.search(f"^python -m denoise: error: {re.escape(str(tmp_path))}/{expected}", err), err


def live_server_stopping(path, method: str, switch_to: str | None = None) -> tuple[int, str]:
    """``python -m denoise.live`` at 32x18 with the method file ``path``, first
    showing ``method``: a viewer acknowledges every frame as the page does
    (switching to ``switch_to`` after the first) until the server closes the
    connection; returns (its exit code, its stderr)."""
    import asyncio
    import json
    import signal
    import subprocess
    import sys
    from pathlib import Path

    import aiohttp

    process = subprocess.Popen([sys.executable, "-m", "denoise.live", "showcase", "--size", "32", "18", "--variant",
                                "llvm_ad_rgb", "--port", "0", "--method-file", str(path), "--method", method],
                               cwd=Path(__file__).resolve().parent.parent, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    try:
        url = process.stdout.readline().split("open ", 1)[1].split()[0]

        async def view():
            async with aiohttp.ClientSession() as session:
                async with session.ws_connect(url + "ws", headers={"Origin": url.rstrip("/")}) as ws:
                    switched = switch_to is None
                    while not ws.closed:
                        message = await asyncio.wait_for(ws.receive(), 240)
                        if message.type in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED,
                                            aiohttp.WSMsgType.ERROR):
                            return
                        if message.type == aiohttp.WSMsgType.BINARY:
                            length = int.from_bytes(message.data[:4], "little")
                            frame = json.loads(message.data[4:4 + length])["frame"]
                            if not switched:
                                await ws.send_str(json.dumps({"type": "method", "name": switch_to}))
                                switched = True
                            await ws.send_str(json.dumps({"type": "ack", "frame": frame}))

        asyncio.run(asyncio.wait_for(view(), 300))
        err = process.communicate(timeout=60)[1]
    finally:
        if process.poll() is None:
            process.send_signal(signal.SIGTERM)
            try:
                process.wait(10)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait(10)
    return process.returncode, err
