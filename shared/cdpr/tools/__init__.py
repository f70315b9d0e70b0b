"""The ``cdpr`` command and what only it uses: the session launcher, the benchmark, reports, experiments,
the soak test, SDF export. Imported by nothing else in :mod:`cdpr`."""

import cdpr.runtime  # noqa: F401  (first: it makes OpenBLAS single-threaded before numpy is imported)
