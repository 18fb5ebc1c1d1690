"""Measurements and reports: render speed, cross-validation, error against time,
denoising, scale-out, stress; the checks themselves live in :mod:`validation`.

Imports nothing: ``python -m benchmarks.X`` runs this first, before X's first
call (:func:`core.launcher.start`) has chosen the Python and the libLLVM; the
helpers every benchmark shares are in :mod:`benchmarks.records`."""
