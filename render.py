#!/usr/bin/env python3
"""Renders course scenes; accepts the course binary's flags verbatim. See --help.

Every error is one line and exit code 2 (``core.entry.run`` inside ``main``)."""
import sys

from renderer.cli import main

if __name__ == "__main__":
    sys.exit(main())
