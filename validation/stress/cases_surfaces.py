"""Stress cases for the newer commands: the live page's server, the scores,
light animation in specs, OIDN and the fit.

Each case runs the real command or server and states what must happen:

- the live server over a real WebSocket: every bad message (not JSON, an
  unknown type or method, a slider value out of range, NaN, binary data, a
  message past our limit) gets one error message back and changes nothing,
  the stream goes on; a message past aiohttp's own limit closes that socket
  only, and the next viewer is served;
- ``python -m denoise.score`` and ``python -m course.score`` on odd folders
  (empty, missing, a file, NaN or infinite pixels, a gap in the frame
  numbers, a damaged image): one ``PROG: error:`` line and exit 2;
- light animation in an export spec (an index that is not one, out of range,
  a translate for a directional light, frames backwards, a negative, NaN or
  infinite scale): one line, exit 2, nothing written;
- OIDN on NaN, infinite, negative, 1x1 and empty images: a finite image
  (a constant stays within 10 % of itself, as OIDN keeps one at 16x16), or one line;
- ``python -m denoise.fit`` with the largest step size: a finite parameter
  file within the allowed ranges, or one line and no file.

The fuzzers of these commands' argument parsers are in
:mod:`validation.stress.fuzz_commands`.
"""
from __future__ import annotations

import asyncio
import contextlib
import io
import json
import math
import socket
from collections.abc import Callable
from pathlib import Path

import numpy as np

from converters.model import Camera
from validation.stress.cases_system import SystemCase, one_error_line
from validation.stress.system import python, run_command

#: the tiny sequence the cases export (a few seconds)
TINY = {"scene": "lamps", "frames": 3, "size": [24, 16], "spp": 1, "reference_spp": 4, "bounces": 1}


def in_process(main: Callable[[list[str]], int], argv: list) -> tuple[int, str]:
    """``main(argv)`` with stdout dropped: (exit code, stderr)."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = main([str(a) for a in argv])
    return code, err.getvalue()


def refusals(prog: str, main, cases: dict[str, tuple[list, str]]) -> list[str]:
    """Each case's argv must be one ``prog: error:`` line holding its words, exit 2."""
    problems = []
    for name, (argv, expect) in cases.items():
        code, err = in_process(main, argv)
        problems += [f"{name}: {p}: {err.strip()[-200:]!r}" for p in one_error_line(code, err, prog, expect)]
    return problems


# -- the live server ----------------------------------------------------------------
#: message -> words its error must hold
LIVE_BAD = {
    "{type: step}": "not JSON",
    '{"type": "shell", "command": "ls"}': "unknown message type",
    '{"type": "method", "name": "best"}': "unknown method 'best'; known: raw",
    '{"type": "param", "name": "sigma_luminance", "value": 1000}': "expected a number in",
    '{"type": "param", "name": "levels", "value": 2.5}': "whole number",
    '{"type": "orbit", "dx": NaN, "dy": 0}': "NaN is not a JSON number",
    '{"type": "dolly", "amount": 1e309}': "too large for a float",
    '{"type": "ack", "frame": -1}': "expected a number in",
    '{"type": "orbit", "dx": 1, "dy": 0, "dx": 2}': 'key "dx" given twice',
    '{"type": "ack", "frame": ' + "1" * 1500 + "}": "an integer of 1500 digits",
    json.dumps({"type": "step", "pad": "x" * 100_000}): "larger than 2048 bytes",
    "[" * 100_000: "larger than 2048 bytes",
    "[" * 1000 + "]" * 1000: "nested 1000 levels deep",
}


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


async def _talk(problems: list[str]) -> None:
    import aiohttp  # noqa: PLC0415  aiohttp loads on use: the other cases run without it
    from aiohttp.test_utils import TestServer  # noqa: PLC0415  aiohttp loads on use: the other cases run without it

    from denoise.live.server import SOCKET_LIMIT, LiveServer, hello_message  # noqa: PLC0415  as above
    from denoise.live.session import Session  # noqa: PLC0415  as above

    port = _free_port()
    camera = Camera((0.0, 0.0, 5.0), (0.0, 0.0, -1.0), (0.0, 1.0, 0.0), 45.0)
    session = Session(camera, (1.0, 2.0, 3.0), 5.0, "svgf")
    server = LiveServer(session, "127.0.0.1", port, hello_message("s", 32, 18, "llvm_ad_rgb", False, True))
    async with TestServer(server.app, host="127.0.0.1", port=port) as running, aiohttp.ClientSession() as client:
        url, origin = f"ws://127.0.0.1:{running.port}/ws", {"Origin": f"http://127.0.0.1:{port}"}

        async def next_text(ws) -> dict:
            message = await asyncio.wait_for(ws.receive(), 20)
            if message.type != aiohttp.WSMsgType.TEXT:
                raise AssertionError(f"socket closed or not text: {message.type}")
            return json.loads(message.data)

        async with client.ws_connect(url, headers=origin) as ws:
            assert [(await next_text(ws))["type"] for _ in range(2)] == ["hello", "state"]
            for text, expect in LIVE_BAD.items():
                await ws.send_str(text)
                reply = await next_text(ws)
                if reply.get("type") != "error" or expect not in reply.get("message", ""):
                    problems.append(f"{text[:40]!r}: {reply}")
            await ws.send_bytes(b"\x00\x01")
            if (await next_text(ws)).get("type") != "error":
                problems.append("binary data: no error")
            if session.view().method != "svgf" or session.paused:
                problems.append("a refused message changed the session")
            await ws.send_str('{"type": "pause", "paused": true}')  # the stream goes on: good ones still work
            state = await next_text(ws)
            if state.get("type") != "state" or not state.get("paused"):
                problems.append(f"a good message after the bad ones: {state}")
            await ws.send_str("x" * (SOCKET_LIMIT + 10))  # beyond aiohttp's limit: it closes this socket
            closed = await asyncio.wait_for(ws.receive(), 20)
            if closed.type not in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED, aiohttp.WSMsgType.CLOSING):
                problems.append(f"a message past the socket limit: {closed.type}")
        async with client.ws_connect(url, headers=origin) as ws:  # the next viewer is served
            if (await next_text(ws)).get("type") != "hello":
                problems.append("the viewer after a closed socket was not greeted")


def live_messages(folder: Path) -> list[str]:
    problems: list[str] = []
    asyncio.run(_talk(problems))
    return problems



def live_bounds(folder: Path) -> list[str]:
    """What a page cannot make the server do: run ahead of the frames it was
    sent (an acknowledgement far beyond them), or listen beyond loopback."""
    from denoise.live.app import main as live_main  # noqa: PLC0415  the live package loads on use (as above)
    from denoise.live.session import Session, parse_message  # noqa: PLC0415  as above

    problems = []
    session = Session(Camera((0.0, 0.0, 5.0), (0.0, 0.0, -1.0), (0.0, 1.0, 0.0), 45.0), None, 5.0, "svgf")
    session.published = 3
    for frame in (10 ** 9, 2 ** 53, 4):
        session.apply(parse_message(json.dumps({"type": "ack", "frame": frame}), "svgf"))
    if session.acked != 3:
        problems.append(f"acknowledgements beyond frame 3, the last sent, left acked at {session.acked}")
    hosts = {f"--host {host!r}": (["showcase", "--host", host, "--port", 0], "--host: expected a loopback address")
             for host in ("", "0.0.0.0", "::", "10.0.0.1", "example.com")}
    return problems + refusals("python -m denoise.live", live_main, hosts)


# -- the scores ---------------------------------------------------------------------
def _exported(folder: Path) -> tuple[Path, Path]:
    """A tiny exported sequence (frames, reference) and its results by ``python -m denoise``."""
    (folder / "seq.json").write_text(json.dumps(TINY))
    for argv in (python("-m", "export", folder / "seq.json", folder / "seq", "--local"),
                 python("-m", "denoise", folder / "seq", folder / "den")):
        code, _, stderr = run_command(argv)
        if code:
            raise RuntimeError(f"{argv[2]}: {stderr.strip()[-300:]}")
    return folder / "seq", folder / "den"


def denoise_score_odd_folders(folder: Path) -> list[str]:
    from denoise.score import main  # noqa: PLC0415  Dr.Jit loads after the suite chose its variant
    from imaging.image_io import read_exr_rgb, write_exr  # noqa: PLC0415  as above

    frames, results = _exported(folder)
    reference = Path(f"{frames}_reference")
    (folder / "empty").mkdir()
    odd = {"nan": folder / "nan", "inf": folder / "inf", "gap": folder / "gap"}
    for name, path in odd.items():
        path.mkdir()
        for i in range(3):
            if name == "gap" and i == 1:
                continue
            image = read_exr_rgb(reference / f"beauty_{i}.exr")
            if i == 2 and name in ("nan", "inf"):
                image[0, 0, 0] = np.nan if name == "nan" else -np.inf
            write_exr(path / f"beauty_{i}.exr", {"": image})
    (folder / "file.exr").write_bytes(b"not a folder")
    return refusals("python -m denoise.score", main, {
        "empty results": ([folder / "empty", "--reference", reference], "result_0.exr: missing"),
        "no reference folder": ([results, "--reference", folder / "none"], "not a folder"),
        "empty reference": ([results, "--reference", folder / "empty"], "no beauty_<i>.exr frames"),
        "reference is a file": ([results, "--reference", folder / "file.exr"], "not a folder"),
        "NaN in the truth": ([results, "--reference", odd["nan"]], "1 pixels NaN and 0 infinite"),
        "inf in the truth": ([results, "--reference", odd["inf"]], "0 pixels NaN and 1 infinite"),
        "gap in the frames": ([results, "--reference", odd["gap"], "--frames", frames], "without beauty_1.exr"),
        "frames missing": ([results, "--reference", reference, "--frames", folder / "empty"], "empty"),
    })


def course_score_odd_folders(folder: Path) -> list[str]:
    from course.score import main  # noqa: PLC0415  loads on use, as the command does
    from imaging.image_io import write_image  # noqa: PLC0415  as above

    rng = np.random.default_rng(5)
    for name in ("ref", "mine", "small"):
        (folder / name).mkdir()
    write_image(folder / "ref" / "a01.png", rng.integers(0, 256, (20, 30, 3), np.uint8))
    write_image(folder / "small" / "a01.png", rng.integers(0, 256, (10, 30, 3), np.uint8))
    (folder / "huge").mkdir()  # past the 89 million pixels where Pillow warns on stderr
    write_image(folder / "huge" / "a01.png", np.zeros((9500, 9500, 3), np.uint8))
    (folder / "damaged").mkdir()
    (folder / "damaged" / "a01.png").write_bytes(b"\x89PNG\r\n\x1a\n broken")
    (folder / "empty").mkdir()
    (folder / "file").write_text("x")
    problems = refusals("python -m course.score", main, {
        "DIR missing": ([folder / "none", "--reference", folder / "ref"], "not a folder"),
        "DIR a file": ([folder / "file", "--reference", folder / "ref"], "not a folder"),
        "reference missing": ([folder / "mine", "--reference", folder / "none"], "not a folder"),
        "reference empty": ([folder / "mine", "--reference", folder / "empty"], "no PNG images"),
        "an image of another size": ([folder / "small", "--reference", folder / "ref"], "10 pixels"),
        "an image of 90 million pixels": ([folder / "huge", "--reference", folder / "ref"], "9500x9500 pixels"),
        "a damaged image": ([folder / "damaged", "--reference", folder / "ref"], "not a readable PNG"),
        "report not Markdown": ([folder / "mine", "--reference", folder / "ref", "--report", folder / "r.png"],
                                "--report writes Markdown"),
    })
    code, err = in_process(main, [folder / "mine", "--reference", folder / "ref", "--report", folder / "r.md"])
    if code != 1 or err:  # an empty DIR is no error: every image is missing, which fails the bar
        problems.append(f"empty DIR: exit {code}, stderr {err.strip()[-200:]!r}")
    return problems


# -- light animation in specs --------------------------------------------------------
LIGHT_SPECS = {  # (scene, lights) -> the words of the error; lamps has three point lights, transforms'
    # first light is a directional one
    ("lamps", '{"x": {"scale": 0.5}}'): "lights.x: expected a light index",
    ("lamps", '{"-1": {"scale": 0.5}}'): "lights.-1: expected a light index",
    ("lamps", '{"1.5": {"scale": 0.5}}'): "lights.1.5: expected a light index",
    ("lamps", '{"99999999999999999999999": {"scale": 0.5}}'): "expected a light index",
    ("lamps", '{"3": {"scale": 0.5}}'): "light 3 does not exist (the scene has 3: 0..2)",
    ("transforms", '{"0": {"translate": [1, 0, 0]}}'): "light 0 is a directional light",
    ("lamps", '{"0": {"rotate": {"axis": [0, 1, 0], "degrees": 9}}}'): "light 0 is a point light",
    ("lamps", '{"0": {"scale": 0.5, "frames": [2, 1]}}'): "expected a first frame before the last",
    ("lamps", '{"0": {"scale": 0.5, "frames": [0, 3]}}'): "lights.0.frames[1]: expected 0..2, found 3",
    ("lamps", '{"0": {"scale": -1}}'): "expected a factor >= 0",
    ("lamps", '{"0": {"scale": NaN}}'): "NaN is not a JSON number",
    ("lamps", '{"0": {"scale": Infinity}}'): "Infinity is not a JSON number",
    ("lamps", '{"0": {"translate": [1, NaN, 0]}}'): "NaN is not a JSON number",
}


def light_animation(folder: Path) -> list[str]:
    from export import main  # noqa: PLC0415  Dr.Jit loads after the suite chose its variant

    cases = {}
    for k, ((scene, lights), expect) in enumerate(LIGHT_SPECS.items()):
        spec = folder / f"light{k}.json"
        spec.write_text(json.dumps(dict(TINY, scene=scene))[:-1] + f', "lights": {lights}}}')
        cases[f"{scene} {lights}"] = ([spec, folder / f"out{k}", "--local"], expect)
    problems = refusals("python -m export", main, cases)
    return problems + [f"{p.name} written" for p in folder.glob("out*")]


# -- OIDN ----------------------------------------------------------------------------
def oidn_odd_inputs(folder: Path) -> list[str]:
    from core.entry import run  # noqa: PLC0415  OIDN loads on use
    from denoise.methods.oidn import OIDN  # noqa: PLC0415  as above

    oidn, problems = OIDN(), []
    rng = np.random.default_rng(2)
    for value in (math.nan, math.inf, -math.inf, -1e30, 3e38):
        image = rng.random((16, 16, 3)).astype(np.float32)
        image[3, 3] = value
        for aux in ((), (np.where(np.isfinite(image), image, value), image)):
            out = oidn(image, *aux)
            if not np.isfinite(out).all():
                problems.append(f"a pixel {value}{' with albedo and normals' if aux else ''}: the output is "
                                "not finite")
    for shape in ((1, 1), (2, 2), (1, 40), (40, 1)):
        out = oidn(np.full(shape + (3,), 0.5, np.float32))
        if out.shape != shape + (3,) or not np.allclose(out, 0.5, rtol=0.1):
            problems.append(f"a constant {shape[1]}x{shape[0]} image: {out.shape}, {out.min():.3f}..{out.max():.3f}")
    for shape in ((0, 4, 3), (4, 0, 3), (4, 4), (4, 4, 1)):
        err = io.StringIO()
        with contextlib.redirect_stderr(err):
            code = run("oidn", lambda shape=shape: oidn(np.zeros(shape, np.float32)))
        problems += [f"shape {shape}: {p}" for p in one_error_line(code, err.getvalue(), "oidn", "OIDN needs")]
    return problems


# -- the fit ---------------------------------------------------------------------------
def fit_largest_step(folder: Path) -> list[str]:
    (folder / "seq.json").write_text(json.dumps(TINY))
    out = folder / "p.json"
    code, _, stderr = run_command(python("-m", "denoise.fit", folder / "seq.json", "--work", folder / "work",
                                         "--steps", 4, "--rate", 10, "--switch-frame", 1, "--quiet", "--out", out))
    if code == 2:
        problems = one_error_line(code, stderr, "python -m denoise.fit", "")
        return problems + (["a parameter file written"] if out.exists() else [])
    if code or stderr:
        return [f"exit {code}: {stderr.strip()[-300:]!r}"]
    from core.errors import UsageError  # noqa: PLC0415  Dr.Jit loads after the suite chose its variant
    from denoise.methods import make  # noqa: PLC0415  as above

    values = json.loads(out.read_text())["parameters"]
    problems = [f"{k} = {v}" for k, v in values.items() if not math.isfinite(v)]
    try:
        make("asvgf", **values)  # each within the range asvgf declares
    except UsageError as error:
        problems.append(str(error))
    code, _, stderr = run_command(python("-m", "denoise.fit", folder / "seq.json", "--work", folder / "work",
                                         "--rate", "1e9", "--out", folder / "q.json"))
    problems += [f"--rate 1e9: {p}" for p in one_error_line(code, stderr, "python -m denoise.fit", "--rate")]
    return problems


def surface_cases() -> list[SystemCase]:
    return [
        SystemCase("live server: bad messages over a real socket", live_messages, fast=True, kind="surface"),
        SystemCase("live server: no frames ahead of the page, loopback only", live_bounds, fast=True, kind="surface"),
        SystemCase("denoise.score on odd folders", denoise_score_odd_folders, fast=True, kind="surface"),
        SystemCase("course.score on odd folders", course_score_odd_folders, fast=True, kind="surface"),
        SystemCase("light animation: bad specs are one line", light_animation, fast=True, kind="surface"),
        SystemCase("oidn on NaN, inf, negative, 1x1 and empty images", oidn_odd_inputs, fast=True, kind="surface"),
        SystemCase("denoise.fit at the largest step size", fit_largest_step, kind="surface"),
    ]
