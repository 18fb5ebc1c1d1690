"""The stress suite: named cases of stiff and bad input, one protocol for all.

Every case, whatever it stresses, is a :class:`StressCase`: a ``name``,
its speed class (``fast``: CI runs it), its ``kind`` (``render`` or
``error`` for a scene, ``cli``, ``system``, ``surface``, ``denoise``) and
``check()`` returning (passed, what happened).
:func:`validation.stress.suite.all_cases` lists them; ``tests/stress/test_stress.py``
runs the fast ones as one parametrised test and ``python -m benchmarks.stress``
all of them with the fuzzers. The case tables live by surface:

- :mod:`~validation.stress.scene`: the renderer's case type, its base scene and its check;
- :mod:`~validation.stress.cases_renderer`, :mod:`~validation.stress.cases_scale`: stiff scenes, scale;
- :mod:`~validation.stress.cases_inputs`, :mod:`~validation.stress.cases_inputs_denoiser`: bad files and
  command lines;
- :mod:`~validation.stress.cases_system` (with :mod:`~validation.stress.system`): signals, full disks,
  clean logs;
- :mod:`~validation.stress.cases_surfaces`: the live server, the scores, light animations, OIDN, the fit;
- :mod:`~validation.stress.cases_denoiser`: the filters on made-up frames;
- :mod:`~validation.stress.fuzz`, :mod:`~validation.stress.fuzz_commands`: the fuzzers.
"""
from __future__ import annotations

from typing import Protocol


class StressCase(Protocol):
    """What every stress case is (a dataclass of its table's shape)."""
    name: str
    fast: bool
    kind: str

    def check(self) -> tuple[bool, str]: ...
