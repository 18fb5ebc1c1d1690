"""The base of the methods a trained network steers: its weights file and ablations declared once."""
from __future__ import annotations

from pathlib import Path

from .asvgf import PARAMETER_FILE, fitted
from .base import DenoisingMethod, Option


def weights_option(default: Path) -> Option:
    """The ``--network`` option of the trained methods (one declaration: its default is each one's file)."""
    return Option("network", str(default), "the weights file (JSON, written by python -m denoise.train)", kind=str,
                  group="trained networks", default_text=f"denoise/{default.name}", metavar="FILE")


class TrainedMethod(DenoisingMethod):
    """asvgf's fitted parameters and a network read from ``--network`` (a bad
    file is one line naming it and the training command), the history carried
    from frame to frame. A subclass sets ``weights_file`` and ``ablations``
    (preset name -> weights file); its option, presets, benchmark names and
    data files follow from them. It overrides two hooks: :meth:`load_network`
    and :meth:`denoise`.
    Temporal by nature; it always demodulates by the albedo when the frames have one."""
    temporal_by_nature = True
    demodulates = True
    weights_file: Path | None = None
    ablations: dict[str, Path] = {}

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        if cls.weights_file is not None:
            cls.options = (weights_option(cls.weights_file),)
            cls.presets = {name: {"network": str(path)} for name, path in cls.ablations.items()}
            cls.benchmark = (cls.name,) + tuple(f"{cls.name}-{name}" for name in cls.ablations)
            cls.data_files = (cls.weights_file, *cls.ablations.values(), PARAMETER_FILE)

    def __init__(self, **props):
        super().__init__(**props)
        self.network = self.load_network(self.props["network"])  # a string: "" is no path, not "."
        self.params = fitted()

    @staticmethod
    def load_network(path: Path | str):
        """The hook: the network of weights file ``path``."""
        raise NotImplementedError

    @staticmethod
    def denoise(frame, params, network, history, index, valid):
        """The hook: (this frame filtered, the history for the next) with ``network``."""
        raise NotImplementedError

    def filter(self, arrays, frame, index, valid):
        result, self.history = self.denoise(arrays, self.params, self.network,
                                            self.history if index is not None else None, index, valid)
        return result
