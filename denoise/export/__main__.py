"""``python -m denoise.export``: see :mod:`denoise.export.cli`."""
import sys

if __name__ == "__main__":  # first: ./.venv's Python, the libLLVM, then Dr.Jit (see core.launcher)
    from core.launcher import start
    start("python -m denoise.export", "denoise.export")
    from denoise.export.cli import main  # after start, for the reason above

    sys.exit(main())
