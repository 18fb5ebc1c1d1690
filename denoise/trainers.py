"""The methods ``python -m denoise.train`` trains: each one's trainer, network and defaults, declared once."""
from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from . import mixture_training, training
from .methods import learned_asvgf, learned_mixture
from .training_state import Settings


@dataclass(frozen=True)
class Trained:
    """A method this command trains: its trainer, its network's maker from a
    parameter vector, its weights files, and the committed network's settings
    (the command without flags makes its weights)."""
    train: Callable
    network_of: Callable
    weights: Path
    ablations: dict[str, Path]
    steps: int
    rate: float
    hidden: int
    hidden_name: str
    batch: int
    crop: tuple[int, int]
    memory: Callable
    max_hidden: int

    def committed_difference(self, out: Path, settings: Settings, sequences: list[str], procedural: int) -> str:
        """Where ``out`` is one of the committed weights files, the first way a run of
        ``settings`` on the spec files ``sequences`` (as the record names them) and
        ``procedural`` generated ones differs from the run its record describes
        ("" where it does not, or ``out`` is another file)."""
        if out.resolve() not in {p.resolve() for p in (self.weights, *self.ablations.values())}:
            return ""
        try:
            data = json.loads(out.read_text())
            record = data["record"]
            made = {"steps": record["steps"], "seed": record["seed"], "rate": record["rate"],
                    "procedural sequences": record["procedural"]["count"], "hidden": len(data["b1"]),
                    "inputs": len(data["features"]), "sequences": sorted(record["training"] + record["held_out"])}
        except Exception:  # noqa: BLE001  a damaged or foreign file: nothing it was made by to compare with
            return ""
        planned = {"steps": settings.steps, "seed": settings.seed, "rate": settings.rate,
                   "procedural sequences": procedural, "hidden": settings.hidden, "inputs": len(settings.features),
                   "sequences": sorted(sequences)}
        for key, value in planned.items():
            if value != made[key]:
                shown = (f"{len(value)} spec files, not its {len(made[key])}" if key == "sequences"
                         else f"{value}, not its {made[key]}")
                return f"{key} {shown}"
        return ""


TRAINED = {
    "learned-asvgf": Trained(training.train, training.network_of, learned_asvgf.WEIGHTS_FILE, learned_asvgf.ABLATIONS,
                             80, 0.02, 12, "hidden units", training.BATCH, training.CROP, training.training_memory,
                             learned_asvgf.MAX_HIDDEN),
    "learned-mixture": Trained(mixture_training.train, learned_mixture.network_of, learned_mixture.WEIGHTS_FILE,
                               learned_mixture.ABLATIONS, mixture_training.STEPS, mixture_training.RATE,
                               mixture_training.CHANNELS, "channels", mixture_training.BATCH,
                               (mixture_training.CROP, mixture_training.CROP), mixture_training.training_memory,
                               learned_mixture.MAX_CHANNELS)}
#: every committed weights file
WEIGHTS_FILES = tuple(p for t in TRAINED.values() for p in (t.weights, *t.ablations.values()))
