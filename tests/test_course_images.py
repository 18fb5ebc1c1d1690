"""The course's 21 reference images, rendered with its own command lines.

Two bars per image: the course's (at most 0.5 % of pixels more than 2/255
off) and a regression bar: at most twice the bad pixels recorded in
``docs/validation/course_images.json`` (+10), which
``python -m benchmarks.course --record`` rewrites after an intended change
(:mod:`validation.course_images`).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import SCALAR_FALLBACK
from helpers import MAX_BAD_FRACTION, bad_fraction, encode, render_layers

from converters.course_scene import load_scene
from course import CourseRun, course_runs, grading_lines
from imaging.image_io import read_png
from imaging.metrics import bad_pixels
from validation.course_images import RECORD, allowed_bad_pixels, image_counts, render_grading_images

SCENES = ["scene01_plane", "scene02_cube", "scene03_sphere", "scene04_axes", "scene05_bunny_200",
          "scene06_bunny_1k", "scene07_arch"]
FLAGS = {"scene06_bunny_1k": dict(bounces=4), "scene07_arch": dict(bounces=4, shadows=True)}
#: scalar_rgb (no usable LLVM): the rows of this band of each image only
SCALAR_BAND = (396, 404)


def regressions(counts: dict, recorded: dict) -> dict:
    """Images over the course's bar or over twice their recorded count."""
    return {name: (c["bad"], allowed_bad_pixels(recorded[name]["bad"], c["pixels"]))
            for name, c in counts.items() if c["bad"] > allowed_bad_pixels(recorded[name]["bad"], c["pixels"])}


def test_course_reference_images(variant_rgb, course, tmp_path):
    if SCALAR_FALLBACK:
        return check_band_on_scalar(course)
    assert len(grading_lines(course)) == 7, "the course README should list seven a2 command lines"
    render_grading_images(course, tmp_path, variant_rgb)
    counts = image_counts(course, tmp_path)
    assert len(counts) == 21
    recorded = json.loads(RECORD.read_text())["images"]
    assert set(recorded) == set(counts), "run: python -m benchmarks.course --record"
    failing = regressions(counts, recorded)
    assert not failing, (failing, "bad pixels (allowed); if intended: python -m benchmarks.course --record")


def test_regression_bar_catches_a_doubling():
    """The bar bites: twice the recorded count plus the slack fails; the course's 0.5 % stays a ceiling."""
    recorded = {"a.png": {"bad": 100, "pixels": 640_000}, "b.png": {"bad": 0, "pixels": 640_000}}
    assert not regressions({"a.png": {"bad": 210, "pixels": 640_000}, "b.png": {"bad": 10, "pixels": 640_000}},
                           recorded)
    assert set(regressions({"a.png": {"bad": 211, "pixels": 640_000}, "b.png": {"bad": 11, "pixels": 640_000}},
                           recorded)) == {"a.png", "b.png"}
    assert allowed_bad_pixels(10_000, 640_000) == int(MAX_BAD_FRACTION * 640_000)


def test_grading_lines_become_the_jobs_render_py_makes(course, monkeypatch):
    """The course module's jobs (used by the benchmarks and the scalar band check) are
    exactly the jobs ``render.py`` makes of the same command lines, run in the course folder."""
    from renderer.cli import build_parser, jobs_from_args
    from renderer.job import course_job

    monkeypatch.chdir(course)
    runs = course_runs(course)
    assert len(runs) == 7 and {"-shadows", "-depth", "-normals", "-bounces"} <= {w for r in runs for w in r.arguments}
    every_flag = CourseRun("x", ["-size", "320", "180", "-input", "data/x.txt", "-output", "a.png", "-normals", "n.png",
                                 "-depth", "8", "18", "d.png", "-bounces", "4", "-shadows", "-jitter", "-filter"])
    for run in runs + [every_flag]:
        (expected,) = jobs_from_args(build_parser().parse_args(run.arguments))
        job = course_job(run, Path("."))
        assert job == expected, run.arguments
        assert course_job(run, course).scene == course / expected.scene
    with pytest.raises(ValueError, match="-fast"):
        CourseRun("x", ["-input", "x.txt", "-fast"]).flags()


def check_band_on_scalar(course):
    """Every grading line, rows SCALAR_BAND only, through the job's own options, filter and encodings."""
    import mitsuba as mi

    from converters.description import scene_dict
    from converters.render_flags import FILTER_SCALE
    from converters.to_mitsuba import load_scene_dict
    from imaging import colour
    from imaging.filters import downsample_3x
    from renderer.job import course_job, split_layers

    y0, y1 = SCALAR_BAND
    for run in course_runs(course):
        job = course_job(run, course, outputs=course / "sample_out")  # the outputs name the reference images
        options = job.options()
        scale = FILTER_SCALE if job.filter else 1
        description = scene_dict(load_scene(job.scene), options)
        film = description["sensor"]["film"]
        description["sensor"]["film"] = dict(film, crop_offset_x=0, crop_offset_y=y0 * scale,
                                             crop_width=film["width"], crop_height=(y1 - y0) * scale)
        image = np.array(mi.render(load_scene_dict(description)), np.float32)
        layers = split_layers(image, options.aovs)
        if job.filter:
            layers = {name: downsample_3x(data) for name, data in layers.items()}
        outputs = [(job.output, lambda layers=layers: colour.to_course_8bit(layers[""]))]
        if job.normals:
            outputs.append((job.normals,
                            lambda layers=layers: colour.to_course_8bit(colour.normals_to_rgb(layers["normal"]))))
        if job.depth:
            outputs.append((job.depth.path, lambda layers=layers, job=job: colour.to_course_8bit(
                colour.depth_to_grey(layers["depth"], job.depth.near, job.depth.far))))
        for reference, make in outputs:
            expected, ours = read_png(reference)[y0:y1], make()
            if ours.ndim == 2 and expected.ndim == 3:  # grey written as RGB
                ours = np.repeat(ours[..., None], expected.shape[-1], axis=-1)
            assert bad_pixels(ours, expected) <= MAX_BAD_FRACTION * expected.shape[0] * expected.shape[1], \
                reference.name


@pytest.mark.slow
@pytest.mark.parametrize("name", SCENES)
def test_scalar_matches_llvm(course, name):
    """scalar_rgb and llvm_ad_rgb give the same images at 200x200 (and the same AOVs)."""
    from conftest import _set

    scene = load_scene(course / "data" / f"{name}.txt")
    options = dict(width=200, height=200, aovs=("depth", "normal", "id"), **FLAGS.get(name, {}))
    layers = {}
    for variant in ("llvm_ad_rgb", "scalar_rgb"):
        _set(variant)
        layers[variant] = render_layers(scene, **options)
    a, b = layers["llvm_ad_rgb"], layers["scalar_rgb"]
    assert bad_fraction(encode(a[""]), encode(b[""])) <= MAX_BAD_FRACTION
    assert bad_fraction(encode((a["normal"] + 1) / 2), encode((b["normal"] + 1) / 2)) <= MAX_BAD_FRACTION
    assert np.mean(np.abs(a["depth"] - b["depth"]) > 1e-4 * np.maximum(1.0, np.abs(a["depth"]))) <= MAX_BAD_FRACTION
    assert np.mean(a["id"] != b["id"]) <= MAX_BAD_FRACTION
