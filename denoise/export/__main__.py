"""``python -m denoise.export``: see :mod:`denoise.export.cli`."""
import sys

from core.launcher import use_project_python

if __name__ == "__main__":
    # before NumPy loads: a Python without the project's packages hands over to ./.venv's
    use_project_python("python -m denoise.export", "denoise.export")
    from denoise.export.cli import main  # after the launcher, for the reason above

    sys.exit(main())
