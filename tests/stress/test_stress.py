"""The stress suite's CI subset: every fast case of every surface, and the fuzzers with 1,000+ inputs."""
from __future__ import annotations

import pytest

from validation.stress.fuzz import fuzz
from validation.stress.fuzz_commands import contract_problems, fuzz_commands
from validation.stress.scene import Case, scene
from validation.stress.suite import all_cases

CASES = [c for c in all_cases() if c.fast]


def test_enough_cases():
    assert len(CASES) >= 40
    assert len(all_cases()) >= 60
    assert len({c.name for c in all_cases()}) == len(all_cases()), "two cases of one name"


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.name)
def test_case(variant_llvm_ad_rgb, case):
    passed, detail = case.check()
    assert passed, detail


def test_fuzzer_finds_only_located_scene_errors():
    assert fuzz(examples=400) >= 1000


def test_a_case_can_fail(variant_llvm_ad_rgb):
    """The checks bite: an error case whose scene is fine fails, and so does a
    render case whose 'equivalent' differs."""
    assert not Case("not an error", scene(), "error", expect="anything").check()[0]
    assert not Case("wrong equivalent", scene(), "render", match=scene(angle="60")).check()[0]


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
