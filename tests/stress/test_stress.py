"""The stress suite's CI subset: every named case, and the fuzzer with 1,000+ inputs."""
from __future__ import annotations

import pytest

from validation.stress import fuzz, run_case
from validation.stress_cases import all_cases
from validation.stress_denoise import denoise_cases
from validation.stress_fuzz_commands import contract_problems, fuzz_commands

CASES = [c for c in all_cases() if c.fast]
DENOISE_CASES = [c for c in denoise_cases() if c.fast]


def test_enough_cases():
    assert len(CASES) + len(DENOISE_CASES) >= 40
    assert len(all_cases()) + len(denoise_cases()) >= 60


@pytest.mark.parametrize("case", DENOISE_CASES, ids=lambda c: c.name)
def test_denoise_case(variant_llvm_ad_rgb, case):
    passed, detail = case.check()
    assert passed, detail


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.name)
def test_case(variant_llvm_ad_rgb, case):
    passed, detail = run_case(case)
    assert passed, detail


def test_fuzzer_finds_only_located_scene_errors():
    assert fuzz(examples=400) >= 1000


def test_a_case_can_fail(variant_llvm_ad_rgb):
    """The checks bite: an error case whose scene is fine fails, and so does a
    render case whose 'equivalent' differs."""
    from validation.stress_cases import Case, scene

    assert not run_case(Case("not an error", scene(), "error", expect="anything"))[0]
    assert not run_case(Case("wrong equivalent", scene(), "render", match=scene(angle="60")))[0]


def test_the_commands_fuzzer_keeps_the_contract(variant_llvm_ad_rgb):
    """Every draw of every denoiser command and score: its exit code, or one error line."""
    assert fuzz_commands(examples=12) >= 7 * 12


def test_the_commands_contract_bites():
    """A traceback, two lines, another program's line or exit 1 are each a problem."""
    prog = "python -m denoise.score"
    assert contract_problems(prog, 2, f"{prog}: error: x\n") == []
    assert contract_problems(prog, 0, "") == []
    for code, err in ((2, f"{prog}: error: x\n{prog}: error: y\n"), (2, "render.py: error: x\n"), (1, ""),
                      (0, "Traceback (most recent call last):\n")):
        assert contract_problems(prog, code, err), (code, err)
