"""One render: a course scene, the course's flags, and the files to write."""
from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

from converters.course_scene import load_scene
from converters.description import scene_dict
from converters.render_flags import DepthOutput, RenderJob
from converters.to_mitsuba import load_scene_dict
from course import CourseRun, root as course_root
from imaging import colour as encoding, image_io
from imaging.filters import centre_sample_3x, downsample_3x
from mi_plugins.aovs import AOV_CHANNELS

from . import bands
from .launches import render_in_launches


@dataclass
class RenderResult:
    job: RenderJob
    layers: dict[str, np.ndarray]  # "" (beauty) and AOV name -> (H, W[, C]) float32
    seconds: dict[str, float] = field(default_factory=dict)  # load, render, write
    stats: dict = field(default_factory=dict)  # with job.stats: rays, AOVs, kernels


def split_layers(image: np.ndarray, aovs: tuple[str, ...], rgb: bool = True) -> dict[str, np.ndarray]:
    """Splits the film's channels (RGB, then AOVs; the AOVs alone where not
    ``rgb``) into named layers."""
    layers = {"": image[..., :3]} if rgb else {}
    channel = 3 if rgb else 0
    for name in aovs:
        count = len(AOV_CHANNELS[name])
        data = image[..., channel:channel + count]
        layers[name] = data[..., 0] if count == 1 else data
        channel += count
    return layers


def render(job: RenderJob) -> RenderResult:
    """Renders ``job`` with the active variant (see :mod:`renderer.variants`).

    Every AOV layer is the first hit of the ray through the output pixel's
    centre, never an average: under ``-jitter`` (or ``--spp``) a second,
    1-sample pass through the pixel centres gives the AOVs, and under
    ``-filter`` each AOV is the centre one of its 3x3 high-resolution
    pixels, whose centre is the output pixel's. Only the beauty is averaged
    (and filtered).
    """
    seconds = {}
    start = time.perf_counter()
    options = job.options()
    description = scene_dict(load_scene(job.scene), options)
    jit = dr.is_jit_v(mi.Float)
    centre_pass = bool(job.aovs) and options.jitter
    stats: dict = {}
    centre = None
    if not jit and bands.worth_it(description):
        # scalar variants: one process per core, each rendering bands of rows
        seconds["load"] = time.perf_counter() - start
        start = time.perf_counter()
        image, stats = bands.render_in_bands(description, mi.variant())
        if centre_pass:
            centre, _ = bands.render_in_bands(centre_description(description), mi.variant())
        seconds["render"] = time.perf_counter() - start
    else:
        scene = load_scene_dict(description)
        seconds["load"] = time.perf_counter() - start
        if job.stats and jit:
            dr.kernel_history()  # clears it
            dr.set_flag(dr.JitFlag.KernelHistory, True)
        start = time.perf_counter()
        # the AOV pass: the scene's camera, shooting through the pixel centres
        centre_sensor = mi.load_dict(centre_description(description)["sensor"]) if centre_pass else None
        if jit:
            image = render_in_launches(scene, options.spp, options.jitter, options.seed)
            if centre_pass:
                centre = render_in_launches(scene, 1, False, sensor=centre_sensor)
        else:
            image = np.array(mi.render(scene), np.float32)
            if centre_pass:
                centre = np.array(mi.render(scene, sensor=centre_sensor), np.float32)
        seconds["render"] = time.perf_counter() - start
        if job.stats:
            stats = scene.integrator().ray_counts()
            if jit:
                dr.set_flag(dr.JitFlag.KernelHistory, False)
                stats["kernels"] = sum(1 for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT)
    if job.stats:
        background = description.get("background")
        stats.update(aovs=list(job.aovs), environment_kind=(
            None if background is None else "cube map" if background["type"] == "course_cubemap" else "colour"))

    layers = split_layers(image, job.aovs)
    if centre is not None:
        layers.update((name, data) for name, data in split_layers(centre, job.aovs).items() if name)
    if job.filter:
        layers = {name: centre_sample_3x(data) if name else downsample_3x(data) for name, data in layers.items()}
    return RenderResult(job, layers, seconds, stats)


def centre_description(description: dict) -> dict:
    """``description`` with one sample per pixel through the pixel centres (the AOV pass)."""
    sensor = dict(description["sensor"], pixel_centers=True)
    sensor["sampler"] = dict(sensor["sampler"], sample_count=1)
    return dict(description, sensor=sensor)


def write_outputs(result: RenderResult) -> list[Path]:
    """Writes every file the job asks for, in parallel (the encoders release the
    GIL); each file appears complete or not at all."""
    start = time.perf_counter()
    job, layers = result.job, result.layers
    tasks = []
    if job.output is not None:
        tasks.append((job.output, lambda: layers[""]))
    if job.normals is not None:
        tasks.append((job.normals, lambda: encoding.normals_to_rgb(layers["normal"])))
    if job.depth is not None:
        depth = job.depth
        tasks.append((depth.path, lambda: encoding.depth_to_grey(layers["depth"], depth.near, depth.far)))
    with ThreadPoolExecutor(max_workers=max(1, len(tasks) + (job.exr is not None))) as pool:
        futures = [pool.submit(_write_image, path, make) for path, make in tasks]
        if job.exr is not None:
            futures.append(pool.submit(image_io.write_exr, job.exr, layers))
        for future in futures:
            future.result()
    result.seconds["write"] = time.perf_counter() - start
    return [path for path, _ in tasks] + ([job.exr] if job.exr is not None else [])


def _write_image(path: Path, make_linear) -> Path:
    linear = make_linear()
    if path.suffix.lower() == ".exr":
        image_io.write_exr(path, {"": linear})
    else:
        image_io.write_image(path, encoding.to_course_8bit(linear))
    return path


def with_outputs_in(job: RenderJob, folder: Path, stem: str, exr: bool) -> RenderJob:
    """``job`` writing ``<stem>.png`` (and ``<stem>.exr``) into ``folder``."""
    return replace(job, output=folder / f"{stem}.png", exr=folder / f"{stem}.exr" if exr else None)


def course_job(run: CourseRun, course: Path | None = None, outputs: Path | None = None) -> RenderJob:
    """A grading line as a job: the input relative to ``course`` (the folder the
    line runs in; default the course's), outputs moved into ``outputs`` if given."""
    flags = run.flags()
    course = course_root() if course is None else course

    def output(name: str) -> Path:
        return Path(outputs) / Path(name).name if outputs is not None else Path(name)

    depth = flags.get("-depth")
    return RenderJob(
        scene=course / flags["-input"][0],
        width=int(flags.get("-size", [800, 800])[0]), height=int(flags.get("-size", [800, 800])[1]),
        output=output(flags["-output"][0]) if "-output" in flags else None,
        normals=output(flags["-normals"][0]) if "-normals" in flags else None,
        depth=DepthOutput(float(depth[0]), float(depth[1]), output(depth[2])) if depth else None,
        bounces=int(flags.get("-bounces", [0])[0]), shadows="-shadows" in flags, jitter="-jitter" in flags,
        filter="-filter" in flags)
