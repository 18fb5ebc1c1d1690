#!/usr/bin/env python3
"""Renders course scenes; accepts the course binary's flags verbatim. See --help.

Every error is one line and exit code 2 (``core.entry.run`` inside ``main``)."""
import sys

if __name__ == "__main__":  # started by a Python without the project's packages: use ./.venv's
    from core.launcher import use_project_python
    use_project_python("render.py")

from renderer.cli import main

if __name__ == "__main__":
    sys.exit(main())
