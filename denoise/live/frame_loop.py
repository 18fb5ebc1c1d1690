"""Frames for the live page: render at 1 spp with G-buffers, denoise, encode.

:class:`SceneRenderer` renders a frame as the export does
(:func:`export.loaded_frame`): whitted's AOVs (:data:`GBUFFER_AOVS`)
through the pixel centres, then Mitsuba's path tracer at 1 spp through
jittered positions, with the camera of the moment (``live_camera``, whose
basis is opaque data) and the first point light where the viewer put it.

After a camera move, one frozen Dr.Jit function (``dr.freeze``) computes the
G-buffers and the beauty in one kernel (:func:`render_both`); while the camera
stays, another computes the beauty alone (:func:`render_beauty`). After their
first frame they replay the recorded kernel with the new camera, light and seed
instead of tracing again; each replay walks the scene (its inputs), so a frame
pays one walk, and the scene holds the path tracer (a C++ integrator), not
whitted (a Python one, slower to walk), which is kept aside for its per-shape
ids. The G-buffers are whitted's AOVs alone (:func:`gbuffer_values`, the same
function as whitted's ``sample``), not its shading, which they would discard.
The denoiser works on NumPy frames (:class:`denoise.pipeline.Denoiser`
checks values on the host), which a frozen function cannot replay.

:class:`FrameLoop` runs in its own thread: it waits for the viewer (paused,
or two frames not yet shown), renders the session's view, denoises it with
the chosen method and hands the encoded frame to ``publish``.
"""
from __future__ import annotations

import io
import json
import struct
import threading
import time
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np
from PIL import Image

from converters.course_scene import load_scene
from converters.description import RenderOptions, scene_dict
from converters.model import PointLight
from converters.scene_variants import with_path_tracer, without_ambient
from converters.to_mitsuba import load_scene_dict
from export import GBUFFER_AOVS
from export.frames import FrameData, camera_matrices, depth_range
from imaging.colour import tone_map
from mi_plugins.aovs import AOV_CHANNELS
from mi_plugins.first_hit import finite, first_hit_values

from .methods import RAW, method_for, retuned
from .session import Session, View

#: frames sent but not yet shown by the page, at most
IN_FLIGHT = 2
#: path depth beyond direct light, as the export's specs (``bounces``)
BOUNCES = 3
JPEG_QUALITY = 85


class SceneRenderer:
    """One course scene loaded once, rendered frame after frame from any view."""

    def __init__(self, scene_path: Path, width: int, height: int, freeze: bool = True):
        from . import camera  # noqa: PLC0415  it derives from the active variant's course_camera: only after set_variant

        camera.register()
        self.scene_path, self.width, self.height, self.frozen = scene_path, width, height, freeze
        self.scene = load_scene(scene_path)
        description = scene_dict(self.scene, RenderOptions(width=width, height=height, aovs=GBUFFER_AOVS))
        description["sensor"]["type"] = "live_camera"
        description["sensor_jittered"] = dict(description["sensor"], pixel_centers=False)
        noisy = scene_dict(self.scene, RenderOptions(width=width, height=height, jitter=True, bounces=BOUNCES,
                                                     shadows=True))
        # whitted analyses the scene (its per-shape ids); the scene holds the path tracer, which renders
        # the beauty: a frozen pass walks its inputs every frame, and a Python integrator costs more to walk
        self.whitted = mi.load_dict(description["integrator"])
        description["integrator"] = without_ambient(with_path_tracer(noisy))["integrator"]
        self.mi_scene = load_scene_dict(description)
        self.integrator = self.mi_scene.integrator()
        self.params = mi.traverse(self.mi_scene)
        sensors = {s.id(): s for s in self.mi_scene.sensors()}
        self.centre_sensor, self.jittered_sensor = sensors["sensor"], sensors["sensor_jittered"]
        lights = [k for k, light in enumerate(self.scene.lights) if isinstance(light, PointLight)]
        self.light_key = f"light_{lights[0]}.position" if lights else None
        self.light = self.scene.lights[lights[0]].position if lights else None
        # whitted's per-shape object ids (what whitted.render analyses before sampling), an input of the G-buffer pass
        self.object_ids = self.whitted.analyse(self.mi_scene).tables["ids"]
        self.last_camera, self.layers, self.ids, self.matrices = None, None, None, None
        self.render_beauty = dr.freeze(render_beauty) if freeze else render_beauty
        self.render_both = dr.freeze(render_both) if freeze else render_both

    def at_size(self, width: int, height: int) -> SceneRenderer:
        """This renderer, or the same scene's at another frame size (loaded anew)."""
        if (width, height) == (self.width, self.height):
            return self
        return SceneRenderer(self.scene_path, width, height, self.frozen)

    def pivot_distance(self) -> float:
        """Distance from the camera to the centre of the scene's bounding box,
        along the view (the orbit's pivot); 1 where that is behind the camera."""
        box = self.mi_scene.bbox()
        centre = np.asarray(box.center(), np.float64)
        camera = self.scene.camera
        direction = np.asarray(camera.direction, np.float64)
        along = float((centre - np.asarray(camera.center)) @ direction / np.linalg.norm(direction))
        return along if np.isfinite(along) and along > 0 else 1.0

    def set_view(self, view: View) -> None:
        camera = view.camera
        for name in ("sensor", "sensor_jittered"):
            self.params[f"{name}.origin"] = mi.ScalarPoint3f(camera.center)
            self.params[f"{name}.direction"] = mi.ScalarVector3f(camera.direction)
            self.params[f"{name}.up"] = mi.ScalarVector3f(camera.up)
        if self.light_key is not None and view.light is not None:
            self.params[self.light_key] = mi.ScalarPoint3f(view.light)
        self.params.update()

    def render(self, view: View, seed: int) -> tuple[FrameData, dict[str, float]]:
        """The frame of ``view`` (beauty with sampler seed ``seed``) and the seconds
        of each stage: "render" (the kernel, with the G-buffers after a camera move)
        and "gbuffers" (the G-buffer layers and the camera's matrices made ready on
        the host, after a camera move). While the camera stays where it was, the
        G-buffers are those of the last frame."""
        start = time.perf_counter()
        self.set_view(view)
        seed = mi.UInt32(seed)
        if view.camera != self.last_camera:  # the G-buffers depend on the camera alone
            gbuffers, pixels = self.render_both(self.mi_scene, self.centre_sensor, self.jittered_sensor,
                                                self.object_ids, seed)
            beauty = to_image(pixels, self.width, self.height)
            rendered = time.perf_counter()
            images = {name: to_image(layer, self.width, self.height) for name, layer in gbuffers.items()}
            self.layers = {name: image[..., 0] if image.shape[-1] == 1 else image for name, image in images.items()}
            self.ids = self.layers["id"].astype(np.int32)
            hit = (self.ids >= 0).ravel()  # np.compress: several times quicker than a 2-D boolean index
            near, far = depth_range(view.camera, np.compress(hit, self.layers["position"].reshape(-1, 3), axis=0))
            self.matrices = camera_matrices(view.camera, self.width, self.height, near, far)
            self.last_camera = view.camera
        else:
            beauty = to_image(self.render_beauty(self.mi_scene, self.jittered_sensor, seed), self.width, self.height)
            rendered = time.perf_counter()
        layers = self.layers
        frame = FrameData(beauty, layers["normal"], layers["position"], layers["depth"], self.ids,
                          [o.to_world for o in self.scene.objects], *self.matrices, albedo=layers["albedo"])
        return frame, {"render": rendered - start, "gbuffers": time.perf_counter() - rendered}


def camera_rays(sensor, seed) -> tuple:
    """(ray, weight, sampler) of one sample per pixel of ``sensor``'s film, in
    row order; the position in its pixel comes from the sampler seeded with
    ``seed`` (``live_camera`` with ``pixel_centers`` shoots through the centre)."""
    width, height = (int(v) for v in sensor.film().size())
    index = dr.arange(mi.UInt32, width * height)
    y = index // width
    x = index - y * width
    sampler = sensor.sampler().clone()
    sampler.seed(seed, width * height)
    position = (mi.Point2f(mi.Float(x), mi.Float(y)) + sampler.next_2d()) / mi.ScalarPoint2f(width, height)
    ray, weight = sensor.sample_ray(0.0, 0.5, position, mi.Point2f(0.5))
    return ray, weight, sampler


def sample_image(scene, integrator, sensor, seed) -> list:
    """One sample per pixel of ``sensor``'s film by ``integrator``: the
    channels RGB, then the integrator's AOVs, each a flat array in row order.
    Launched without ``mi.render``: its binding swaps the process's SIGINT
    handler while it runs (and keeps its own after a nested render, as
    ``whitted``'s is), so Ctrl-C would reach neither Python nor the server."""
    with dr.suspend_grad():
        ray, weight, sampler = camera_rays(sensor, seed)
        spectrum, _, aovs = integrator.sample(scene, sampler, ray, None, mi.Bool(True))
        spectrum = spectrum * weight
        return [spectrum.x, spectrum.y, spectrum.z] + list(aovs)


def render_beauty(scene, sensor, seed) -> mi.Float:
    """The noisy 1-spp beauty by the scene's integrator, RGB per pixel as consecutive floats
    (a function that is frozen: the pass of a frame whose camera did not move)."""
    return interleaved(sample_image(scene, scene.integrator(), sensor, seed)[:3])


def gbuffer_values(scene, sensor, object_ids: mi.TensorXf) -> list:
    """whitted's AOVs :data:`GBUFFER_AOVS` through the pixel centres of ``sensor``:
    exactly what ``whitted``'s ``sample`` returns as its AOVs (the same function,
    :func:`mi_plugins.first_hit.first_hit_values`), without its shading, which the
    G-buffers do not use. ``object_ids`` is whitted's per-shape id table, an input
    so that a frozen function may read it."""
    with dr.suspend_grad():
        ray, _, _ = camera_rays(sensor, mi.UInt32(0))
        active = dr.full(mi.Bool, True, dr.width(ray.d.x))
        si = scene.ray_intersect(mi.Ray3f(ray), active)
        values = first_hit_values(GBUFFER_AOVS, si, active,
                                  lambda: object_ids.array[dr.reinterpret_array(mi.UInt32, si.shape)])
        return [finite(v) for v in values]


def render_both(scene, centre_sensor, jittered_sensor, object_ids: mi.TensorXf, seed) -> tuple[dict, mi.Float]:
    """(G-buffers, beauty): each G-buffer layer by name (:data:`GBUFFER_AOVS`) and the
    beauty an array of its own, a pixel's channels consecutive (:func:`gbuffer_values`,
    :func:`render_beauty`), all computed by one kernel (a function that is frozen: one
    walk of the scene and one launch a frame, not two; each layer NumPy reads as one
    contiguous view, which the denoiser checks and uploads as it is)."""
    values = iter(gbuffer_values(scene, centre_sensor, object_ids))
    gbuffers = {name: dr.ravel(mi.ArrayXf(*[next(values) for _ in AOV_CHANNELS[name]])) for name in GBUFFER_AOVS}
    beauty = dr.ravel(mi.ArrayXf(*sample_image(scene, scene.integrator(), jittered_sensor, seed)[:3]))
    dr.eval(gbuffers, beauty)
    return gbuffers, beauty


def interleaved(channels: list) -> mi.Float:
    """Flat channels as one array, a pixel's channels consecutive: the kernel
    that computes them writes the image as NumPy reads it (no copy per channel)."""
    pixels = dr.ravel(mi.ArrayXf(*channels))
    dr.eval(pixels)
    return pixels


def to_image(pixels: mi.Float, width: int, height: int) -> np.ndarray:
    """An :func:`interleaved` image as (H, W, C) float32 (a view of its memory)."""
    return np.asarray(pixels).reshape(height, width, -1)


#: the tone map's input range: Reinhard's extended operator with white 4 reaches 1 (code 255) at 4
TONE_MAP_WHITE = 4.0
#: table entries over [0, white]: steps of 6e-5, a fifth of an 8-bit code where sRGB is steepest
TONE_MAP_ENTRIES = 1 << 16


class JPEGEncoder:
    """HDR frames as one JPEG, tone-mapped as the previews are (:func:`imaging.colour.tone_map`)
    through a table of that function, built once (a frame is then one lookup)."""

    def __init__(self, quality: int = JPEG_QUALITY):
        self.quality = quality
        self.table = tone_map(np.linspace(0.0, TONE_MAP_WHITE, TONE_MAP_ENTRIES, dtype=np.float64))
        self.scale = np.float32((TONE_MAP_ENTRIES - 1) / TONE_MAP_WHITE)

    def codes(self, image: np.ndarray) -> np.ndarray:
        """``image`` (H, W, 3) tone-mapped to 8-bit codes."""
        index = np.multiply(image, self.scale, dtype=np.float32)
        index += np.float32(0.5)
        np.fmax(index, 0.0, out=index)  # fmax: NaN becomes 0 (code 0), in the same pass
        np.minimum(index, TONE_MAP_ENTRIES - 1, out=index)  # +inf the table's last entry
        return np.take(self.table, index.astype(np.uint16))

    def __call__(self, *images: np.ndarray) -> bytes:
        """The images (each H x W x 3) side by side in one JPEG, each in a column
        :func:`slot_width` wide (its block columns its own: no block straddles two)."""
        height, width = images[0].shape[:2]
        slot = slot_width(width)
        codes = np.zeros((height, slot * len(images), 3), np.uint8)
        for k, image in enumerate(images):
            column = codes[:, k * slot:(k + 1) * slot]
            column[:, :width] = self.codes(image)
            column[:, width:] = column[:, width - 1:width]  # the last column repeated: no edge in a block
        buffer = io.BytesIO()
        Image.fromarray(codes).save(buffer, "JPEG", quality=self.quality, subsampling=0)  # 4:4:4
        return buffer.getvalue()


def slot_width(width: int) -> int:
    """An image's column in a frame's JPEG: its width rounded up to JPEG's 8-pixel blocks,
    so that no block holds both images (the colour is not subsampled, which a decoder's
    upsampling would smear across the seam)."""
    return -(-width // 8) * 8


def packet(header: dict, image: bytes) -> bytes:
    """One frame for the page: a little-endian uint32 header length, the JSON header,
    then one JPEG holding the raw and the denoised image side by side (the header's
    ``images``: 2; 1 where the method is raw), each :func:`slot_width` wide: the
    page decodes one image a frame, not two."""
    text = json.dumps(dict(header, image_bytes=len(image), slot=slot_width(header["width"]))).encode()
    return struct.pack("<I", len(text)) + text + image


class FrameLoop(threading.Thread):
    """Renders, denoises and publishes frames while :meth:`stop` is not called."""

    def __init__(self, renderer: SceneRenderer, session: Session, publish, variant: str):
        super().__init__(name="live frame loop", daemon=True)
        self.renderer, self.session, self.publish, self.variant = renderer, session, publish, variant
        self.stopped = False
        self.frame = 0
        self.sent_at: dict[int, float] = {}
        self.transport_ms = None
        self.error: BaseException | None = None
        self.encode = JPEGEncoder()

    def stop(self) -> None:
        with self.session.changed:
            self.stopped = True
            self.session.changed.notify_all()

    def shown(self, frame: int) -> None:
        """The page has shown ``frame``: its transport time is known."""
        with self.session.changed:
            sent = self.sent_at.pop(frame, None)
            if sent is not None:
                self.transport_ms = (time.perf_counter() - sent) * 1000
            for old in [k for k in self.sent_at if k < frame]:
                del self.sent_at[old]

    def _ready(self) -> bool:
        session = self.session
        if self.stopped:
            return True
        if not session.connected:
            return False
        if session.acked is None:
            session.acked = self.frame - 1
        if self.frame - 1 - session.acked >= IN_FLIGHT:
            return False
        return not session.paused or session.steps > 0

    def run(self) -> None:
        try:
            self._run()
        except BaseException as error:  # the server reports it and stops
            self.error = error
            self.publish(None)

    def _run(self) -> None:
        denoiser, method, values, resets = None, None, None, None
        while True:
            with self.session.changed:
                while not self._ready():
                    self.session.changed.wait(0.5)
                if self.stopped:
                    return
                if self.session.paused:
                    self.session.steps -= 1
                view, reset = self.session.view(), self.session.history_resets
            if view.size != (self.renderer.width, self.renderer.height):
                self.renderer, method = self.renderer.at_size(*view.size), None  # a new size: a new denoiser
            frame, seconds = self.renderer.render(view, self.frame)
            start = time.perf_counter()
            if view.method != method or reset != resets:
                denoiser = method_for(view.method, self.renderer.width, dict(view.values))
            elif view.values != values and denoiser is not None:
                denoiser = retuned(denoiser, view.method, self.renderer.width, dict(view.values))
            method, values, resets = view.method, view.values, reset
            result = denoiser.step(frame) if denoiser is not None else frame.beauty
            denoised = time.perf_counter()
            images = (frame.beauty,) if view.method == RAW else (frame.beauty, result)
            jpeg = self.encode(*images)
            encoded = time.perf_counter()
            ms = {"render": seconds["render"] * 1000, "gbuffers": seconds["gbuffers"] * 1000,
                  "denoise": (denoised - start) * 1000, "encode": (encoded - denoised) * 1000,
                  "transport": self.transport_ms}
            header = {"type": "frame", "frame": self.frame, "width": self.renderer.width,
                      "height": self.renderer.height, "images": len(images), "method": view.method,
                      "variant": self.variant,
                      "frozen": self.renderer.frozen, "ms": {k: (None if v is None else round(v, 2))
                                                             for k, v in ms.items()}}
            with self.session.changed:
                self.sent_at[self.frame] = time.perf_counter()
                self.session.published = self.frame
            self.publish(packet(header, jpeg))
            self.frame += 1

