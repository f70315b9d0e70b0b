"""Parameter studies on Ray: sweeps, Monte Carlo robustness and gain tuning, one machine or a cluster.

* :func:`~cdpr.tools.study.engine.run_study` (``cdpr study``): every point of a study file is one
  session, run as one Ray task; one folder of results (table, plots, per-point files), resumable.
* :func:`~cdpr.tools.study.tune.run_tune` (``cdpr tune``): Optuna through Ray Tune, early stopping,
  the best point as a ready-to-run scenario.
* :func:`~cdpr.tools.study.bench.study_throughput` (``cdpr study-bench``): a study's aggregate steps/s
  against the same points run one at a time.

Ray, Optuna and pyarrow are the ``study`` extra (``pip install 'cdpr[study]'``); they are imported
only when a study runs.
"""

from __future__ import annotations

from cdpr.config.study import StudySpec, load_study
from cdpr.tools.study.bench import study_throughput
from cdpr.tools.study.engine import run_study
from cdpr.tools.study.tune import run_tune

__all__ = ["StudySpec", "load_study", "run_study", "run_tune", "study_throughput"]
