"""python -m denoise.validate: the held-out sequences judged against a converged truth."""
from __future__ import annotations

import numpy as np
import pytest


def test_judge_scores_each_method_per_frame_and_the_table_gives_ratios(exported):
    from denoise.methods import from_name
    from denoise.validate import judge, table

    errors = judge(exported, {"asvgf": lambda: from_name("asvgf"), "raw": lambda: from_name("bilateral")})
    assert set(errors) == {"asvgf", "raw"} and all(len(e) == 2 for e in errors.values())
    assert all(np.isfinite(v) and v > 0 for e in errors.values() for v in e)
    long = {m: e * 3 for m, e in errors.items()}  # six frames: frames >= 4 exist
    lines = table({"seq": long})
    assert lines[0] == "| sequence | asvgf | raw |"
    ratio = np.mean(long["raw"][4:]) / np.mean(long["asvgf"][4:])
    assert f"({ratio:.2f}×)" in lines[2]


@pytest.mark.parametrize("argv, words", [
    (["--reference-spp", "3"], "--reference-spp must be even"),
    (["--methods", "nonsense"], "--methods: unknown nonsense"),
    (["--network", "nowhere.json"], "nowhere.json: no such weights file"),
    (["nowhere_spec.json"], "nowhere_spec.json"),
    (["scenes/sequences/training/network/mirrors_switch.json", "--json",
      "scenes/sequences/training/network/mirrors_switch.json"], "is the input SPEC.json"),
])
def test_bad_arguments_are_one_line_before_any_rendering(argv, words, tmp_path, capsys):
    from denoise.validate import main

    assert main(argv + ["--work", str(tmp_path / "work")]) == 2
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1
    assert not (tmp_path / "work").exists()
