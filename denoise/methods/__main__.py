"""python -m denoise.methods: print the method list of docs/denoising_methods.md,
or (``--write``) make that page's generated part anew."""
from __future__ import annotations

if __name__ == "__main__":  # first: ./.venv's Python, the libLLVM, then Dr.Jit (see core.launcher)
    from core.launcher import start
    start("python -m denoise.methods", "denoise.methods")

import argparse

from core.entry import ArgumentParser, finish, run

from .listing import DOC, method_list, with_method_list

PROG = "python -m denoise.methods"


def _main(argv: list[str] | None) -> int:
    parser = ArgumentParser(prog=PROG, description=__doc__.split(": ", 1)[1],
                            formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--write", action="store_true", help=f"update {DOC.name} in docs/")
    args = parser.parse_args(argv)
    if args.write:
        DOC.write_text(with_method_list(DOC.read_text()))
        print(f"{DOC}: method list written")
    else:
        print(method_list())
    return 0


def main(argv: list[str] | None = None) -> int:
    return run(PROG, lambda: _main(argv))


if __name__ == "__main__":
    finish(main())
