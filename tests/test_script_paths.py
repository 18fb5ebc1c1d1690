"""Every benchmark runs as ``python benchmarks/x.py`` as well as ``python -m benchmarks.x``:
started by its path, a benchmark's folder comes first on ``sys.path``, where
``benchmarks/course.py`` and ``benchmarks/denoise.py`` would shadow the packages."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
#: the benchmark commands: every module of benchmarks/ with a __main__ guard
BENCHMARKS = sorted(p.name for p in (ROOT / "benchmarks").glob("*.py") if 'if __name__ == "__main__"' in p.read_text())


@pytest.mark.parametrize("name", BENCHMARKS)
def test_a_benchmark_runs_by_its_path(name, tmp_path):
    result = subprocess.run([sys.executable, str(ROOT / "benchmarks" / name), "--help"], cwd=tmp_path,
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("usage: python -m benchmarks.")
    assert result.stderr == ""
