"""The closed-form methods: ``closed-form`` (Pott 2009) and ``improved-closed-form`` (Pott 2014)."""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from cdpr.mechanics.rotation import Array
from cdpr.mechanics.tda.base import TensionDistributor, _min_norm, _Problem, nearest_admissible


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
