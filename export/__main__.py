"""``python -m export``: see :mod:`export.cli`."""

if __name__ == "__main__":  # first: ./.venv's Python, the libLLVM, then Dr.Jit (see core.launcher)
    from core.launcher import start
    start("python -m export", "export")
    from core.entry import finish  # after start, for the reason above
    from export.cli import main  # after start, for the reason above

    finish(main())
