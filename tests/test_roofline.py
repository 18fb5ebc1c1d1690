"""benchmarks.roofline: its quick run writes the record its page is made of
(run as a command: tests do not import benchmarks)."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_roofline_quick_writes_its_record(tmp_path):
    """The quick roofline: every record size, table and pattern timed, a
    bandwidth and an operation rate, and every kernel of the three methods
    with its bounds; the À-Trous levels found both ways."""
    out = tmp_path / "roofline.json"
    finished = subprocess.run([sys.executable, "-m", "benchmarks.roofline", "--quick", "--json", str(out), "--work",
                               str(tmp_path / "work")], cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert finished.returncode == 0, finished.stderr[-3000:]
    results = json.loads(out.read_text())
    assert {"date", "machine", "load_average_at_start", "load_average_at_end"} <= set(results)
    cells = {(g["record"], g["table_bytes"] > 1 << 20, g["pattern"]) for g in results["micro"]["gathers"]}
    assert len(cells) == 6 * 2 * 2 and all(g["ns_per_gather"] > 0 for g in results["micro"]["gathers"])
    assert results["micro"]["copy"]["gb_per_s"] > 0 and results["micro"]["ops"]["ns_per_op"] > 0
    for key, reads in (("methods", "shifted_loads"), ("gather_methods", "packet_gathers")):
        assert [p["method"] for p in results[key]] == ["atrous+temporal", "svgf", "asvgf"]
        for p in results[key]:
            levels = [k for k in p["kernels"] if k["level"]]
            assert len(levels) >= 2 and all(k[reads] for k in levels), (key, p["method"])
            assert all(k["binds"] in ("gathers", "bandwidth", "operations") for k in p["kernels"])
            assert all(k["ratio"] is None or k["ratio"] > 0 for k in p["kernels"])
    assert "| 8 floats | 32 |" in finished.stdout and "À-Trous levels take" in finished.stdout
