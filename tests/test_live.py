"""The live page (``python -m denoise.live``): message checks, the server's
safety points against a real server process, and the page in a real browser
(Debian's chromium driven headless by Playwright)."""
from __future__ import annotations

import asyncio
import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from denoise.live.app import is_loopback
from denoise.live.frame_loop import IN_FLIGHT
from denoise.live.methods import METHOD_NAMES, SLIDERS
from denoise.live.server import HEARTBEAT_S
from denoise.live.session import MESSAGE_LIMIT, MessageError, parse_message

ROOT = Path(__file__).resolve().parent.parent
CHROMIUM = Path("/usr/bin/chromium")
#: small frames: the tests check the plumbing, the benchmark the speed
SIZE = ("96", "54")
#: the first frame compiles every kernel (tens of seconds on a busy 2-core machine)
FIRST_FRAME_S = int(os.environ.get("LIVE_FIRST_FRAME_S", 240))


# -- messages (no server) -------------------------------------------------------------
GOOD = [{"type": "orbit", "dx": 3.5, "dy": -1}, {"type": "dolly", "amount": 0.1}, {"type": "pan", "dx": 0, "dy": 0.2},
        {"type": "light", "dx": 0.1, "dy": 0, "dz": -0.1}, {"type": "method", "name": "atrous+temporal"},
        {"type": "param", "name": "sigma_luminance", "value": 8}, {"type": "pause", "paused": True},
        {"type": "step"}, {"type": "reset_history"}, {"type": "reset_view"}, {"type": "ack", "frame": 12},
        {"type": "size", "name": "640x360"}]
BAD = {
    "too long": json.dumps({"type": "step", "pad": "x" * MESSAGE_LIMIT}),
    "not json": "{type: step}",
    "not an object": "[1, 2]",
    "unknown type": '{"type": "shell", "command": "ls"}',
    "no type": '{"dx": 1}',
    "unknown key": '{"type": "step", "extra": 1}',
    "missing key": '{"type": "orbit", "dx": 1}',
    "number out of range": '{"type": "orbit", "dx": 1e9, "dy": 0}',
    "NaN": '{"type": "orbit", "dx": NaN, "dy": 0}',
    "infinity": '{"type": "dolly", "amount": Infinity}',
    "bool for a number": '{"type": "dolly", "amount": true}',
    "string for a number": '{"type": "dolly", "amount": "0.1"}',
    "string for a bool": '{"type": "pause", "paused": "yes"}',
    "unknown method": '{"type": "method", "name": "rm -rf"}',
    "not a size": '{"type": "size", "name": "99999x1"}',
    "a size with a sign": '{"type": "size", "name": "-320x180"}',
    "size as numbers": '{"type": "size", "name": [640, 360]}',
    "unknown slider": '{"type": "param", "name": "levels_x", "value": 1}',
    "slider value beyond its range": '{"type": "param", "name": "sigma_luminance", "value": 1000}',
    "fractional whole slider": '{"type": "param", "name": "levels", "value": 2.5}',
    "negative frame": '{"type": "ack", "frame": -1}',
    "deeply nested": "[" * 900 + "]" * 900,
    "a key twice": '{"type": "orbit", "dx": 1, "dy": 0, "dx": 2}',
    "a number too large for a float": '{"type": "dolly", "amount": 1e999}',
    "a long integer": '{"type": "ack", "frame": ' + "1" * 1500 + "}",
    "a lone surrogate": '{"type": "method", "name": "\\ud800"}',
    "megabytes": '{"type": "step", "pad": "' + "x" * (4 << 20) + '"}',
}


@pytest.mark.parametrize("message", GOOD, ids=[m["type"] for m in GOOD])
def test_good_messages_pass(message):
    assert parse_message(json.dumps(message), "svgf") == message


@pytest.mark.parametrize("text", BAD.values(), ids=BAD.keys())
def test_bad_messages_are_refused(text):
    with pytest.raises(MessageError):
        parse_message(text, "svgf")


def test_an_unknown_method_is_refused_with_the_known_ones():
    known = re.escape(", ".join(METHOD_NAMES))
    with pytest.raises(MessageError, match=f"unknown method 'rm -rf'; known: {known}$"):
        parse_message(BAD["unknown method"], "svgf")


@pytest.mark.parametrize("value, expected", [(0.5, None), (2.0, None), (float("nan"), 0), (float("inf"), 255),
                                             (-1.0, 0), (1e30, 255)])
def test_frames_are_tone_mapped_as_the_previews(value, expected):
    """A frame's JPEG holds the previews' tone map of each pixel (a flat grey block, which
    JPEG keeps within a code or two); NaN is black, +inf and huge values white."""
    import io
    import warnings

    from PIL import Image

    from denoise.live.frame_loop import JPEGEncoder
    from imaging.colour import tone_map

    image = np.full((16, 16, 3), value, np.float32)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # NaN cast to an integer is undefined (NumPy warns), not a code
        encoded = JPEGEncoder()(image)
    decoded = np.asarray(Image.open(io.BytesIO(encoded)).convert("RGB"), np.int32)
    if expected is None:
        expected = int(tone_map(np.array([value]))[0])
    assert np.abs(decoded - expected).max() <= 2


def test_a_frame_is_one_jpeg_with_both_images_in_their_own_blocks():
    """Raw and denoised go as one JPEG (one decode in the page), side by side, each in a
    column of whole 8-pixel blocks and its colour not subsampled: at a width that is no
    multiple of 8, neither bleeds into the other."""
    import io

    from PIL import Image

    from denoise.live.frame_loop import JPEGEncoder, slot_width

    dark, bright = np.zeros((18, 29, 3), np.float32), np.zeros((18, 29, 3), np.float32)
    dark[..., 0], bright[..., 1] = 0.3, 3.0  # red beside green: subsampled colour would bleed across
    decoded = np.asarray(Image.open(io.BytesIO(JPEGEncoder()(dark, bright))).convert("RGB"), np.int32)
    slot = slot_width(29)
    assert slot == 32 and decoded.shape == (18, 2 * slot, 3)
    for image, start in ((dark, 0), (bright, slot)):
        expected = JPEGEncoder().codes(image).astype(np.int32)
        assert np.abs(decoded[:, start:start + 29] - expected).max() <= 3


def test_binary_message_is_refused():
    with pytest.raises(MessageError, match="text message"):
        parse_message(b'{"type": "step"}', "svgf")


def test_every_method_is_built_with_its_sliders(variant_llvm_ad_rgb):
    """Every registered method is on the page, each with its sliders' values."""
    from denoise.live.methods import describe, method_for
    from denoise.methods import METHODS

    assert {name.split("+")[0].split("-")[0] for name in METHOD_NAMES[1:]} >= {n.split("-")[0] for n in METHODS}
    assert SLIDERS["svgf"] and SLIDERS["atrous+temporal"]
    for name in METHOD_NAMES:
        values = {s.name: s.high for s in SLIDERS[name]}
        method = method_for(name, 320, values)
        assert (method is None) == (name == "raw")
        assert [s["value"] for s in describe(name, 320, values)] == [s.high for s in SLIDERS[name]]


# -- a real server ---------------------------------------------------------------------
def _needs_llvm():
    from core.libllvm import find_libllvm

    if find_libllvm() is None:
        pytest.skip("no usable libLLVM: the live page needs a JIT variant")


def start_server(*extra: str, scene: str = "showcase") -> tuple[subprocess.Popen, str]:
    """``python -m denoise.live`` in a new process; (process, address) once it listens."""
    command = [sys.executable, "-m", "denoise.live", scene, "--size", *SIZE, "--variant", "llvm_ad_rgb", *extra]
    process = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = process.stdout.readline()
    if "http://" not in line:
        process.kill()
        raise AssertionError(f"no address printed: {line!r} {process.stderr.read()!r}")
    return process, line.split("open ", 1)[1].split()[0]


def stop(process: subprocess.Popen) -> None:
    if process.poll() is None:
        process.kill()
        process.wait(10)


@pytest.fixture(scope="module")
def server():
    _needs_llvm()
    process, url = start_server("--port", "0")
    yield url
    stop(process)


def port_of(url: str) -> int:
    return int(url.rstrip("/").rsplit(":", 1)[1])


async def _receive_frame(ws, timeout: float = FIRST_FRAME_S):
    """The next frame's header (text messages before it are returned in a list too)."""
    import aiohttp

    texts = []
    while True:
        message = await asyncio.wait_for(ws.receive(), timeout)
        if message.type == aiohttp.WSMsgType.BINARY:
            length = int.from_bytes(message.data[:4], "little")
            return json.loads(message.data[4:4 + length]), texts
        if message.type != aiohttp.WSMsgType.TEXT:
            raise AssertionError(f"socket closed: {message}")
        texts.append(json.loads(message.data))


def run(coroutine):
    return asyncio.run(coroutine)


def test_listens_on_loopback_only(server):
    assert server.startswith("http://127.0.0.1:")
    with pytest.raises(OSError):  # 127.0.0.2 is this machine too, but not the address it listens on
        socket.create_connection(("127.0.0.2", port_of(server)), timeout=5).close()
    socket.create_connection(("127.0.0.1", port_of(server)), timeout=5).close()


@pytest.mark.parametrize("origin", ["http://evil.example", "http://127.0.0.1:1", "null", None])
def test_socket_from_another_origin_is_refused(server, origin):
    import aiohttp

    async def connect():
        headers = {} if origin is None else {"Origin": origin}
        async with aiohttp.ClientSession() as session:
            with pytest.raises(aiohttp.WSServerHandshakeError) as error:
                await session.ws_connect(server + "ws", headers=headers)
            assert error.value.status == 403

    run(connect())


def _raw_get(url: str, path: str) -> int:
    """The status of ``GET path`` sent byte for byte (no client normalises it)."""
    with socket.create_connection(("127.0.0.1", port_of(url)), timeout=30) as s:
        s.sendall(f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n".encode())
        return int(s.recv(4096).split(b" ", 2)[1])


@pytest.mark.parametrize("path", ["/../pyproject.toml", "/static/../../../pyproject.toml", "/%2e%2e/pyproject.toml",
                                  "/%2E%2E%2Fpyproject.toml", "//etc/passwd", "/etc/passwd", "/static/index.html",
                                  "/index.html/..", "/./", "/denoise/live/static/index.html", "/%2f"])
def test_serves_only_its_page(server, path):
    assert _raw_get(server, path) == 404


def test_serves_the_page(server):
    assert _raw_get(server, "/") == 200


def test_bad_message_gets_an_error_and_the_stream_goes_on(server):
    import aiohttp

    async def talk():
        async with aiohttp.ClientSession() as session:
            async with session.ws_connect(server + "ws", headers={"Origin": server.rstrip("/")}) as ws:
                first, texts = await _receive_frame(ws)
                assert [t["type"] for t in texts][:2] == ["hello", "state"]
                for text in (BAD["unknown type"], BAD["too long"], BAD["number out of range"]):
                    await ws.send_str(text)
                await ws.send_bytes(b"\x00\x01")
                await ws.send_json({"type": "ack", "frame": first["frame"]})
                errors = []
                frame = first
                while len(errors) < 4 or frame["frame"] <= first["frame"]:
                    frame, texts = await _receive_frame(ws, 60)
                    errors += [t for t in texts if t["type"] == "error"]
                    await ws.send_json({"type": "ack", "frame": frame["frame"]})
                assert len(errors) == 4 and all(e["message"] for e in errors)
                assert frame["frame"] > first["frame"]

    run(talk())


def test_second_viewer_is_refused_with_a_message(server):
    import aiohttp

    async def two():
        async with aiohttp.ClientSession() as session:
            origin = {"Origin": server.rstrip("/")}
            async with session.ws_connect(server + "ws", headers=origin) as first:
                await _receive_frame(first)
                async with session.ws_connect(server + "ws", headers=origin) as second:
                    message = await asyncio.wait_for(second.receive(), 30)
                    assert json.loads(message.data)["type"] == "refused"
                    assert (await asyncio.wait_for(second.receive(), 30)).type == aiohttp.WSMsgType.CLOSE
                # the first still streams
                await first.send_json({"type": "ack", "frame": 10 ** 6})
                await _receive_frame(first, 60)

    run(two())


def test_a_silent_viewer_does_not_hold_the_place(server):
    """A client that opens the socket and then never reads or answers (an outside
    tester's raw socket held the one viewer's place for good): the server's ping goes
    unanswered, it closes that socket, and the next viewer is served."""
    import base64

    import aiohttp

    host, port = "127.0.0.1", port_of(server)
    silent = socket.create_connection((host, port))
    key = base64.b64encode(os.urandom(16)).decode()
    silent.sendall((f"GET /ws HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                    f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\nOrigin: {server.rstrip('/')}\r\n\r\n"
                    ).encode())
    assert b" 101 " in silent.recv(1024).split(b"\r\n", 1)[0]

    async def next_viewer():
        async with aiohttp.ClientSession() as session:
            async with session.ws_connect(server + "ws", headers={"Origin": server.rstrip("/")}) as ws:
                return json.loads((await asyncio.wait_for(ws.receive(), 30)).data)["type"]

    try:
        assert run(next_viewer()) == "refused"  # the silent one has the place, for now
        time.sleep(HEARTBEAT_S * 1.5 + 2)
        assert run(next_viewer()) == "hello"
    finally:
        silent.close()


def test_the_next_viewer_is_greeted_with_the_size_now(server):
    """A viewer changes the size and leaves: the next one's hello gives the size
    the frames now have (it gave the size the server started with)."""
    import aiohttp

    async def viewer(size: str | None) -> dict:
        async with aiohttp.ClientSession() as session:
            async with session.ws_connect(server + "ws", headers={"Origin": server.rstrip("/")}) as ws:
                hello = json.loads((await asyncio.wait_for(ws.receive(), 30)).data)
                if size is not None:
                    await ws.send_json({"type": "size", "name": size})
                    while True:  # applied once the state that answers it comes
                        message = await asyncio.wait_for(ws.receive(), 60)
                        if message.type == aiohttp.WSMsgType.TEXT and json.loads(message.data).get("size") == size:
                            break
                return hello

    started = "x".join(SIZE)
    assert "{width}x{height}".format(**run(viewer("320x180"))) == started
    try:
        assert "{width}x{height}".format(**run(viewer(started))) == "320x180"
    finally:
        assert "{width}x{height}".format(**run(viewer(None))) == started


def test_port_in_use_is_one_line_exit_2(server):
    result = subprocess.run([sys.executable, "-m", "denoise.live", "showcase", "--port", str(port_of(server))],
                            cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and "in use" in result.stderr and result.stdout == ""


@pytest.mark.parametrize("host, loopback", [("127.0.0.1", True), ("localhost", True), ("::1", True),
                                            ("127.0.0.2", True), ("", False), ("0.0.0.0", False), ("::", False),
                                            ("192.168.1.10", False), ("example.com", False)])
def test_only_loopback_hosts_are_served(host, loopback):
    assert is_loopback(host) == loopback


@pytest.mark.parametrize("host", ["", "0.0.0.0"])
def test_a_host_beyond_loopback_is_one_line_exit_2(host):
    """The page has no login: ``--host ""`` listened on every interface."""
    result = subprocess.run([sys.executable, "-m", "denoise.live", "showcase", "--host", host, "--port", "0"],
                            cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert result.returncode == 2, result.stderr
    assert result.stderr.count("\n") == 1 and "--host" in result.stderr and result.stdout == ""


def test_a_viewer_that_stops_reading_gets_no_queue(server):
    """Acknowledgements far beyond the frames sent, and steps, then no reading:
    the frame loop stays within IN_FLIGHT frames of what was really sent (an
    acknowledgement taken at its word let it queue frames without bound)."""
    import aiohttp

    async def flood():
        async with aiohttp.ClientSession() as session:
            async with session.ws_connect(server + "ws", headers={"Origin": server.rstrip("/")}) as ws:
                await _receive_frame(ws)
                for _ in range(100):
                    await ws.send_json({"type": "ack", "frame": 10 ** 9})
                    await ws.send_json({"type": "step"})
                await asyncio.sleep(3)  # a page that reads nothing
                frames = []
                while len(frames) < 20:
                    try:
                        header, _ = await _receive_frame(ws, 2.0)
                    except asyncio.TimeoutError:
                        break
                    frames.append(header["frame"])
                return frames

    frames = run(flood())
    assert len(frames) <= 2 * IN_FLIGHT, frames


@pytest.mark.timed
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_interrupt_stops_within_a_second(signum):
    _needs_llvm()
    process, url = start_server("--port", "0")
    try:
        import aiohttp

        async def watch():
            async with aiohttp.ClientSession() as session:
                async with session.ws_connect(url + "ws", headers={"Origin": url.rstrip("/")}) as ws:
                    async def keep_watching():  # a viewer streaming frames while the signal comes
                        while True:
                            header, _ = await _receive_frame(ws)
                            await ws.send_json({"type": "ack", "frame": header["frame"]})

                    viewer = asyncio.ensure_future(keep_watching())
                    await asyncio.sleep(1.0)  # frames are being rendered and sent
                    start = time.perf_counter()
                    process.send_signal(signum)
                    while process.poll() is None and time.perf_counter() - start < 10:
                        await asyncio.sleep(0.02)
                    seconds = time.perf_counter() - start
                    viewer.cancel()
                    await asyncio.gather(viewer, return_exceptions=True)
                    return seconds

        seconds = run(watch())
        assert process.poll() is not None, "still running 10 s after the signal"
        stderr = process.stderr.read()
        assert process.returncode == 128 + signum
        assert seconds < 1.0, f"took {seconds:.2f} s"
        assert stderr.count("\n") <= 1, stderr
    finally:
        stop(process)


# -- the page in a real browser -----------------------------------------------------------
def _browser():
    if not CHROMIUM.exists():
        pytest.skip(f"{CHROMIUM} missing: ./dev setup installs Debian's chromium")
    playwright = pytest.importorskip("playwright.sync_api", reason="playwright not installed (pip install -e .[test])")
    return playwright


def canvas_pixels(page) -> np.ndarray:
    data = page.evaluate("() => { const c = document.getElementById('canvas');"
                         " return Array.from(c.getContext('2d').getImageData(0, 0, c.width, c.height).data); }")
    width, height = page.evaluate("[document.getElementById('canvas').width, document.getElementById('canvas').height]")
    return np.asarray(data, np.float64).reshape(height, width, 4)[..., :3]


def step(page) -> np.ndarray:
    """One more frame while paused; its pixels."""
    frames = page.evaluate("window.live.frames")
    page.click("#step")
    page.wait_for_function(f"window.live.frames > {frames}", timeout=60000)
    return canvas_pixels(page)


def blocks(image: np.ndarray, size: int = 6) -> np.ndarray:
    h, w = image.shape[0] // size * size, image.shape[1] // size * size
    return image[:h, :w].reshape(h // size, size, w // size, size, 3).mean(axis=(1, 3))


def test_page_in_a_real_browser(server):
    sync_api = _browser()
    with sync_api.sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=["--no-sandbox"])
        try:
            page = browser.new_page()
            page.goto(server)
            page.wait_for_function("window.live.frames >= 3", timeout=FIRST_FRAME_S * 1000)
            assert float(page.inner_text("#fps")) > 0  # a number, counted by the page
            page.click("#pause")
            page.wait_for_function("window.live.state && window.live.state.paused", timeout=30000)
            page.wait_for_timeout(2000)  # frames already under way arrive
            step(page)
            before = step(page)
            again = step(page)  # same view: only the noise changes
            box = page.locator("#canvas").bounding_box()
            x, y = box["x"] + box["width"] * 0.25, box["y"] + box["height"] / 2
            page.mouse.move(x, y)
            page.mouse.down()
            page.mouse.move(x + 60, y, steps=6)
            page.mouse.up()
            page.wait_for_timeout(300)  # the page sends moves once per animation frame
            dragged = step(page)
            noise = np.abs(blocks(again) - blocks(before)).mean()
            moved = np.abs(blocks(dragged) - blocks(again)).mean()
            assert moved > 3 * noise, (moved, noise)
            right = slice(dragged.shape[1] // 2 + 2, None)
            same_method = np.abs(step(page)[:, right] - (last := step(page))[:, right]).mean()
            page.select_option("#method", "raw")
            page.wait_for_function("window.live.state.method === 'raw'", timeout=30000)
            switched = step(page)
            assert page.evaluate("window.live.header.method") == "raw"
            assert np.abs(switched[:, right] - last[:, right]).mean() > 3 * same_method
            page.select_option("#size", "320x180")  # the size control: the next frame is rendered at that size
            page.wait_for_function("window.live.state.size === '320x180'", timeout=30000)
            frames = page.evaluate("window.live.frames")
            page.click("#step")
            page.wait_for_function(f"window.live.frames > {frames}", timeout=FIRST_FRAME_S * 1000)
            assert page.evaluate("[window.live.header.width, window.live.header.height]") == [320, 180]
            assert canvas_pixels(page).shape[:2] == (180, 320)
            assert page.evaluate("window.live.errors") == []
        finally:
            browser.close()


# -- the session's camera and light (no server) ------------------------------------------
def _session(light=(1.0, 2.0, 3.0)):
    from converters.model import Camera
    from denoise.live.session import Session

    return Session(Camera((0.0, 0.0, 10.0), (0.0, 0.0, -1.0), (0.0, 1.0, 0.0), 40.0), light, 10.0, "svgf")


def test_orbit_keeps_the_pivot_in_view_and_its_distance():
    session = _session()
    session.apply({"type": "orbit", "dx": 90.0, "dy": 0.0})
    camera = session.view().camera
    assert np.allclose(camera.center, (-10.0, 0.0, 0.0), atol=1e-9)  # a quarter turn about the origin
    assert np.allclose(np.asarray(camera.center) + 10.0 * np.asarray(camera.direction), 0.0, atol=1e-9)
    session.apply({"type": "orbit", "dx": 0.0, "dy": 180.0})  # pitch stops short of the pole
    assert abs(session.view().camera.direction[1]) < 1.0


def test_dolly_stops_before_the_pivot_and_reset_view_restores():
    session = _session()
    for _ in range(50):
        session.apply({"type": "dolly", "amount": 1.0})
    assert 0 < session.distance and session.view().camera.center[2] > 0.0
    session.apply({"type": "reset_view"})
    assert session.view().camera.center == (0.0, 0.0, 10.0)


def test_light_moves_in_the_view_plane_and_a_scene_without_one_says_so():
    session = _session()
    session.apply({"type": "light", "dx": 0.5, "dy": 0.0, "dz": 0.0})
    assert session.view().light[0] > 1.0 and session.view().light[1:] == (2.0, 3.0)
    with pytest.raises(MessageError, match="no point light"):
        _session(light=None).apply({"type": "light", "dx": 0.1, "dy": 0.0, "dz": 0.0})


def test_the_page_offers_its_sizes_and_the_one_it_started_with():
    from denoise.live.session import SIZES, parse_message

    session = _session()
    session.first_size = session.size = (32, 18)
    for name in (*SIZES, "32x18"):
        session.apply(parse_message(f'{{"type": "size", "name": "{name}"}}', "svgf"))
        assert "{}x{}".format(*session.view().size) == name
    with pytest.raises(MessageError, match=re.escape(f"unknown size '99x99'; known: {', '.join(SIZES)} (those the "
                                                     "page lists), and 32x18, the size the server started with")):
        session.apply(parse_message('{"type": "size", "name": "99x99"}', "svgf"))
    assert session.view().size == (32, 18)


@pytest.mark.parametrize("text, expected", [
    ("null", "expected a JSON object, got null"), ("[1, 2]", "expected a JSON object, got an array"),
    ('"step"', "expected a JSON object, got a string"), ("7", "expected a JSON object, got a number"),
    ('{"type": "step", "": 1}', 'step: unknown keys ""'),
    ('{"type": "pause", "paused": null}', "pause.paused: expected true or false, got null"),
    ('{"type": "dolly", "amount": true}', "dolly.amount: expected a number in [-1, 1], got true")])
def test_a_refused_message_says_what_it_got_in_json_words(text, expected):
    """The page speaks JSON: a refusal names what came in JSON's words (null, an array, true), not Python's."""
    with pytest.raises(MessageError) as error:
        parse_message(text, "svgf")
    assert str(error.value) == expected


def test_dolly_out_stays_within_float32():
    """200 dolly-outs: the camera stays a bounded distance away (it had run to 2^200, beyond float32)."""
    session = _session()
    for _ in range(200):
        session.apply({"type": "dolly", "amount": -1.0})
    assert session.distance <= 1e3 * session.first_distance * (1 + 1e-9)
    assert np.all(np.abs(session.camera.center) < 1e6)


# -- the frame loop's passes (no server) -----------------------------------------------
def test_frozen_gbuffers_are_whitteds_aovs_bit_for_bit(variant_vectorised_rgb):
    """The live G-buffer pass (frozen, AOVs alone) gives exactly what whitted's
    ``sample`` gives as its AOVs, frame after frame of a moving camera (the
    frozen function replays with each new view)."""
    import mitsuba as mi

    import mi_plugins
    from denoise.live.frame_loop import SceneRenderer, sample_image
    from denoise.live.session import Session
    from export import GBUFFER_AOVS
    from renderer.job import split_layers

    mi_plugins.register()
    renderer = SceneRenderer(ROOT / "scenes" / "showcase.txt", 48, 27, freeze=True)
    session = Session(renderer.scene.camera, renderer.light, renderer.pivot_distance(), "svgf", (48, 27))
    for frame in range(3):
        session.apply({"type": "orbit", "dx": 4.0, "dy": 1.0})
        view = session.view()
        renderer.render(view, frame)
        channels = sample_image(renderer.mi_scene, renderer.whitted, renderer.centre_sensor, mi.UInt32(0))
        expected = split_layers(np.stack([np.asarray(c) for c in channels], -1).reshape(27, 48, -1), GBUFFER_AOVS)
        for name in GBUFFER_AOVS:
            assert np.array_equal(renderer.layers[name].view(np.uint32), expected[name].view(np.uint32)), name


def test_frozen_beauty_is_the_path_tracers_bit_for_bit(variant_vectorised_rgb):
    """The frozen beauty passes (with the G-buffers after a camera move, alone while the
    camera stays) replay exactly what tracing the path tracer anew gives, seed by seed."""
    import mitsuba as mi

    import mi_plugins
    from denoise.live.frame_loop import SceneRenderer, sample_image
    from denoise.live.session import Session

    mi_plugins.register()
    renderer = SceneRenderer(ROOT / "scenes" / "showcase.txt", 48, 27, freeze=True)
    session = Session(renderer.scene.camera, renderer.light, renderer.pivot_distance(), "svgf", (48, 27))
    for frame in range(4):  # odd frames keep the view: the beauty pass alone, not with the G-buffers
        if frame % 2 == 0:
            session.apply({"type": "orbit", "dx": 4.0, "dy": 1.0})
        beauty = renderer.render(session.view(), frame)[0].beauty
        channels = sample_image(renderer.mi_scene, renderer.integrator, renderer.jittered_sensor, mi.UInt32(frame))
        expected = np.stack([np.asarray(c) for c in channels[:3]], -1).reshape(27, 48, 3)
        assert np.array_equal(beauty.view(np.uint32), expected.view(np.uint32))
