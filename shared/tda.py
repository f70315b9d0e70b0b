"""Tension distribution algorithms (TDA): cable tensions f with W f = w and tmin ≤ f ≤ tmax. No I/O.

``W`` is the k×m wrench matrix restricted to the controlled rows (k = 3 or 6, m cables), ``w`` the
wrench the cables must exert (see :mod:`cdpr.kinematics` for the sign convention). Methods, by
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

import math
import warnings
from abc import ABC, abstractmethod
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, ClassVar, Literal, cast, get_args

import numpy as np
import qpsolvers
import scipy.sparse as spa
from numpy.typing import ArrayLike
from scipy.linalg import lapack
from scipy.optimize import lsq_linear

from cdpr.rotation import Array

Status = Literal[
    "optimal", "suboptimal", "rate_relaxed", "out_of_bounds", "infeasible", "solver_failed", "invalid_input"
]
STATUSES: tuple[str, ...] = get_args(Status)
Reference = Literal["min-norm", "mid-range"]
FEASIBLE_STATUSES: frozenset[str] = frozenset({"optimal", "suboptimal", "rate_relaxed"})

# OSQP is ADMM with loose defaults; these settings apply to the scaled problem (tensions / max bound).
_OSQP_SETTINGS: MappingProxyType[str, Any] = MappingProxyType(
    {"eps_abs": 1e-9, "eps_rel": 1e-9, "polish": True, "max_iter": 20000, "polish_refine_iter": 5}
)
_EPS = float(np.finfo(float).eps)
_SOLVER_ERRORS = (qpsolvers.QPError, ValueError, ArithmeticError, np.linalg.LinAlgError)


@dataclass(frozen=True)
class TdaResult:
    """One tension distribution. ``tensions`` is read-only."""

    tensions: Array  # (m,), finite, within [tmin, tmax]
    feasible: bool  # W f = w met (residual <= tolerance) with admissible tensions
    residual: float  # ‖W f − w‖₂ of ``tensions`` (inf for invalid input)
    status: str  # one of STATUSES
    method: str  # registry name


class _Problem:
    """One distribution problem: W f = w within [lb, ub]. ``bound_scale`` and ``pinned`` derive from the
    bounds (given when the caller already has them)."""

    __slots__ = ("W", "any_pinned", "bound_scale", "lb", "pinned", "tol", "ub", "w")

    def __init__(self, W: Array, w: Array, lb: Array, ub: Array, tol: float,
                 bound_scale: float | None = None, pinned: Array | None = None) -> None:
        self.W, self.w, self.lb, self.ub = W, w, lb, ub
        self.tol = tol  # residual below which W f = w counts as met
        self.bound_scale = _bound_scale(lb, ub) if bound_scale is None else bound_scale
        self.pinned = lb >= ub if pinned is None else pinned
        self.any_pinned = bool(self.pinned.any()) if pinned is None else any(pinned.tolist())

    def residual(self, f: Array) -> float:
        r = self.W @ f - self.w
        return math.sqrt(float(r @ r))  # what np.linalg.norm computes for a vector, without its overhead


def _bound_scale(lb: Array, ub: Array) -> float:
    return max(1.0, float(np.abs(lb).max(initial=0.0)), float(np.abs(ub).max(initial=0.0)))


def _as_arrays(
    W: ArrayLike, w: ArrayLike, tmin: ArrayLike, tmax: ArrayLike
) -> tuple[Array, Array, Array, Array]:
    W = np.asarray(W, dtype=float)
    if W.ndim != 2 or W.shape[1] == 0:
        raise ValueError(f"W must be a k×m matrix with m >= 1 (got shape {W.shape})")
    k, m = W.shape
    w = np.asarray(w, dtype=float)
    if w.shape != (k,):
        raise ValueError(f"w must have shape ({k},) to match W {W.shape} (got {w.shape})")
    try:
        lb = np.array(np.broadcast_to(np.asarray(tmin, dtype=float), (m,)))
        ub = np.array(np.broadcast_to(np.asarray(tmax, dtype=float), (m,)))
    except ValueError as e:
        raise ValueError(f"tmin and tmax must be scalars or ({m},) arrays") from e
    if not (np.all(np.isfinite(lb)) and np.all(np.isfinite(ub))):
        raise ValueError("tension bounds must be finite")
    if np.any(lb > ub):
        raise ValueError(f"tmin must not exceed tmax (cables {np.flatnonzero(lb > ub).tolist()})")
    return W, w, lb, ub


def nearest_admissible(W: Array, w: Array, lb: Array, ub: Array) -> Array:
    """Tensions in [lb, ub] minimising ‖W f − w‖₂ (bounded-variable least squares)."""
    f = lb.copy()
    free = lb < ub
    if free.any():
        r = w - W[:, ~free] @ lb[~free]
        sol = lsq_linear(W[:, free], r, bounds=(lb[free], ub[free]), method="bvls", tol=1e-12)
        f[free] = sol.x
    return np.clip(f, lb, ub)


def _gram_factor(A: Array) -> Array | None:
    """The Cholesky factor (lower) of A Aᵀ for a wide A (k×n, k ≤ n), or None when A Aᵀ is singular or
    badly conditioned (cond(A Aᵀ) = cond(A)² above ~1e10). Straight through LAPACK: several times
    faster than numpy's solvers, with their checks, for k ≤ 6."""
    L, info = lapack.dpotrf(A @ A.T, lower=1, clean=0)
    if info != 0:  # not positive definite
        return None
    d = L.diagonal().tolist()
    return L if min(d) > 1e-5 * max(d) else None


def _min_norm(A: Array, b: Array) -> Array:
    """A⁺ b, the least-norm (least-squares) solution of A x = b.

    Through the normal equations of the smaller Gram matrix (a Cholesky factorisation and solve of a
    k×k system, k ≤ 6: several times faster than an SVD for these sizes); falls back to the SVD when
    the Gram matrix is singular or badly conditioned, so rank-deficient systems get the true
    pseudo-inverse answer.
    """
    r, c = A.shape
    if r <= c:
        L = _gram_factor(A)
        if L is not None:
            y, info = lapack.dpotrs(L, b, lower=1)
            if info == 0:
                return A.T @ y
    else:
        L = _gram_factor(A.T)
        if L is not None:
            y, info = lapack.dpotrs(L, A.T @ b, lower=1)
            if info == 0:
                return y
    return np.linalg.lstsq(A, b, rcond=None)[0]


def _refine(alpha: float, q: Array | None, prob: _Problem, w: Array, f0: Array) -> Array | None:
    """The exact minimiser of ½α‖f‖² + qᵀf s.t. W f = w, lb ≤ f ≤ ub, from the active set of f0.

    Solves the equality-constrained problem with the active bounds fixed, then checks the KKT
    conditions (free tensions within bounds, multiplier signs); a violated condition moves one cable
    in or out of the active set. None if no KKT point is reached within a few corrections.
    ``q=None`` means q = 0 (the min-norm problem).
    """
    W, lb, ub = prob.W, prob.lb, prob.ub
    m = lb.size
    scale = prob.bound_scale
    pinned = prob.pinned
    lo_band, hi_band = lb + 1e-6 * scale, ub - 1e-6 * scale
    # (small reductions through Python lists: several times cheaper than numpy's for m ≲ 30)
    all_free = (
        not prob.any_pinned and min((f0 - lo_band).tolist()) > 0.0 and min((hi_band - f0).tolist()) > 0.0
    )
    if all_free:
        at_lo = np.zeros(m, dtype=bool)  # f0 strictly inside the bounds (the usual case): no active bound
        at_hi = at_lo.copy()
    else:
        at_lo = pinned | (f0 <= lo_band)
        at_hi = ~at_lo & (f0 >= hi_band)
    btol = 1e-12 * scale
    if q is None:
        c = None
        gtol = 1e-9 * alpha * scale
    else:
        c = -q / alpha  # unconstrained minimiser
        gtol = 1e-9 * (alpha * scale + float(np.abs(q).max(initial=0.0)))
    for _ in range(m + 2):
        if all_free or not (bound := at_lo | at_hi).any():
            # Every cable free (the usual case): no multiplier to check, only the bounds.
            f = _min_norm(W, w) if c is None else c + _min_norm(W, w - W @ c)
            r = W @ f - w
            if math.sqrt(float(r @ r)) > prob.tol:
                return None
            if min((f - lb).tolist()) >= -btol and min((ub - f).tolist()) >= -btol:
                return np.clip(f, lb, ub)
            viol = np.maximum(lb - f, f - ub)
            i = int(np.argmax(viol))
            if f[i] < lb[i]:
                at_lo[i] = True
            else:
                at_hi[i] = True
            all_free = False
            continue
        free = ~bound
        f = np.where(at_lo, lb, ub)
        if not free.any():
            return None  # the wrench is out of this active set's reach, or its multipliers are undetermined
        Wf = W[:, free]
        rhs = w - W[:, bound] @ f[bound]
        if c is not None:
            rhs = rhs - Wf @ c[free]
        # With at least as many free cables as rows, the primal (least-norm tensions) and the dual
        # (multipliers) solves share the Gram matrix Wf Wfᵀ: factorised once.
        L = _gram_factor(Wf) if Wf.shape[0] <= Wf.shape[1] else None
        x = _min_norm(Wf, rhs) if L is None else Wf.T @ lapack.dpotrs(L, rhs, lower=1)[0]
        f[free] = x if c is None else c[free] + x
        r = W @ f - w
        if math.sqrt(float(r @ r)) > prob.tol:
            return None  # this active set cannot produce the wrench
        grad = alpha * f if q is None else alpha * f + q
        lam = _min_norm(Wf.T, grad[free]) if L is None else lapack.dpotrs(L, Wf @ grad[free], lower=1)[0]
        mu = grad - W.T @ lam  # ≥ 0 at lower bounds, ≤ 0 at upper bounds, 0 on free cables
        viol = np.where(free, np.maximum(lb - f, f - ub), -np.inf).tolist()
        wrong = np.where(at_lo & ~pinned, -mu, np.where(at_hi, mu, -np.inf)).tolist()
        if max(viol) > btol:
            i = viol.index(max(viol))
            if f[i] < lb[i]:
                at_lo[i] = True
            else:
                at_hi[i] = True
        elif max(wrong) > gtol:
            i = wrong.index(max(wrong))
            at_lo[i] = at_hi[i] = False
        else:
            return np.clip(f, lb, ub)
    return None


class TensionDistributor(ABC):
    """A tension distribution method. Keeps the previous answer (warm start, continuity) between calls."""

    name: ClassVar[str]

    def __init__(self, atol: float = 1e-6) -> None:
        """``atol``: residual ‖W f − w‖₂ (N, N·m) below which the wrench counts as met."""
        if not atol > 0.0:
            raise ValueError(f"atol must be > 0 (got {atol})")
        self.atol = float(atol)
        self._previous: Array | None = None  # tensions returned by the last call
        self._last_feasible: Array | None = None
        self._bounds: dict[tuple[int, float, float], tuple[Array, Array, float, Array]] = {}

    def reset(self) -> None:
        """Forget the previous tensions (warm start, continuity reference, last feasible answer)."""
        self._previous = None
        self._last_feasible = None

    def solve(self, W: ArrayLike, w: ArrayLike, tmin: ArrayLike, tmax: ArrayLike) -> TdaResult:
        """Tensions for the wrench ``w`` (k,) through ``W`` (k×m) within [tmin, tmax] (scalars or (m,))."""
        bounds = self._scalar_bounds(W, w, tmin, tmax)
        if bounds is None:
            W, w, lb, ub = _as_arrays(W, w, tmin, tmax)
            bscale, pinned = _bound_scale(lb, ub), lb >= ub
        else:  # the loop's case: float arrays of the right shapes, scalar bounds
            lb, ub, bscale, pinned = bounds
        W = cast(Array, W)
        w = cast(Array, w)
        w_max, row_max = float(np.abs(w).max()), float(np.abs(W).sum(axis=1).max())
        # Both are finite when W and w are (a NaN or an infinity propagates); only an overflow of
        # the row sums of finite numbers needs the element-wise check.
        if not math.isfinite(w_max + row_max) and not (np.all(np.isfinite(W)) and np.all(np.isfinite(w))):
            return self._finish(self._keep(lb, ub), math.inf, "invalid_input")
        scale = w_max + row_max * bscale
        prob = _Problem(W, w, lb, ub, max(self.atol, 64.0 * _EPS * scale), bscale, pinned)
        try:
            f, status = self._solve(prob)
        except _SOLVER_ERRORS:
            f, status = None, "solver_failed"
        if f is None or (not math.isfinite(float(f.sum())) and not np.all(np.isfinite(f))):
            kept = self._keep(lb, ub)
            return self._finish(kept, prob.residual(kept), "solver_failed")
        f = np.clip(f, lb, ub)
        residual = prob.residual(f)
        if status in FEASIBLE_STATUSES and residual > prob.tol:
            status = "solver_failed"  # defensive: never report a wrench that is not met
        return self._finish(f, residual, status)

    def _scalar_bounds(
        self, W: ArrayLike, w: ArrayLike, tmin: ArrayLike, tmax: ArrayLike
    ) -> tuple[Array, Array, float, Array] | None:
        """(lb, ub, bound scale, pinned) for float64 arrays W (k×m), w (k,) and float bounds, built once
        per (m, tmin, tmax) and kept; None for any other input (then :func:`_as_arrays` checks it all)."""
        if type(W) is not np.ndarray or type(w) is not np.ndarray:
            return None
        if type(tmin) is not float or type(tmax) is not float:
            return None
        if W.dtype != np.float64 or w.dtype != np.float64 or W.ndim != 2 or w.shape != (W.shape[0],):
            return None
        key = (W.shape[1], tmin, tmax)
        cached = self._bounds.get(key)
        if cached is None:
            if key[0] == 0 or not (math.isfinite(tmin) and math.isfinite(tmax)) or tmin > tmax:
                return None  # let _as_arrays raise the usual error
            if len(self._bounds) >= 8:
                self._bounds.clear()  # bounds that change all the time: keep the cache small
            lb, ub = np.full(key[0], tmin), np.full(key[0], tmax)
            lb.flags.writeable = ub.flags.writeable = False
            pinned = lb >= ub
            pinned.flags.writeable = False
            cached = self._bounds[key] = (lb, ub, _bound_scale(lb, ub), pinned)
        return cached

    def _keep(self, lb: Array, ub: Array) -> Array:
        """The last feasible tensions, clipped to the current bounds, or tmin."""
        last = self._last_feasible
        return np.clip(last, lb, ub) if last is not None and last.shape == lb.shape else lb.copy()

    def _finish(self, f: Array, residual: float, status: str) -> TdaResult:
        f = np.array(f, dtype=float)
        f.flags.writeable = False
        feasible = status in FEASIBLE_STATUSES
        self._previous = f
        if feasible:
            self._last_feasible = f
        return TdaResult(tensions=f, feasible=feasible, residual=residual, status=status, method=self.name)

    def _previous_for(self, m: int) -> Array | None:
        prev = self._previous
        return prev if prev is not None and prev.shape == (m,) else None

    @abstractmethod
    def _solve(self, prob: _Problem) -> tuple[Array | None, str]:
        """(tensions, status) for a valid problem; the base class clips and computes the residual."""


def _fallback(prob: _Problem, method_answer: Array) -> tuple[Array, str]:
    """After a closed-form failure: ``infeasible`` (nearest admissible tensions) or ``out_of_bounds``."""
    nearest = nearest_admissible(prob.W, prob.w, prob.lb, prob.ub)
    if prob.residual(nearest) > prob.tol:
        return nearest, "infeasible"
    return np.clip(method_answer, prob.lb, prob.ub), "out_of_bounds"


class ClosedForm(TensionDistributor):
    """Pott et al. 2009 closed form, single shot: f = f_m + W⁺(w − W f_m)."""

    name: ClassVar[str] = "closed-form"

    def _solve(self, prob: _Problem) -> tuple[Array | None, str]:
        fm = 0.5 * (prob.lb + prob.ub)
        f = np.clip(fm + _min_norm(prob.W, prob.w - prob.W @ fm), prob.lb, prob.ub)
        if prob.residual(f) <= prob.tol:
            return f, "optimal"
        return _fallback(prob, f)


class ImprovedClosedForm(TensionDistributor):
    """Pott 2014 improved closed form: fix the most violated tension at its bound and repeat."""

    name: ClassVar[str] = "improved-closed-form"

    def _solve(self, prob: _Problem) -> tuple[Array | None, str]:
        W, w, lb, ub = prob.W, prob.w, prob.lb, prob.ub
        k = W.shape[0]
        fm = 0.5 * (lb + ub)
        f = fm.copy()
        free = np.ones(lb.size, dtype=bool)
        while True:
            Wf = W[:, free]
            f[free] = fm[free] + _min_norm(Wf, w - W[:, ~free] @ f[~free] - Wf @ fm[free])
            clipped = np.clip(f, lb, ub)
            if prob.residual(clipped) <= prob.tol:
                return clipped, "optimal"
            viol = np.where(free, np.maximum(lb - f, f - ub), -np.inf)
            i = int(np.argmax(viol))
            if viol[i] <= 0.0 or free.sum() <= k:
                return _fallback(prob, f)  # rank lost, or no cable left to fix
            f[i] = lb[i] if f[i] < lb[i] else ub[i]
            free[i] = False


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
        if solver not in qpsolvers.available_solvers:
            raise ValueError(
                f"QP solver {solver!r} is not installed (available: {', '.join(qpsolvers.available_solvers)})"
            )
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
            except _SOLVER_ERRORS:
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
        if tight is None and prev is not None and self.warm_active_set:
            # Along a trajectory the active set rarely changes: if the previous one still satisfies the
            # KKT conditions (checked exactly by _refine) the QP is solved without calling the solver.
            exact = _refine(alpha, q, prob, prob.w, prev)
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


METHODS: dict[str, type[TensionDistributor]] = {
    cls.name: cls for cls in (MinNormQp, ClosedForm, ImprovedClosedForm, ContinuityQp)
}


def make_tda(name: str, **options: Any) -> TensionDistributor:
    """A new distributor of the registered method ``name`` built with ``options``."""
    try:
        cls = METHODS[name]
    except KeyError:
        raise ValueError(f"unknown TDA method {name!r} (known: {', '.join(sorted(METHODS))})") from None
    return cls(**options)
