#!/usr/bin/env python3
"""Renders course scenes; accepts the course binary's flags verbatim. See --help.

Every error is one line and exit code 2 (``core.entry.run`` inside ``main``);
Ctrl-C and SIGTERM are one line and 130 / 143 in every phase, the imports included."""
import sys

from core.start_up import exit_on_signals  # first: standard library only, before the heavy imports

if __name__ == "__main__":  # started by a Python without the project's packages: use ./.venv's
    exit_on_signals("render.py")  # first, until main's core.entry.run takes over
    from core.launcher import start
    # then the libLLVM and Dr.Jit, whose start-up notices stay unless --quiet (read here: Dr.Jit
    # starts before the arguments are parsed)
    start("render.py", quiet="--quiet" in sys.argv[1:])

from core.entry import finish
from renderer.cli import main

if __name__ == "__main__":
    finish(main())  # a signal in the teardown keeps this exit code (see core.entry.finish)
