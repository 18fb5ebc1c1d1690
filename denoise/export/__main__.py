"""``python -m denoise.export``: see :mod:`denoise.export.cli`."""
import sys

from core.launcher import start

if __name__ == "__main__":
    # before NumPy loads: ./.venv's Python, the libLLVM, then Dr.Jit
    start("python -m denoise.export", "denoise.export")
    from denoise.export.cli import main  # after start, for the reason above

    sys.exit(main())
