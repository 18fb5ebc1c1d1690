"""Rendering animated sequences into frame folders, with their ground truth.

    python -m export SPEC.json... OUT [--frames N] [--size W H] [--spp K]
                             [--reference-spp R] [--batch-spp B] [--whitted] [--data DIR]
                             [--variant V] [--force]
                             [--local | --workers N | --scheduler ADDRESS]

The spec is JSON::

    {
      "scene": "showcase",              # a scene name or .txt path (as render.py finds them)
      "frames": 8, "size": [1280, 720],
      "spp": 1, "reference_spp": 256,   # noisy input, converged ground truth (even: two halves)
      "bounces": 3, "shadows": true,    # path depth beyond direct light; shadow rays
      "jitter": true,                   # sub-pixel positions for the noisy input and the truth
      "seed": 0,                        # another value draws another realisation of the noise
      "camera": {"orbit": {"center": [0, 1, 0], "degrees": 20},   # about the vertical axis
                 "dolly": 1.5,          # along the view direction
                 "pan": [0.5, 0, 0]},   # a translation
      "objects": {"2": {"translate": [0.8, 0, 0],
                        "rotate": {"axis": [0, 1, 0], "degrees": 45}}},  # about its centre
      "lights": {"0": {"translate": [2, 0, 0],     # a point light moves
                       "scale": 0.2,               # its colour times 1 -> 0.2
                       "frames": [5, 6]},          # only between frames 5 and 6
                 "1": {"rotate": {"axis": [0, 1, 0], "degrees": 30}}}   # a directional light turns
    }

Objects and lights are named by their position in the scene's ``Group`` and
``Lights`` blocks. Every motion is linear in time from frame 0 to the last
frame; a light's change with ``"frames": [a, b]`` runs between frames a and b. One spec
writes the frame folder ``OUT`` and its ground truth ``OUT_reference``;
several specs (a dataset) write ``OUT/<spec name>`` and
``OUT/<spec name>_reference`` each, and ``OUT/dataset.json`` lists them all.

Per frame the Mitsuba scene is loaded once and every pass rendered from it:
the G-buffers (whitted's AOVs through the pixel centres), the noisy beauty
(Mitsuba's path tracer at ``spp``, or whitted with ``--whitted``) and the
ground truth, which is split into sample batches of ``--batch-spp`` samples,
each with its own seed. The batches form two halves of ``reference_spp / 2``
samples each; ``OUT_reference`` holds their means ``half_a_i.exr`` and
``half_b_i.exr`` and the full reference ``beauty_i.exr`` = (a + b) / 2, so the
reference's own noise is estimated as relMSE(half_a, half_b) / 4.

Seeds come from a hash of the sequence (its spec and settings), the frame, the
pass and the batch, and batches are summed in a fixed order, so a frame's
bytes do not depend on how many workers rendered it or in which order tasks
finished; every render runs on one Dr.Jit thread (whose count would change
the sums' rounding), parallel across processes. The folder records its spec and settings in ``sequence.json``; an
interrupted export resumes with only the missing frames and batches (finished
batches wait in ``OUT_reference/.batches``), and one made with other settings
is refused (``--force`` starts it over).

By default the tasks run on a Dask ``LocalCluster`` with one worker process
per core; ``--scheduler ADDRESS`` runs them on an existing Dask cluster (see
:mod:`export.cluster`), ``--local`` in this process without Dask.

The package's modules, each importing only those above it:
``spec`` (the schema and its checks), ``animation`` (the scene at a time),
``sequence`` (settings, key, batches, seeds), ``tasks`` (a worker's scene
cache, rendering one task), ``files`` (crash-safe writes, staging files,
folder locks), ``store`` (folders: done, claimed, resumed, written),
``recorder`` (results as they come, the manifest), ``cluster`` (Dask),
``runners`` (the whole export), ``cli`` (``python -m export``).
"""
from __future__ import annotations

import importlib

#: the public names, by the module that defines them
_HOMES = {
    "Spec": "spec", "MAX_SPP": "spec", "MAX_SAMPLES_PER_RENDER": "spec",
    "animate": "animation",
    "Sequence": "sequence", "seed": "sequence", "reference_folder": "sequence", "RENDER_THREADS": "sequence",
    "EXPORT_FORMAT": "sequence", "DEFAULT_BATCH_SPP": "sequence",
    "Task": "tasks", "run_task": "tasks", "prepare_process": "tasks", "GBUFFER_AOVS": "tasks",
    "plan": "store", "batch_path": "store", "frame_done": "store", "reference_done": "store",
    "assemble_reference": "store", "claim_folder": "store",
    "Recorder": "recorder",
    "dask_client": "cluster",
    "run_local": "runners", "sequences_for": "runners", "export_sequences": "runners", "export": "runners",
    "sequences_into": "runners",
    "main": "cli",
}
__all__ = sorted(_HOMES)


def __getattr__(name: str):
    # imported on first use: ``python -m export`` must reach its launcher
    # (core.launcher) before NumPy or Mitsuba are imported
    if name not in _HOMES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f".{_HOMES[name]}", __name__), name)
