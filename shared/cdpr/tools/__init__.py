"""The ``cdpr`` command and what only it uses: the session launcher, the benchmark, reports, experiments,
the soak test, SDF export. Imported by nothing else in :mod:`cdpr`."""
