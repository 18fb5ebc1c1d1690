"""What every part of the toolkit shares and nothing else: the error types
that users see (:mod:`core.errors`) and the wrapper that turns them into one
line and an exit code at every command-line entry point (:mod:`core.entry`).
Imports nothing from the rest of the project."""
