"""The methods ``python -m denoise.train`` trains: each one's trainer, network and defaults, declared once."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from . import mixture_training, training
from .methods import learned_asvgf, learned_mixture


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
