"""Stress suite: stiff and bad inputs, and a fuzzer over the scene grammar and raw bytes.

    python -m benchmarks.stress [--json PATH] [--fuzz N] [--quick] [--only NAME]

Runs every named case of :mod:`validation.stress` (``validation.stress.suite.all_cases``:
the renderer, the inputs, the system, the newer surfaces, the denoiser), each
stating its expected behaviour, and the fuzzers of :mod:`validation.stress.fuzz` (hypothesis: mutated
scenes, token soup, raw bytes as scene and as OBJ files, and ``render.py``'s
command line) and :mod:`validation.stress.fuzz_commands` (the command lines of
the denoiser's commands and the scores). Only :class:`SceneError`, with
``file:line:col``, may come out of the scene fuzzers; a command ends in its
exit code or one error line.
Prints and writes ``{"cases": N, "passed": N, "fuzz_inputs": M}`` (with
``--json``, every case's result too); exits non-zero on any failure.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

# started as `python benchmarks/x.py`, this folder would shadow the course and denoise packages
if __name__ == "__main__" and not __package__:
    sys.path[0] = str(Path(__file__).resolve().parents[1])

if __name__ == "__main__":  # first: ./.venv's Python, the libLLVM, then Dr.Jit (see core.launcher)
    from core.launcher import start
    start("python -m benchmarks.stress", "benchmarks.stress" if __package__ else None)

from benchmarks.records import check_json, write_json
from core.entry import ArgumentParser, native_start_up
from core.errors import UsageError
from core.numbers import ascii_int
from renderer.variants import set_variant
from validation.stress.fuzz import fuzz, fuzz_cli
from validation.stress.fuzz_commands import fuzz_commands
from validation.stress.suite import all_cases


def run(fuzz_examples: int, quick: bool, only: list[str] | None = None) -> dict:
    with native_start_up():
        set_variant(None)

    def wanted(case) -> bool:
        return (case.fast or not quick) and (not only or case.name in only)

    results = []
    for case in all_cases():
        if wanted(case):
            passed, detail = case.check()
            results.append({"name": case.name, "kind": case.kind, "passed": bool(passed), "detail": detail})
    fuzz_inputs, fuzz_failure = 0, None
    try:
        if fuzz_examples:
            fuzz_inputs = fuzz(fuzz_examples)
            fuzz_inputs += fuzz_cli(max(10, fuzz_examples // 35))
            fuzz_inputs += fuzz_commands(max(5, fuzz_examples // 70))
    except Exception as error:  # the first escaping input, as hypothesis reports it
        fuzz_failure = f"{type(error).__name__}: {error}"
    return {"cases": len(results), "passed": sum(r["passed"] for r in results), "fuzz_inputs": fuzz_inputs,
            "fuzz_failure": fuzz_failure, "results": results}


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog="python -m benchmarks.stress", description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", type=Path, metavar="PATH", help="write the results as JSON")
    parser.add_argument("--fuzz", type=ascii_int, default=7000, metavar="N",
                        help="examples per fuzzer (three fuzzers; default 7000, i.e. 21000 inputs; 0: no fuzzing)")
    parser.add_argument("--quick", action="store_true", help="the CI subset")
    parser.add_argument("--only", action="append", metavar="NAME",
                        help="only the case of this name (repeatable; the names are in docs/stress.json)")
    args = parser.parse_args(argv)
    if args.fuzz < 0:
        raise UsageError(f"--fuzz wants a number >= 0, got {args.fuzz}")
    names = {case.name for case in all_cases()}
    unknown = [name for name in args.only or [] if name not in names]
    if unknown:
        raise UsageError(f"--only: no stress case named {', '.join(map(repr, unknown))}")
    check_json(args.json)
    results = run(args.fuzz, args.quick, args.only)
    for r in results["results"]:
        if not r["passed"]:
            print(f"FAILED {r['name']}: {r['detail']}", file=sys.stderr)
    if results["fuzz_failure"]:
        print(f"FAILED fuzzer: {results['fuzz_failure']}", file=sys.stderr)
    summary = {k: results[k] for k in ("cases", "passed", "fuzz_inputs")}
    print(json.dumps(summary))
    if args.json:
        write_json(args.json, results)
    ok = results["passed"] == results["cases"] and not results["fuzz_failure"]
    return 0 if ok else 1


if __name__ == "__main__":
    from core import entry

    entry.finish(entry.run("python -m benchmarks.stress", main))
