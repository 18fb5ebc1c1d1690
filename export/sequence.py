"""One sequence of a dataset: what it renders, where, and the seeds of its samples.

Everything in :meth:`Sequence.settings` decides the bytes of its frames. Seeds
come from a hash of the sequence's settings (its key), the frame, the pass and
the batch, so that a frame's bytes do not depend on where or in which order
its tasks ran.
"""
from __future__ import annotations

import dataclasses
import hashlib
from importlib.metadata import version
from pathlib import Path

from .ground_truth import reference_folder, settings_key
from .spec import Spec

#: bump when the way frames are rendered changes (seeds, batching, passes)
EXPORT_FORMAT = 2
DEFAULT_BATCH_SPP = 64
#: Dr.Jit threads per render: its film sums a pixel's samples in an order that
#: follows the thread count, so every pass renders on one thread and
#: parallelism comes from processes (docs/export.md has the measurements).
RENDER_THREADS = 1
#: the most samples per pixel one render accumulates (its film sums in
#: float32); larger passes are split and summed in float64 (docs/export.md)
MAX_SPP_PER_RENDER = 1024


def versions() -> dict:
    """The versions of the packages that decide the bytes."""
    return {name: version(name) for name in ("mitsuba", "drjit", "numpy", "OpenEXR")}


@dataclasses.dataclass(frozen=True)
class Sequence:
    """One sequence of a dataset: what to render and where. Everything in
    :meth:`settings` decides the bytes; it goes into ``sequence.json``."""
    name: str
    spec: Spec
    scene_path: str  # resolved, absolute
    target: str  # the frame folder
    batch_spp: int = DEFAULT_BATCH_SPP
    whitted: bool = False
    variant: str = "llvm_ad_rgb"

    @property
    def reference(self) -> Path:
        return reference_folder(Path(self.target))

    def settings(self) -> dict:
        width, height = self.spec.size
        return {"format": EXPORT_FORMAT, "spec": self.spec.as_json(), "scene_file": self.scene_path,
                "size": [width, height], "spp": self.spec.spp, "reference_spp": self.spec.reference_spp,
                "batch_spp": self.batch_spp, "batches": [spp for _, spp in self.batches()],
                "noisy_integrator": "whitted" if self.whitted else "path", "gbuffer": "whitted AOVs at pixel centres",
                "variant": self.variant, "versions": versions(), "render_threads": RENDER_THREADS,
                "spp_per_render": MAX_SPP_PER_RENDER,
                "seeds": "sha256(key/frame/pass/batch) -> uint31; key = sha256 of this file's other settings",
                "scene_sha256": hashlib.sha256(Path(self.scene_path).read_bytes()).hexdigest()}

    @property
    def key(self) -> str:
        """A hash of the sequence's settings: the root of its seeds."""
        # without the versions, the seeds' description, the scene's path (the same scene moved
        # elsewhere renders the same noise) and its hash, and the samples per render (below the
        # limit a pass is one render, as without it; recorded after the first folders were made)
        return settings_key(self.settings())

    def batches(self) -> list[tuple[str, int]]:
        """(half, spp) of each reference batch: half "a" first, then "b"; each half
        is ``reference_spp / 2`` samples in batches of ``batch_spp`` (the last smaller)."""
        half = self.spec.reference_spp // 2
        sizes = [self.batch_spp] * (half // self.batch_spp) + ([half % self.batch_spp] if half % self.batch_spp else [])
        return [("a", s) for s in sizes] + [("b", s) for s in sizes]


def seed(key: str, frame: int, stream: str, batch: int = 0) -> int:
    """A sampler seed from the sequence key, the frame, the pass and the batch."""
    digest = hashlib.sha256(f"{key}/{frame}/{stream}/{batch}".encode()).digest()
    return int.from_bytes(digest[:4], "little") & 0x7FFFFFFF


def part_seed(seed: int, part: int) -> int:
    """The seed of part ``part`` (1, 2, ...) of a pass split into several renders."""
    digest = hashlib.sha256(f"{seed}/part/{part}".encode()).digest()
    return int.from_bytes(digest[:4], "little") & 0x7FFFFFFF


