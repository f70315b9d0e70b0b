"""Tension distribution algorithms (TDA): cable tensions f with W f = w and tmin ≤ f ≤ tmax. No I/O.

``W`` is the k×m wrench matrix restricted to the controlled rows (k = 3 or 6, m cables), ``w`` the
wrench the cables must exert (see :mod:`cdpr.mechanics.kinematics` for the sign convention). Methods, by
registry name (:data:`METHODS`, :func:`make_tda`):

``qp``
    The seed paper's eq. 8, the 2-norm optimal distribution: min ‖f‖² s.t. W f = w, tmin ≤ f ≤ tmax.
    Solved with ``qpsolvers`` (OSQP by default, warm-started from the previous call), then made exact:
    the equality-constrained least-norm problem is solved on the active set the solver found and the
    KKT conditions (bounds, multiplier signs) are checked; the solver's own answer is the fallback.
    Warm start goes one step further: each call first tries the previous call's active set, and when
    the KKT conditions hold there (the usual case along a trajectory) the strictly convex QP's unique
    optimum is found without calling the solver at all (``solver_calls`` counts the calls that did).
``closed-form``
    Pott, Bruckmann & Mikelsons (2009), "Closed-form force distribution for parallel wire robots":
    f = f_m + W⁺(w − W f_m), f_m = (tmin + tmax)/2, in a single shot. When f leaves the bounds the
    method has failed: status ``out_of_bounds``, tensions clipped to the bounds, ``feasible=False``.
``improved-closed-form``
    Pott (2014), "An improved force distribution algorithm for over-constrained cable-driven parallel
    robots" (the ``IMPROVED_CLOSED_FORM`` solver of CASPR): after the closed form, the cable with the
    largest bound violation is fixed at that bound and the closed form is repeated on the remaining
    cables, until every tension is admissible or fewer than k cables (or rank k) remain.
``continuity``
    min ‖f − f_prev‖² + ε‖f − f_ref‖² s.t. W f = w, bounds, where f_prev is the tension vector returned
    by the previous call (the first call after construction or :meth:`~TensionDistributor.reset`
    solves the ``qp`` problem). f_ref is 0 by default (``reference="min-norm"``: a constant wrench
    converges to the ``qp`` answer, in about 1/ε calls), or f_m (``reference="mid-range"``). An
    optional ``max_rate`` (N per call) adds the bounds |f − f_prev| ≤ max_rate, dropped when they
    make the wrench unreachable. This smooths the "tension spikes" of the paper's Fig. 2–3: the answer
    moves as little as the new wrench allows instead of jumping with the qp's active set.

Result statuses (:data:`STATUSES`); ``feasible`` is True exactly for the first three:

* ``optimal``: W f = w within bounds, and f is the method's own answer.
* ``suboptimal``: W f = w within bounds, but the QP solver failed and f is the bounded least-squares
  fallback (admissible, not the method's optimum).
* ``rate_relaxed``: ``continuity`` only: optimal after dropping the ``max_rate`` bounds.
* ``out_of_bounds``: closed-form methods only: admissible tensions exist, the method did not find them;
  f is its answer clipped to the bounds.
* ``infeasible``: w is outside the wrench-feasible set; f is the nearest admissible answer (it minimises
  ‖W f − w‖₂ within the bounds; the QP methods pick their own optimum among such f).
* ``solver_failed``: every solver failed; f is the last feasible tension vector (clipped) or tmin.
* ``invalid_input``: W or w is not finite; f is the last feasible tension vector (clipped) or tmin.

Tensions are always finite and inside [tmin, tmax]. Shape errors and inconsistent bounds (non-finite,
tmin > tmax) are programming errors and raise ``ValueError``.
"""


from __future__ import annotations

from typing import Any

from cdpr.mechanics.tda.base import (
    FEASIBLE_STATUSES,
    STATUSES,
    Reference,
    TdaResult,
    TdaStatus,
    TensionDistributor,
    nearest_admissible,
)
from cdpr.mechanics.tda.closed_form import ClosedForm, ImprovedClosedForm

__all__ = [
    "FEASIBLE_STATUSES",
    "METHODS",
    "METHOD_NAMES",
    "STATUSES",
    "ClosedForm",
    "ContinuityQp",
    "ImprovedClosedForm",
    "MinNormQp",
    "Reference",
    "TdaResult",
    "TdaStatus",
    "TensionDistributor",
    "make_tda",
    "nearest_admissible",
]

# The registry by name. The QP methods (and qpsolvers, OSQP, scipy behind them) are imported on first
# use: a process that only reads a scenario naming its method (the clock, the sim) never loads them.
METHOD_NAMES: tuple[str, ...] = ("qp", "closed-form", "improved-closed-form", "continuity")


def _methods() -> dict[str, type[TensionDistributor]]:
    from cdpr.mechanics.tda.qp import ContinuityQp, MinNormQp

    return {cls.name: cls for cls in (MinNormQp, ClosedForm, ImprovedClosedForm, ContinuityQp)}


def __getattr__(name: str) -> Any:  # PEP 562: METHODS, MinNormQp, ContinuityQp on first use
    if name == "METHODS":
        return _methods()
    if name in ("MinNormQp", "ContinuityQp"):
        from cdpr.mechanics.tda import qp

        return getattr(qp, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def make_tda(name: str, **options: Any) -> TensionDistributor:
    """A new distributor of the registered method ``name`` built with ``options``."""
    if name not in METHOD_NAMES:
        raise ValueError(f"unknown TDA method {name!r} (known: {', '.join(sorted(METHOD_NAMES))})")
    return _methods()[name](**options)
