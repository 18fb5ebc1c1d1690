"""The ``python -m denoise.live`` command: arguments, then scene, session,
frame loop and server wired together until Ctrl-C (exit 130)."""
from __future__ import annotations

import argparse
import asyncio
import ipaddress
import os
import sys
from pathlib import Path

import mi_plugins
from core.entry import ArgumentParser, run
from core.errors import UsageError
from core.numbers import ascii_int
from core.start_up import NOTHING_WRITTEN
from course import check_data_flag, data_dir, resolve_scene
from denoise.methods.user import add_method_file_option, load_method_files
from renderer.variants import set_variant

from .frame_loop import FrameLoop, SceneRenderer
from .methods import METHOD_NAMES, refresh
from .session import Session

DESCRIPTION = ("watch a scene rendered at 1 spp and denoised, live, in a browser: serves a local page (it prints "
               "the address and opens nothing); drag to orbit, right-drag or Shift+drag to pan, wheel to dolly, "
               "Alt+drag to move the first point light")
DEFAULT_SIZE = (320, 180)
MAX_SIDE = 4096
#: seconds a thread runs before Python hands the GIL to another that waits (Python's default: 0.005)
SWITCH_INTERVAL_S = 0.0002
#: a viewer that stops the loop sees the error; the join is bounded so Ctrl-C stays quick
JOIN_S = 1.0


def is_loopback(host: str) -> bool:
    """``localhost`` or an address of this machine's loopback (127.0.0.0/8, ::1):
    the page has no login, so it is served to this machine alone."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def parser() -> argparse.ArgumentParser:
    result = ArgumentParser(prog="python -m denoise.live", description=DESCRIPTION)
    result.add_argument("scene", help="a scene name (showcase, glossy_shadow, a course scene) or a scene file")
    result.add_argument("--size", type=ascii_int, nargs=2, metavar=("W", "H"), default=DEFAULT_SIZE,
                        help=f"frame size in pixels (default {DEFAULT_SIZE[0]} {DEFAULT_SIZE[1]})")
    result.add_argument("--method", choices=METHOD_NAMES, default="svgf", help="the first method (default svgf)")
    result.add_argument("--variant", help="Mitsuba variant (default: llvm_ad_rgb where usable); a JIT variant")
    result.add_argument("--host", default="127.0.0.1",
                        help="loopback address to listen on (default 127.0.0.1; also localhost, ::1, "
                             "127.x.y.z): the page has no login, so it serves this machine only")
    result.add_argument("--port", type=ascii_int, default=8765, help="port (default 8765; 0: any free one)")
    result.add_argument("--no-freeze", action="store_true", help="trace every frame's render (no dr.freeze)")
    result.add_argument("--data", type=Path, help="course data folder for course scene names")
    add_method_file_option(result)
    return result


def _main(argv: list[str] | None) -> int:
    load_method_files(argv)  # before the parser: a method of one's own is a --method choice and has its sliders
    refresh()
    args = parser().parse_args(argv)
    width, height = args.size
    if not (1 <= width <= MAX_SIDE and 1 <= height <= MAX_SIDE):
        raise UsageError(f"--size: expected 1..{MAX_SIDE} pixels per side, found {width} {height}")
    if not is_loopback(args.host):
        raise UsageError(f"--host: expected a loopback address (127.0.0.1, ::1 or localhost: the page has no "
                         f"login, so it serves this machine only), found {args.host!r}")
    if not 0 <= args.port <= 65535:
        raise UsageError(f"--port: expected 0..65535, found {args.port}")
    check_data_flag(args.data)

    from .server import check_port  # noqa: PLC0415  aiohttp loads on use: --help and the paths without it stay quick

    check_port(args.host, args.port)
    scene_path = resolve_scene(args.scene, data_dir(args.data))
    variant = set_variant(args.variant, jit=True)

    mi_plugins.register()
    from .server import LiveServer, hello_message  # noqa: PLC0415  aiohttp after the checks: --help and errors stay quick

    renderer = SceneRenderer(scene_path, width, height, freeze=not args.no_freeze)
    session = Session(renderer.scene.camera, renderer.light, renderer.pivot_distance(), args.method,
                      (width, height))
    hello = hello_message(scene_path.stem, width, height, variant, renderer.frozen, renderer.light is not None)
    server = LiveServer(session, args.host, args.port, hello)
    loop = FrameLoop(renderer, session, server.publish, variant)
    server.on_shown = loop.shown

    def ready(url: str) -> None:
        loop.start()
        print(f"live: open {url} in a browser (Ctrl-C stops)", flush=True)

    # the frame loop's thread holds the GIL while it traces kernels; the server's thread
    # (sending a frame, reading an acknowledgement) gets it within this, not Python's 5 ms
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    try:
        asyncio.run(server.serve(ready))
    finally:
        loop.stop()
        if loop.is_alive():
            loop.join(JOIN_S)
    if loop.error is not None:
        raise loop.error
    return 0


def main(argv: list[str] | None = None) -> int:
    code = run("python -m denoise.live", lambda: _main(argv), interrupted=NOTHING_WRITTEN)
    if code > 128:  # stopped by a signal: the server writes no files, so a frame in flight and
        sys.stdout.flush()  # Dr.Jit's teardown would only delay the exit
        sys.stderr.flush()
        os._exit(code)
    return code
