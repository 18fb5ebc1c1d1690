"""Validation: the checks the tests and the benchmarks share.

- the metrics they use (relMSE, FLIP, the course's "pixels off by > N/255", the
  temporal figures) are :mod:`imaging.metrics`, where the scoring commands take them too;
- :mod:`validation.reference_tracer`: the course's semantics in NumPy (the tests' oracle);
- :mod:`validation.crossval`: the phong BSDF's chi-square and furnace tests, whitted
  against Mitsuba's path tracer (z-scores per tile);
- :mod:`validation.convergence`: relMSE against spp and time (Monte Carlo rate);
- :mod:`validation.course_images`: the course's reference images and their regression bar;
- :mod:`validation.stress`: the stress suite, one protocol for every named case (tables by surface) and the fuzzers.

``benchmarks/`` runs them at full size, times them and writes the reports.
"""
