#!/usr/bin/env python3
"""Renders course scenes; accepts the course binary's flags verbatim. See --help."""
import sys

from renderer.cli import main

if __name__ == "__main__":
    sys.exit(main())
