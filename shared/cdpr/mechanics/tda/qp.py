"""The QP methods through ``qpsolvers`` (OSQP by default): ``qp`` (the paper's eq. 8) and ``continuity``.

``qpsolvers`` (and the scipy.sparse it needs) is imported on the first call that needs the solver: an
exact active-set step (from the previous answer's active set, or from none on the first call, KKT
checked) solves most problems along a trajectory, so a session often never loads it.
"""

from __future__ import annotations

import importlib.util
import math
import warnings
from abc import abstractmethod
from types import MappingProxyType
from typing import Any, ClassVar, cast, get_args

import numpy as np

from cdpr.mechanics.rotation import Array
from cdpr.mechanics.tda.base import Reference, TensionDistributor, _Problem, _refine, nearest_admissible

# OSQP is ADMM with loose defaults; these settings apply to the scaled problem (tensions / max bound).
_OSQP_SETTINGS: MappingProxyType[str, Any] = MappingProxyType(
    {"eps_abs": 1e-9, "eps_rel": 1e-9, "polish": True, "max_iter": 20000, "polish_refine_iter": 5}
)
# qpsolvers' backend names → the package each needs (checked without importing qpsolvers).
_SOLVER_PACKAGES = {"osqp": "osqp", "quadprog": "quadprog", "clarabel": "clarabel", "cvxopt": "cvxopt",
                    "daqp": "daqp", "ecos": "ecos", "highs": "highspy", "piqp": "piqp", "proxqp": "proxsuite",
                    "qpalm": "qpalm", "scs": "scs", "gurobi": "gurobipy", "mosek": "mosek"}


def _solver_installed(solver: str) -> tuple[bool, str]:
    """(whether qpsolvers' backend ``solver`` can be used, the backends that can) — importing qpsolvers
    only for a name this module does not know."""
    package = _SOLVER_PACKAGES.get(solver)
    if package is not None and importlib.util.find_spec(package) is not None:
        return True, ""
    import qpsolvers

    return solver in qpsolvers.available_solvers, ", ".join(qpsolvers.available_solvers)


class _QpDistributor(TensionDistributor):
    """Shared machinery of the QP methods: min ½α‖f‖² + qᵀf s.t. W f = w, bounds."""

    def __init__(
        self,
        solver: str = "osqp",
        atol: float = 1e-6,
        warm_active_set: bool = True,
        exact: bool = True,
        solver_settings: dict[str, Any] | None = None,
    ) -> None:
        """``solver``: a qpsolvers backend; ``warm_active_set``: first try the previous call's active set
        (exact KKT check, no solver call), which is what a warm-started active-set method does.
        ``exact=False`` takes the solver's answer as it comes (no active-set refinement, no warm active
        set, the solver's own default tolerances unless ``solver_settings`` says otherwise): the
        typical real-time QP setup, kept to reproduce the paper's tension spikes."""
        super().__init__(atol)
        installed, available = _solver_installed(solver)
        if not installed:
            raise ValueError(f"QP solver {solver!r} is not installed (available: {available})")
        self.solver = solver
        self.exact = exact
        self.warm_active_set = warm_active_set and exact
        self.solver_settings = dict(solver_settings or {})
        self.solver_calls = 0  # how many calls needed the QP solver (the active set changed)
        self.calls = 0

    @abstractmethod
    def _objective(self, prob: _Problem) -> tuple[float, Array | None]:
        """(α, q) of the cost ½α‖f‖² + qᵀf; q = None stands for q = 0."""

    def _rate_bounds(self, prob: _Problem) -> tuple[Array, Array] | None:
        """Tighter bounds to try first (continuity's max_rate), or None."""
        return None

    def _qp(
        self, alpha: float, q: Array | None, prob: _Problem, lb: Array, ub: Array
    ) -> tuple[Array, str] | None:
        """Solve with the QP solver, then make it exact; None if no admissible answer comes out."""
        import qpsolvers
        import scipy.sparse as spa

        sub = _Problem(prob.W, prob.w, lb, ub, prob.tol)
        s = sub.bound_scale  # solve for f / s so the solver's absolute tolerances are relative
        m = lb.size
        if self.solver in qpsolvers.sparse_solvers:
            P: Any = spa.identity(m, format="csc") * alpha
            A: Any = spa.csc_matrix(prob.W)
        else:
            P, A = alpha * np.eye(m), prob.W
        prev = self._previous_for(m)
        initvals = None if prev is None else np.clip(prev, lb, ub) / s
        settings = dict(_OSQP_SETTINGS) if self.solver == "osqp" and self.exact else {}
        settings.update(self.solver_settings)
        q_s = np.zeros(m) if q is None else q / s
        problem = qpsolvers.Problem(P, q_s, A=A, b=prob.w / s, lb=lb / s, ub=ub / s)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # failures are reported through the status instead
            try:
                solution = qpsolvers.solve_problem(problem, solver=self.solver, initvals=initvals, **settings)
            except (cast(type[Exception], qpsolvers.QPError), *self.solver_errors):
                return None
        x = solution.x
        if x is None or np.shape(x) != (m,) or not np.all(np.isfinite(x)):
            return None
        x = np.asarray(x, dtype=float) * s
        if not self.exact:
            x = np.clip(x, lb, ub)
            return (x, "optimal") if sub.residual(x) <= prob.tol else None
        exact = _refine(alpha, q, sub, prob.w, x)
        if exact is not None:
            return exact, "optimal"
        x = np.clip(x, lb, ub)
        if sub.residual(x) <= prob.tol:
            return x, "optimal" if solution.found else "suboptimal"
        return None

    def _solve(self, prob: _Problem) -> tuple[Array | None, str]:
        alpha, q = self._objective(prob)
        tight = self._rate_bounds(prob)
        self.calls += 1
        prev = self._previous_for(prob.lb.size)
        if tight is None and self.warm_active_set:
            # Along a trajectory the active set rarely changes: if the previous one still satisfies the
            # KKT conditions (checked exactly by _refine) the QP is solved without calling the solver.
            # With no previous answer, the same exact step starts from no active bound (the middle of
            # the box) and moves cables in or out while a KKT condition fails.
            start = prev if prev is not None else 0.5 * (prob.lb + prob.ub)
            exact = _refine(alpha, q, prob, prob.w, start)
            if exact is not None:
                return exact, "optimal"
        self.solver_calls += 1
        if tight is not None:
            answer = self._qp(alpha, q, prob, *tight)
            if answer is not None:
                return answer
        answer = self._qp(alpha, q, prob, prob.lb, prob.ub)
        if answer is not None:
            f, status = answer
            return f, "rate_relaxed" if tight is not None and status == "optimal" else status
        if not self.exact:
            return None, "solver_failed"
        # The solver failed: start the active-set refinement from the bounded least-squares answer.
        nearest = nearest_admissible(prob.W, prob.w, prob.lb, prob.ub)
        if prob.residual(nearest) <= prob.tol:
            exact = _refine(alpha, q, prob, prob.w, nearest)
            if exact is not None:
                return exact, "optimal" if tight is None else "rate_relaxed"
            return nearest, "suboptimal"
        # Unreachable wrench: the method's optimum among the tensions that come nearest to it.
        best = _refine(alpha, q, prob, prob.W @ nearest, nearest)
        if best is not None and prob.residual(best) <= prob.residual(nearest) + prob.tol:
            return best, "infeasible"
        return nearest, "infeasible"


class MinNormQp(_QpDistributor):
    """The paper's eq. 8: min ‖f‖² s.t. W f = w, tmin ≤ f ≤ tmax."""

    name: ClassVar[str] = "qp"

    def _objective(self, prob: _Problem) -> tuple[float, Array | None]:
        return 1.0, None


class ContinuityQp(_QpDistributor):
    """min ‖f − f_prev‖² + ε‖f − f_ref‖² s.t. W f = w, bounds (and |f − f_prev| ≤ max_rate if possible)."""

    name: ClassVar[str] = "continuity"

    def __init__(
        self,
        epsilon: float = 1e-2,
        max_rate: float | None = None,
        reference: Reference = "min-norm",
        solver: str = "osqp",
        atol: float = 1e-6,
    ) -> None:
        """``epsilon``: weight of the pull towards the reference tensions f_ref, per call;
        ``max_rate``: largest change of a tension per call (N), None = unlimited;
        ``reference``: ``min-norm`` (f_ref = 0: a constant wrench converges to the ``qp`` answer) or
        ``mid-range`` (f_ref = f_m = (tmin + tmax)/2: converges to the closed-form answer, tensions rise
        towards mid-range)."""
        super().__init__(solver=solver, atol=atol)
        if not (math.isfinite(epsilon) and epsilon >= 0.0):
            raise ValueError(f"epsilon must be >= 0 (got {epsilon})")
        if max_rate is not None and not max_rate > 0.0:
            raise ValueError(f"max_rate must be > 0 or None (got {max_rate})")
        if reference not in get_args(Reference):
            raise ValueError(f"reference must be one of {get_args(Reference)} (got {reference!r})")
        self.epsilon = float(epsilon)
        self.max_rate = None if max_rate is None else float(max_rate)
        self.reference = reference

    def _objective(self, prob: _Problem) -> tuple[float, Array | None]:
        prev = self._previous_for(prob.lb.size)
        if prev is None:
            return 1.0, None  # first call: the qp problem
        ref = 0.5 * (prob.lb + prob.ub) if self.reference == "mid-range" else 0.0
        return 1.0 + self.epsilon, -(prev + self.epsilon * ref)

    def _rate_bounds(self, prob: _Problem) -> tuple[Array, Array] | None:
        prev = self._previous_for(prob.lb.size)
        if prev is None or self.max_rate is None:
            return None
        lo = np.clip(prev - self.max_rate, prob.lb, prob.ub)
        hi = np.clip(prev + self.max_rate, prob.lb, prob.ub)
        return lo, hi
