"""Rendering an animated sequence into a frame folder, with its ground truth.

    python -m denoise.export SPEC.json OUT_DIR [--frames N] [--size W H] [--spp K]
                             [--reference-spp R] [--whitted] [--data DIR]

The spec is JSON::

    {
      "scene": "showcase",              # a scene name or .txt path (as render.py finds them)
      "frames": 8, "size": [1280, 720],
      "spp": 1, "reference_spp": 256,   # noisy input, converged ground truth
      "bounces": 3, "shadows": true,    # path depth beyond direct light; shadow rays
      "camera": {"orbit": {"center": [0, 1, 0], "degrees": 20},   # about the vertical axis
                 "dolly": 1.5,          # along the view direction
                 "pan": [0.5, 0, 0]},   # a translation
      "objects": {"2": {"translate": [0.8, 0, 0],
                        "rotate": {"axis": [0, 1, 0], "degrees": 45}}}   # about its centre
    }

Every motion is linear in time from frame 0 to the last frame. The noisy
beauty is Mitsuba's path tracer (full Phong model, the background as a light)
at ``spp`` with a new seed per frame (or ``whitted`` with jittered samples);
the G-buffers are the first hit through each pixel centre; the ground truth
goes to ``OUT_DIR_reference/beauty_i.exr``. An interrupted run resumes at the
first frame with a missing file.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

from converters import transforms
from converters.model import Scene, Sphere, Triangle, TriangleMesh

from .frames import BUFFERS, FrameData, camera_matrices, depth_range, write_frame


@dataclasses.dataclass(frozen=True)
class Spec:
    scene: str
    frames: int = 8
    size: tuple[int, int] = (1280, 720)
    spp: int = 1
    reference_spp: int = 256
    bounces: int = 3
    shadows: bool = True
    jitter: bool = True  # sub-pixel sample positions (false: pixel centres, like the G-buffers)
    camera: dict = dataclasses.field(default_factory=dict)
    objects: dict = dataclasses.field(default_factory=dict)

    @staticmethod
    def load(path: Path, **overrides) -> "Spec":
        data = json.loads(Path(path).read_text())
        unknown = set(data) - {f.name for f in dataclasses.fields(Spec)}
        if unknown:
            raise ValueError(f"{path}: unknown keys {', '.join(sorted(unknown))}")
        data.update({k: v for k, v in overrides.items() if v is not None})
        data["size"] = tuple(data.get("size", (1280, 720)))
        return Spec(**data)


def _centre(obj) -> np.ndarray:
    m = obj.to_world
    if isinstance(obj, Sphere):
        local = np.asarray([obj.center], np.float64)
    elif isinstance(obj, Triangle):
        local = np.asarray(obj.vertices, np.float64)
    elif isinstance(obj, TriangleMesh):
        local = obj.positions
    else:
        return np.zeros(3)
    points = local @ m[:3, :3].T + m[:3, 3]
    return (points.min(0) + points.max(0)) / 2


def animate(scene: Scene, spec: Spec, t: float) -> Scene:
    """The scene at time ``t`` in [0, 1]."""
    camera = scene.camera
    center = np.asarray(camera.center, np.float64)
    direction = np.asarray(camera.direction, np.float64)
    motion = spec.camera
    if "orbit" in motion:
        pivot = np.asarray(motion["orbit"].get("center", [0, 0, 0]), np.float64)
        turn = transforms.rotate_y(motion["orbit"]["degrees"] * t)[:3, :3]
        center = pivot + turn @ (center - pivot)
        direction = turn @ direction
    if "dolly" in motion:
        center = center + motion["dolly"] * t * direction / np.linalg.norm(direction)
    if "pan" in motion:
        center = center + np.asarray(motion["pan"], np.float64) * t
    camera = dataclasses.replace(camera, center=tuple(center), direction=tuple(direction))
    objects = list(scene.objects)
    for key, move in spec.objects.items():
        k = int(key)
        if not 0 <= k < len(objects):
            raise ValueError(f"spec: object {k} does not exist (the scene has {len(objects)})")
        obj = objects[k]
        c = _centre(obj)
        m = transforms.translate(np.asarray(move.get("translate", [0, 0, 0]), np.float64) * t)
        if "rotate" in move:
            r = move["rotate"]
            m = m @ transforms.translate(c) @ transforms.rotate(r["axis"], r["degrees"] * t) @ transforms.translate(-c)
        objects[k] = dataclasses.replace(obj, to_world=m @ obj.to_world)
    return dataclasses.replace(scene, camera=camera, objects=objects)


def render_frame(scene: Scene, spec: Spec, index: int, whitted: bool = False) -> tuple[FrameData, np.ndarray]:
    """(the frame's buffers, its ground truth)."""
    import mitsuba as mi

    from converters.to_mitsuba import RenderOptions, load_scene_dict, scene_dict
    from renderer.job import split_layers

    width, height = spec.size
    aovs = ("depth", "normal", "position", "id", "albedo")
    gbuffer = RenderOptions(width=width, height=height, aovs=aovs)
    image = np.array(mi.render(load_scene_dict(scene_dict(scene, gbuffer))), np.float32)
    layers = split_layers(image, aovs)
    noisy = dict(width=width, height=height, jitter=spec.jitter, bounces=spec.bounces, shadows=spec.shadows)
    if not whitted:
        noisy.update(integrator="path", ambient=False)

    def beauty(spp: int, seed: int) -> np.ndarray:
        description = scene_dict(scene, RenderOptions(spp=spp, seed=seed, **noisy))
        return np.array(mi.render(load_scene_dict(description)), np.float32)[..., :3]

    world_to_camera, world_to_screen = camera_matrices(scene.camera, width, height, *depth_range(
        scene.camera, layers["position"][layers["id"] >= 0]))
    frame = FrameData(beauty(spec.spp, 1 + index), layers["normal"], layers["position"], layers["depth"],
                      layers["id"].astype(np.int32), [o.to_world for o in scene.objects], world_to_camera,
                      world_to_screen)
    frame.albedo = layers["albedo"]  # not in the course's layout; OIDN uses it
    return frame, beauty(spec.reference_spp, 1_000_003 + index)


def reference_folder(target: Path) -> Path:
    return target.parent / f"{target.name}_reference"


def frame_done(target: Path, index: int) -> bool:
    files = [target / f"{name}_{index}.exr" for name in BUFFERS] + [target / f"matrix_{index}.mat",
                                                                   reference_folder(target) / f"beauty_{index}.exr"]
    return all(f.exists() for f in files)


def export(spec: Spec, target: Path, data: Path | None = None, whitted: bool = False) -> list[int]:
    """Renders the missing frames of ``spec`` into ``target``; returns their indices."""
    from converters.course_scene import load_scene
    from imaging.image_io import write_exr
    from renderer.cli import course_data_dir, resolve_scene

    scene = load_scene(resolve_scene(spec.scene, course_data_dir(str(data) if data else None)))
    todo = [i for i in range(spec.frames) if not frame_done(target, i)]
    for index in tqdm(todo, desc="frames", unit="frame", delay=1.0, leave=False):
        t = index / max(spec.frames - 1, 1)
        frame, truth = render_frame(animate(scene, spec, t), spec, index, whitted)
        write_frame(target, index, frame)
        write_exr(reference_folder(target) / f"beauty_{index}.exr", {"": truth})
    return todo


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m denoise.export", description=__doc__.split("\n\n")[0])
    parser.add_argument("spec", type=Path, metavar="SPEC.json")
    parser.add_argument("target", type=Path, metavar="OUT_DIR")
    parser.add_argument("--frames", type=int)
    parser.add_argument("--size", type=int, nargs=2, metavar=("W", "H"))
    parser.add_argument("--spp", type=int)
    parser.add_argument("--reference-spp", type=int)
    parser.add_argument("--whitted", action="store_true", help="noisy beauty from whitted (jittered), not path")
    parser.add_argument("--data", type=Path, help="course data folder for course scene names")
    parser.add_argument("--variant")
    args = parser.parse_args(argv)
    from converters.errors import SceneError
    from renderer.cli import UsageError
    from renderer.variants import set_variant

    set_variant(args.variant, quiet=True)
    try:
        spec = Spec.load(args.spec, frames=args.frames, size=tuple(args.size) if args.size else None,
                         spp=args.spp, reference_spp=args.reference_spp)
        done = export(spec, args.target, args.data, args.whitted)
    except (SceneError, UsageError, ValueError, OSError, KeyError) as error:
        print(f"denoise.export: error: {error}", file=sys.stderr)
        return 2
    print(f"{len(done)} frames rendered into {args.target} (ground truth in {reference_folder(args.target)})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
