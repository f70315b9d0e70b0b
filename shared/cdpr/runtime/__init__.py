"""The Zenoh runtime: sessions and configs (:mod:`.transport`), the node base and its serve loop
(:mod:`.service`), the node registry, ``python -m cdpr_<name>`` (:mod:`.main`) and the remote-controller
SDK (:mod:`.client`). The only part of :mod:`cdpr` that imports Zenoh."""

import os

# numpy's and scipy's OpenBLAS single-threaded unless the user says otherwise: the matrices of a CDPR are
# 6 × m, far below what a thread pool pays off for, and the pool's threads cost every process ~0.15 s of
# CPU to start (and would keep the launcher from forking its services, :mod:`cdpr.tools.launch`).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
