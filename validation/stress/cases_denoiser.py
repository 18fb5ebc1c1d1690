"""Named stress cases for the denoiser: extreme parameters and bad frames.

Each case builds small frames, runs the denoiser and checks its stated
behaviour: a finite result (equal to a well-conditioned equivalent where one
exists) or one clear error. Used by ``tests/stress`` and ``python -m benchmarks.stress``.
"""
from __future__ import annotations

import contextlib
import io
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import mitsuba as mi
import numpy as np

from core.errors import FrameError, UsageError
from denoise.__main__ import main as denoise_main
from denoise.filters import OutlierParams, TemporalParams, clamp_box
from denoise.methods import METHODS, make
from denoise.pipeline import denoise_folder
from denoise.svgf_common import SVGFParams
from export.frames import FrameData, read_matrices, write_frame
from imaging.image_io import write_exr

H, W = 12, 16


@dataclass(frozen=True)
class DenoiseCase:
    """A denoiser case: ``check`` runs the filters on made-up frames."""
    name: str
    check: Callable[[], tuple[bool, str]]
    fast: bool = True
    kind: str = "denoise"


def _frame(seed: int = 0, beauty=None, normal=None, position=None, ids=None, objects=None):
    rng = np.random.default_rng(seed)
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float64)
    default_position = np.stack([xs / W, np.zeros_like(xs), -ys / H - 2], -1)
    screen = np.array([[W, 0, 0, 0], [0, 0, -H, -2.0 * H], [0, 0, 1, 0], [0, 0, 0, 1.0]])  # x, -z -> pixels
    return FrameData(
        beauty=rng.random((H, W, 3)) if beauty is None else beauty,
        normal=np.tile([0.0, 1.0, 0.0], (H, W, 1)) if normal is None else normal,
        position=default_position if position is None else position,
        depth=np.ones((H, W)), ids=np.zeros((H, W), np.int32) if ids is None else ids,
        object_to_world=[np.eye(4)] if objects is None else objects, world_to_camera=np.eye(4),
        world_to_screen=screen)


def _run(frames, method: str = "atrous", bilateral: dict | None = None, temporal_params: dict | None = None,
         **props) -> list[np.ndarray]:
    """``method`` over ``frames``; ``bilateral`` and ``temporal_params`` are
    parameters of the methods that have them (a 7x7 bilateral window unless given)."""
    cls = METHODS[method]
    given = {"radius": 3, **(bilateral or {}), **(temporal_params or {})}
    keys = {o.key for o in cls.all_options()}
    denoiser = cls(**{k: v for k, v in given.items() if k in keys}, **props)
    return [denoiser.step(f) for f in frames]


def _finite(results) -> tuple[bool, str]:
    ok = all(np.all(np.isfinite(r)) for r in results)
    return ok, "finite" if ok else "NaN or inf in the output"


def _close(a, b, tolerance=1e-4) -> tuple[bool, str]:
    error = float(np.max(np.abs(np.asarray(a) - np.asarray(b)) / np.maximum(np.abs(b), 1e-3)))
    return error <= tolerance, f"largest relative difference {error:.2e}"


def sigma_to_zero(method):
    def check():
        frames = [_frame(1)]
        out = _run(frames, method=method, temporal=False,
                   bilateral=dict(sigma_coord=1e-30, sigma_color=1e-30, sigma_normal=1e-30, sigma_plane=1e-30,
                                  radius=3))
        ok, detail = _finite(out)
        return ok and _close(out[0], frames[0].beauty)[0], detail + "; equals the input (no neighbour has weight)"
    return check


def sigma_huge(method):
    def check():
        frames = [_frame(2)]
        out = _run(frames, method=method, temporal=False,
                   bilateral=dict(sigma_coord=1e30, sigma_color=1e30, sigma_normal=1e30, sigma_plane=1e30, radius=3))
        ok, detail = _finite(out)
        return ok and np.std(out[0]) < np.std(frames[0].beauty), detail + "; smoother than the input"
    return check


def bad_beauty(value):
    def check():
        beauty = _frame(3).beauty.copy()
        beauty[2, 3] = value
        beauty[5, :, 1] = value
        out = _run([_frame(3, beauty=beauty), _frame(4, beauty=beauty)], method="atrous")
        return _finite(out)
    return check


def negative_beauty():
    out = _run([_frame(5, beauty=-_frame(5).beauty)], method="bilateral", temporal=False)
    return _finite(out)


def zero_normals():
    normal = np.zeros((H, W, 3))
    out = _run([_frame(6, normal=normal), _frame(7, normal=normal)], method="atrous")
    return _finite(out)


def identical_positions():
    out = _run([_frame(8, position=np.zeros((H, W, 3)))], method="bilateral", temporal=False)
    return _finite(out)


def all_background():
    ids = -np.ones((H, W), np.int32)
    out = _run([_frame(9, ids=ids), _frame(10, ids=ids)], method="atrous")
    ok, detail = _finite(out)
    # no pixel has history: the second frame is its spatial filtering alone
    alone = _run([_frame(10, ids=ids)], method="atrous", temporal=False)[0]
    return ok and _close(out[1], alone)[0], detail + "; history unused"


def singular_matrix():
    objects = [np.zeros((4, 4))]
    out = _run([_frame(11, objects=objects), _frame(12, objects=objects)], method="atrous")
    return _finite(out)


def matrix_file_error(content: bytes, expect: str):
    def check():
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "matrix_0.mat"
            path.write_bytes(content)
            try:
                read_matrices(path)
            except FrameError as error:
                return expect in str(error) and "\n" not in str(error), str(error)
        return False, "no error"
    return check


def different_sizes():
    small = _frame(13)
    big = replace(_frame(14), beauty=np.zeros((H + 1, W, 3)), normal=np.zeros((H + 1, W, 3)),
                  position=np.zeros((H + 1, W, 3)), ids=np.zeros((H + 1, W), np.int32))
    try:
        _run([small, big], method="atrous")
    except FrameError as error:
        return "frame size changed" in str(error), str(error)
    return False, "no error"


def missing_file():
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for i in (0, 1, 2):
            write_frame(folder, i, _frame(i))
        (folder / "normal_1.exr").unlink()
        try:
            denoise_folder(folder, folder / "out", make("atrous"))
        except FrameError as error:
            return "frame 1 lacks normal_1.exr" in str(error), str(error)
        (folder / "beauty_1.exr").unlink()
    return False, "no error"


def hdr_clamp():
    rng = np.random.default_rng(15)
    # noise of 1 on 1e6: E[x^2] - E[x]^2 in float32 would be pure cancellation (1e12 has a spacing of 65536)
    base = 1e6 * np.ones((H, W, 3)) + rng.normal(0, 1.0, (H, W, 3))
    mean, sigma = clamp_box(mi.TensorXf(base.astype(np.float32)), 3)
    sigma = np.array(sigma)
    ok = np.all(np.isfinite(np.array(mean))) and np.all((sigma > 0.5) & (sigma < 2.0))
    return bool(ok), f"sigma in [{sigma.min():.3g}, {sigma.max():.3g}] for noise 1 at 1e6"


def alpha(value):
    def check():
        frames = [_frame(16), _frame(17)]
        out = _run(frames, method="atrous", temporal_params={"alpha": value})
        ok, detail = _finite(out)
        if value == 1.0:  # only the current frame counts
            alone = _run([frames[1]], method="atrous", temporal=False)[0]
            ok = ok and _close(out[1], alone)[0]
        return ok, detail
    return check


def static_drift(count: int):
    def check():
        frame = _frame(18)
        out = _run([frame] * count, method="atrous")
        ok, detail = _finite(out)
        drift = float(np.max(np.abs(out[-1] - out[len(out) // 2])))
        return ok and drift < 1e-4, f"{detail}; change over the last {count // 2} frames {drift:.2e}"
    return check


def bad_parameter(argv: list[str], expect: str):
    """``python -m denoise`` with an out-of-range parameter: one line, exit 2."""
    def check():

        err = io.StringIO()
        with tempfile.TemporaryDirectory() as tmp, contextlib.redirect_stderr(err):
            code = denoise_main([tmp, str(Path(tmp) / "out")] + argv)
        text = err.getvalue()
        return code == 2 and text.count("\n") == 1 and expect in text, f"exit {code}: {text.strip()}"
    return check


def parameter_type_checks():
    """Each parameter type refuses nonsense when built from Python too (UsageError)."""
    attempts = [lambda: make("atrous", levels=0), lambda: make("atrous", levels=2.5),
                lambda: make("bilateral", radius=65), lambda: make("atrous", sigma_normal=float("nan")),
                lambda: TemporalParams(clamp_radius=0), lambda: make("asvgf", clip_width=float("nan")),
                lambda: make("svgf", normal_exponent=0.0), lambda: make("atrous", outliers=0.0),
                lambda: OutlierParams(radius=0), lambda: SVGFParams(alpha_moments=0),
                lambda: SVGFParams(levels=2, feedback_level=2)]
    refused = 0
    for attempt in attempts:
        try:
            attempt()
        except UsageError:
            refused += 1
    return refused == len(attempts), f"{refused} of {len(attempts)} refused"


def damaged_folder(damage, expect: str):
    """A frame folder damaged by ``damage(folder)``: a FrameError naming the file."""
    def check():
        with tempfile.TemporaryDirectory() as tmp:
            folder = Path(tmp)
            for i in (0, 1):
                write_frame(folder, i, _frame(i))
            damage(folder)
            try:
                denoise_folder(folder, folder / "out", make("atrous"))
            except FrameError as error:
                return expect in str(error) and "\n" not in str(error), str(error)
        return False, "no error"
    return check


def _truncate(name: str):
    def damage(folder: Path):
        path = folder / name
        path.write_bytes(path.read_bytes()[: len(path.read_bytes()) // 3])
    return damage


def _ids(value):
    def damage(folder: Path):
        write_exr(folder / "ID_1.exr", {"": np.full((H, W), value, np.float32)})
    return damage


def _resized(folder: Path):
    big = _frame(3)
    big = replace(big, beauty=np.zeros((H + 2, W, 3)), normal=np.zeros((H + 2, W, 3)),
                  position=np.zeros((H + 2, W, 3)), depth=np.ones((H + 2, W)), ids=np.zeros((H + 2, W), np.int32))
    write_frame(folder, 1, big)


def _one_buffer_resized(folder: Path):
    write_exr(folder / "depth_0.exr", {"": np.ones((H, W + 1), np.float32)})


def method_finite(method: str, **options):
    """A method on frames with NaN, inf, negative values and zero normals: finite output."""
    def check():
        beauty = _frame(20).beauty.copy()
        beauty[1, 1], beauty[2, 2], beauty[3, 3] = np.nan, np.inf, -5.0
        frames = [_frame(20, beauty=beauty, normal=np.zeros((H, W, 3))), _frame(21, beauty=beauty)]
        out = _run(frames, method=method, **options)
        return _finite(out)
    return check


def huge_values(method: str):
    """Finite but huge inputs (beauty 1e30 over a region, a 3e38 pixel, 1e20
    fireflies; positions of 1e30 and -3e38, a normal of length 3e38, an
    albedo of 3e38, demodulated by atrous and svgf): squared differences,
    second moments and lengths would overflow float32 into NaN; the output
    must be finite."""
    def check():
        beauty = _frame(30).beauty.copy()
        beauty[:4, :5] = 1e30
        beauty[6, 7] = 3e38
        beauty[::5, ::3, 0] = 1e20
        position = _frame(30).position.copy()
        position[8, ::4] = 1e30
        position[9, 2] = -3e38
        normal = _frame(30).normal.copy()
        normal[3, 3] = [1e30, 3e38, 0.0]
        albedo = np.full_like(beauty, 0.5)
        albedo[4, 4] = 3e38
        frames = [_frame(30, beauty=beauty, position=position, normal=normal),
                  _frame(31, beauty=beauty, position=position), _frame(32, beauty=beauty)]
        frames = [replace(f, albedo=albedo) for f in frames]
        return _finite(_run(frames, method=method, demodulate=method in ("atrous", "svgf")))
    return check


def albedo_damage(require: bool, expect: str):
    """Albedo for some frames only, or (with ``--demodulate``) for none: a FrameError."""
    def check():
        with tempfile.TemporaryDirectory() as tmp:
            folder = Path(tmp)
            for i in (0, 1):
                frame = _frame(i)
                write_frame(folder, i, replace(frame, albedo=np.full_like(frame.beauty, 0.5)) if i == 0 and not require
                            else frame)
            try:
                denoise_folder(folder, folder / "out", make("atrous"), require_albedo=require)
            except FrameError as error:
                ok = expect in str(error) and "\n" not in str(error) and not (folder / "out").exists()
                return ok, str(error)
        return False, "no error"
    return check


def svgf_static():
    """SVGF on a static noisy scene: the history grows and the output settles."""
    rng = np.random.default_rng(22)
    frames = [_frame(23, beauty=0.5 + 0.2 * rng.random((H, W, 3))) for _ in range(12)]
    out = _run(frames, method="svgf")
    ok, detail = _finite(out)
    change = float(np.max(np.abs(out[-1] - out[-2])))
    return ok and change < 0.05, f"{detail}; last change {change:.3f}"


def denoise_cases() -> list[DenoiseCase]:
    return [
        DenoiseCase("bilateral sigma -> 0", sigma_to_zero("bilateral")),
        DenoiseCase("atrous sigma -> 0", sigma_to_zero("atrous")),
        DenoiseCase("bilateral sigma huge", sigma_huge("bilateral")),
        DenoiseCase("atrous sigma huge", sigma_huge("atrous")),
        DenoiseCase("NaN in beauty", bad_beauty(np.nan)),
        DenoiseCase("inf in beauty", bad_beauty(np.inf)),
        DenoiseCase("-inf in beauty", bad_beauty(-np.inf)),
        DenoiseCase("negative beauty", negative_beauty),
        DenoiseCase("zero-length normals", zero_normals),
        DenoiseCase("identical positions (plane term 0/0)", identical_positions),
        DenoiseCase("all-background frames", all_background),
        DenoiseCase("singular object matrix", singular_matrix),
        DenoiseCase("non-finite matrix file", matrix_file_error(
            np.array([1], "<i4").tobytes() + np.full(48, np.nan, "<f4").tobytes(), "expected finite matrices")),
        DenoiseCase("truncated matrix file", matrix_file_error(np.array([3], "<i4").tobytes(), "expected 324 bytes")),
        DenoiseCase("frames of different sizes", different_sizes),
        DenoiseCase("missing file in a sequence", missing_file),
        DenoiseCase("HDR 1e6 with small noise: stable clamp", hdr_clamp),
        DenoiseCase("alpha -> 0", alpha(1e-6)),
        DenoiseCase("alpha = 1", alpha(1.0)),
        DenoiseCase("100 frames of a static scene", static_drift(100)),
        DenoiseCase("1000 frames of a static scene", static_drift(1000), fast=False),
        DenoiseCase("--levels 31", bad_parameter(["--levels", "31"], "levels must be a whole number")),
        DenoiseCase("--radius -5", bad_parameter(["--method", "bilateral", "--radius", "-5"],
                                                 "radius must be a whole number")),
        DenoiseCase("--alpha 2", bad_parameter(["--alpha", "2"], "alpha")),
        DenoiseCase("--k -1", bad_parameter(["--k", "-1"], "--k must be")),
        DenoiseCase("--sigma-normal 0", bad_parameter(["--sigma-normal", "0"], "--sigma-normal")),
        DenoiseCase("--outliers nan", bad_parameter(["--outliers", "nan"], "--outliers")),
        DenoiseCase("parameter types refuse nonsense", parameter_type_checks),
        DenoiseCase("truncated beauty EXR", damaged_folder(_truncate("beauty_1.exr"), "beauty_1.exr")),
        DenoiseCase("garbage in a normal EXR", damaged_folder(
            lambda f: (f / "normal_0.exr").write_bytes(b"\x76\x2f\x31\x01garbage"), "normal_0.exr")),
        DenoiseCase("object id beyond the matrices", damaged_folder(_ids(5), "object id 5, but matrix_1.mat")),
        DenoiseCase("fractional (averaged) object ids", damaged_folder(_ids(-0.875), "whole numbers")),
        DenoiseCase("frames of different sizes in a folder", damaged_folder(_resized, "but frame 0 has")),
        DenoiseCase("buffers of different sizes in a frame", damaged_folder(_one_buffer_resized, "depth_0.exr")),
        DenoiseCase("svgf on NaN/inf/negative input", method_finite("svgf")),
        DenoiseCase("oidn+temporal on NaN/inf/negative input", method_finite("oidn")),
        DenoiseCase("oidn-guided on NaN/inf/negative input", method_finite("oidn-guided")),
        DenoiseCase("outliers+demod on NaN/inf input", method_finite("atrous", demodulate=True,
                                                                     outliers=_outliers())),
        DenoiseCase("svgf on a static scene settles", svgf_static),
        *[DenoiseCase(f"{method} on huge finite values (1e20 to 3e38)", huge_values(method))
          for method in ("bilateral", "atrous", "svgf", "oidn", "oidn-guided")],
        DenoiseCase("albedo for some frames only", albedo_damage(False, "albedo_1.exr: missing")),
        DenoiseCase("--demodulate without albedo", albedo_damage(True, "(--demodulate, or demod+ in the method's name) "
                                                                 "needs albedo_i.exr")),
        DenoiseCase("a damaged frame after written ones", damaged_folder(
            _truncate("beauty_1.exr"), "the result of frame 0 was written")),
    ]


def _outliers() -> float:
    return 1.0
