"""The ``cdpr`` command and what only it uses: the session launcher, the benchmark, reports, experiments,
the soak test, SDF export. Imported by nothing else in :mod:`cdpr`."""

import os

# numpy's and scipy's OpenBLAS single-threaded unless the user says otherwise: the matrices of a CDPR are
# 6 × m, far below what a thread pool pays off for, and the pool's threads cost every process ~0.15 s of
# CPU to start (and would keep the launcher from forking its services, :mod:`cdpr.tools.launch`).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
