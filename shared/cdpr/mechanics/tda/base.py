"""The interface every tension distribution method shares, and the exact active-set machinery.

:class:`TensionDistributor` validates and scales a problem, calls the method's ``_solve``, clips the
answer, computes the residual and keeps the last feasible tensions; :func:`_refine` turns an
approximate answer into the exact optimum on its active set (KKT checked). numpy and scipy only.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, ClassVar, Literal, cast, get_args

import numpy as np
from numpy.typing import ArrayLike

from cdpr.mechanics.rotation import Array, BoolArray

TdaStatus = Literal[
    "optimal", "suboptimal", "rate_relaxed", "out_of_bounds", "infeasible", "solver_failed", "invalid_input"
]
STATUSES: tuple[str, ...] = get_args(TdaStatus)
Reference = Literal["min-norm", "mid-range"]
FEASIBLE_STATUSES: frozenset[str] = frozenset({"optimal", "suboptimal", "rate_relaxed"})

_EPS = float(np.finfo(float).eps)
_LAPACK: Any = None


def _lapack() -> Any:
    """LAPACK's Cholesky routines (``dpotrf``, ``dpotrs``: scipy's Fortran wrappers), loaded on first use:
    importing this module costs no scipy (the clock and the sim load scenarios that name a method without
    ever solving).

    ``import scipy.linalg`` costs ~0.5 s of CPU (its array-API layer imports numpy.testing and numpy.f2py),
    the largest part of a controller's start-up, and the two routines need none of it: the extension module
    that holds them, ``scipy.linalg._flapack``, is loaded by itself and registered under its own name, so
    that a later ``import scipy.linalg`` (qpsolvers, scipy.sparse) takes the same module. Where that is not
    possible (another layout of scipy), the normal import."""
    global _LAPACK
    if _LAPACK is None:
        _LAPACK = _load_flapack()
        if _LAPACK is None:
            from scipy.linalg import lapack

            _LAPACK = lapack
    return _LAPACK


def _load_flapack() -> Any:
    import importlib.machinery
    import importlib.util
    import sys
    from pathlib import Path

    name = "scipy.linalg._flapack"
    if name in sys.modules:
        return sys.modules[name]
    try:
        import scipy

        folder = Path(scipy.__file__).parent / "linalg"
        path = next((folder / f"_flapack{s}" for s in importlib.machinery.EXTENSION_SUFFIXES
                     if (folder / f"_flapack{s}").is_file()), None)
        spec = importlib.util.spec_from_file_location(name, path) if path is not None else None
        if spec is None or spec.loader is None:
            return None
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    except Exception:  # an unexpected layout or loader: the normal import instead
        return None
    if not (hasattr(module, "dpotrf") and hasattr(module, "dpotrs")):
        return None
    sys.modules[name] = module
    return module


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
                 bound_scale: float | None = None, pinned: BoolArray | None = None) -> None:
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
    from scipy.optimize import lsq_linear  # only on the way to an infeasible answer

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
    L, info = _lapack().dpotrf(A @ A.T, lower=1, clean=0)
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
            y, info = _lapack().dpotrs(L, b, lower=1)
            if info == 0:
                return A.T @ y
    else:
        L = _gram_factor(A.T)
        if L is not None:
            y, info = _lapack().dpotrs(L, A.T @ b, lower=1)
            if info == 0:
                return y
    return cast(Array, np.linalg.lstsq(A, b, rcond=None)[0])


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
        x = _min_norm(Wf, rhs) if L is None else Wf.T @ _lapack().dpotrs(L, rhs, lower=1)[0]
        f[free] = x if c is None else c[free] + x
        r = W @ f - w
        if math.sqrt(float(r @ r)) > prob.tol:
            return None  # this active set cannot produce the wrench
        grad = alpha * f if q is None else alpha * f + q
        lam = _min_norm(Wf.T, grad[free]) if L is None else _lapack().dpotrs(L, Wf @ grad[free], lower=1)[0]
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
    # Exceptions a method's solver may raise: the call then returns ``solver_failed``.
    solver_errors: ClassVar[tuple[type[BaseException], ...]] = (ValueError, ArithmeticError, np.linalg.LinAlgError)

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
        except self.solver_errors:
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
    ) -> tuple[Array, Array, float, BoolArray] | None:
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
