"""Tension distribution: every method against independent computations (quadprog, lsq_linear, pinv)."""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import pytest
import quadprog
from scipy.optimize import lsq_linear
from scipy.stats import special_ortho_group

from cdpr.config.robot import load_robot
from cdpr.mechanics.dynamics import gravity_wrench, required_wrench
from cdpr.mechanics.kinematics import inverse_kinematics
from cdpr.mechanics.robot import Robot
from cdpr.mechanics.rotation import rpy_to_matrix
from cdpr.mechanics.tda import FEASIBLE_STATUSES, METHODS, STATUSES, TdaResult, make_tda

ALL = sorted(METHODS)
QP_LIKE = ["qp", "continuity"]
PAPER_LIMITS = (1.0, 6500.0)  # the seed paper's experiments


@dataclass(frozen=True)
class Case:
    name: str
    W: np.ndarray
    w: np.ndarray
    lb: np.ndarray
    ub: np.ndarray


def best_residual(c: Case) -> float:
    """min ‖W f − w‖ over the bounds, by scipy's BVLS."""
    sol = lsq_linear(c.W, c.w, bounds=(c.lb, c.ub), method="bvls", tol=1e-14)
    return float(np.linalg.norm(c.W @ sol.x - c.w))


def quadprog_qp(c: Case, alpha: float = 1.0, q: np.ndarray | None = None) -> np.ndarray:
    """min ½α‖f‖² + qᵀf s.t. W f = w, lb ≤ f ≤ ub with quadprog (Goldfarb–Idnani), no qpsolvers."""
    k, m = c.W.shape
    C = np.hstack([c.W.T, np.eye(m), -np.eye(m)])
    b = np.r_[c.w, c.lb, -c.ub]
    a = np.zeros(m) if q is None else -q
    return quadprog.solve_qp(alpha * np.eye(m), a, C, b, meq=k)[0]


def bounds(robot: Robot, limits: tuple[float, float] | None) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = (robot.tmin, robot.tmax) if limits is None else limits
    return np.full(robot.m, lo), np.full(robot.m, hi)


def caroca_case(name: str, robot: Robot, position, rpy=(0.0, 0.0, 0.0), accel=None, twist=None,
                limits=None, rows=slice(None)) -> Case:
    R = rpy_to_matrix(*rpy)
    W = inverse_kinematics(robot, position, R).wrench_matrix
    if accel is None:
        w = -gravity_wrench(robot)
    else:
        w = required_wrench(robot, R, np.zeros(6) if twist is None else twist, accel)
    lb, ub = bounds(robot, limits)
    return Case(name, W[rows], w[rows], lb, ub)


def feasible_cases() -> list[Case]:
    caroca = load_robot("caroca")
    heavy = caroca.with_mass(150.0)
    light = caroca.with_payload(15.0)
    small = caroca.with_mass(15.0)
    cases = []
    for p in [(0.0, 0.0, 1.5), (0.9, 0.9, 0.2), (2.5, 1.5, 3.0), (-3.0, -1.5, 0.5), (0.0, 0.0, 3.3)]:
        cases.append(caroca_case(f"static150@{p}", heavy, p))
        cases.append(caroca_case(f"static15@{p}/paper-limits", small, p, limits=PAPER_LIMITS))
    cases += [
        caroca_case("tilted150", heavy, (0.5, -0.4, 1.2), rpy=(0.1, -0.15, 0.3)),
        caroca_case("dynamic165", light, (0.3, 0.2, 1.0), accel=[1.0, -0.5, 2.0, 0.3, -0.2, 0.1],
                    twist=[0.2, 0.1, 0.0, 0.5, -0.3, 0.2]),
        caroca_case("dynamic15/paper-limits", small, (-1.0, 0.5, 2.0), rpy=(0.0, 0.1, -0.2),
                    accel=[-2.0, 1.0, -1.0, 0.0, 0.5, 0.2], twist=[0.0, 0.0, 0.3, 0.1, 0.1, 0.0],
                    limits=PAPER_LIMITS),
        caroca_case("3dof-rows150", heavy, (0.4, 0.3, 1.8), accel=[0.5, 0.5, -1.0, 0, 0, 0],
                    rows=slice(0, 3)),
    ]
    for seed in range(8):  # random well-conditioned W (singular values in [1, 3]), per-cable bounds
        rng = np.random.default_rng(seed)
        k = (3, 6)[seed % 2]
        m = k + 2 + seed % 3
        S = np.zeros((k, m))
        S[:, :k] = np.diag(rng.uniform(1.0, 3.0, k))
        W = special_ortho_group.rvs(k, random_state=rng) @ S @ special_ortho_group.rvs(m, random_state=rng).T
        lb = rng.uniform(0.0, 20.0, m)
        ub = lb + rng.uniform(50.0, 200.0, m)
        cases.append(Case(f"random{seed}-{k}x{m}", W, W @ rng.uniform(lb, ub), lb, ub))
    return cases


def infeasible_cases() -> list[Case]:
    caroca = load_robot("caroca")
    heavy = caroca.with_mass(150.0)
    lb, ub = bounds(heavy, None)
    huge = caroca_case("huge-wrench", heavy, (0.2, -0.3, 1.4))
    too_low = caroca_case("tmax-too-small", heavy, (0.0, 0.0, 1.5), limits=(50.0, 120.0))
    return [
        Case("huge-wrench", huge.W, huge.w * 80.0 + np.r_[0, 0, 0, 5e4, 0, 0], lb, ub),
        too_low,
        caroca_case("light-platform-tmin50", caroca.with_mass(15.0), (0.0, 0.0, 1.5)),
        Case("sideways-3dof", huge.W[:3], np.array([5e4, 0.0, 0.0]), lb, ub),
    ]


FEASIBLE = feasible_cases()
INFEASIBLE = infeasible_cases()


def check_result(res: TdaResult, c: Case, method: str) -> None:
    """Properties every answer has: finite, within bounds, consistent fields."""
    f = res.tensions
    assert f.shape == (c.W.shape[1],)
    assert np.all(np.isfinite(f))
    assert np.all(f >= c.lb)
    assert np.all(f <= c.ub)
    assert res.method == method
    assert res.status in STATUSES
    assert res.feasible == (res.status in FEASIBLE_STATUSES)
    assert res.residual == pytest.approx(np.linalg.norm(c.W @ f - c.w), abs=1e-9)


@pytest.mark.parametrize("case", FEASIBLE, ids=lambda c: c.name)
def test_cases_are_feasible(case: Case) -> None:
    assert best_residual(case) < 1e-8


@pytest.mark.parametrize("case", INFEASIBLE, ids=lambda c: c.name)
def test_infeasible_cases_are_infeasible(case: Case) -> None:
    assert best_residual(case) > 1.0


@pytest.mark.parametrize("method", ALL)
@pytest.mark.parametrize("case", FEASIBLE, ids=lambda c: c.name)
def test_feasible_wrench_is_met_within_bounds(method: str, case: Case) -> None:
    res = make_tda(method).solve(case.W, case.w, case.lb, case.ub)
    check_result(res, case, method)
    if method == "closed-form" and res.status == "out_of_bounds":
        # The plain closed form fails in parts of the workspace: that must be reported, not hidden.
        assert not res.feasible
        assert res.residual > 1e-6
        return
    assert res.status == "optimal"
    assert res.feasible
    assert np.linalg.norm(case.W @ res.tensions - case.w) < 1e-6


def test_plain_closed_form_fails_where_improved_succeeds() -> None:
    plain = make_tda("closed-form")
    failures = [c for c in FEASIBLE if plain.solve(c.W, c.w, c.lb, c.ub).status == "out_of_bounds"]
    assert len(failures) >= 3  # the reason the improved method exists
    for c in failures:
        assert make_tda("improved-closed-form").solve(c.W, c.w, c.lb, c.ub).status == "optimal"


@pytest.mark.parametrize("solver", ["osqp", "quadprog"])
@pytest.mark.parametrize("case", FEASIBLE, ids=lambda c: c.name)
def test_qp_is_the_min_norm_optimum(solver: str, case: Case) -> None:
    res = make_tda("qp", solver=solver).solve(case.W, case.w, case.lb, case.ub)
    ref = quadprog_qp(case)
    np.testing.assert_allclose(res.tensions, ref, rtol=0, atol=1e-6)
    assert res.residual < 1e-9 * max(1.0, float(np.abs(case.w).max()))


def assert_kkt(f: np.ndarray, grad: np.ndarray, c: Case) -> None:
    """grad − Wᵀλ = μ with μ = 0 on free cables, ≥ 0 at lower bounds, ≤ 0 at upper bounds."""
    scale = float(np.abs(grad).max()) + 1.0
    lo = f <= c.lb + 1e-7 * c.ub.max()
    hi = f >= c.ub - 1e-7 * c.ub.max()
    free = ~(lo | hi)
    lam = np.linalg.lstsq(c.W[:, free].T, grad[free], rcond=None)[0]
    mu = grad - c.W.T @ lam
    assert np.abs(mu[free]).max(initial=0.0) < 1e-8 * scale
    assert mu[lo].min(initial=0.0) > -1e-8 * scale
    assert mu[hi].max(initial=0.0) < 1e-8 * scale


@pytest.mark.parametrize("case", FEASIBLE, ids=lambda c: c.name)
def test_qp_kkt(case: Case) -> None:
    f = make_tda("qp").solve(case.W, case.w, case.lb, case.ub).tensions
    assert_kkt(f, f, case)


@pytest.mark.parametrize("case", FEASIBLE, ids=lambda c: c.name)
def test_continuity_first_call_is_qp_then_stays_near_previous(case: Case) -> None:
    eps = 0.05
    tda = make_tda("continuity", epsilon=eps)
    first = tda.solve(case.W, case.w, case.lb, case.ub)
    np.testing.assert_allclose(first.tensions, quadprog_qp(case), rtol=0, atol=1e-6)
    # A different wrench on the next call: min ‖f − f_prev‖² + ε‖f‖² = ½(1+ε)‖f‖² − f_prevᵀ f + const.
    mid_wrench = case.W @ (0.5 * (case.lb + case.ub))
    nxt = Case(case.name, case.W, 0.9 * case.w + 0.1 * mid_wrench, case.lb, case.ub)
    second = tda.solve(nxt.W, nxt.w, nxt.lb, nxt.ub)
    assert second.status == "optimal"
    ref = quadprog_qp(nxt, alpha=1.0 + eps, q=-first.tensions)
    np.testing.assert_allclose(second.tensions, ref, rtol=0, atol=1e-6)
    assert_kkt(second.tensions, (1.0 + eps) * second.tensions - first.tensions, nxt)


def test_continuity_mid_range_reference() -> None:
    case = FEASIBLE[0]
    tda = make_tda("continuity", epsilon=0.2, reference="mid-range")
    first = tda.solve(case.W, case.w, case.lb, case.ub).tensions
    second = tda.solve(case.W, case.w, case.lb, case.ub).tensions
    fm = 0.5 * (case.lb + case.ub)
    ref = quadprog_qp(case, alpha=1.2, q=-(first + 0.2 * fm))
    np.testing.assert_allclose(second, ref, rtol=0, atol=1e-6)
    assert np.linalg.norm(second - fm) < np.linalg.norm(first - fm)  # drifts towards mid-range


@pytest.mark.parametrize("method", ALL)
@pytest.mark.parametrize("case", INFEASIBLE, ids=lambda c: c.name)
def test_infeasible_returns_nearest_admissible(method: str, case: Case) -> None:
    res = make_tda(method).solve(case.W, case.w, case.lb, case.ub)
    check_result(res, case, method)
    assert res.status == "infeasible"
    assert not res.feasible
    best = best_residual(case)
    assert res.residual == pytest.approx(best, rel=1e-7, abs=1e-6)


@pytest.mark.parametrize("method", QP_LIKE)
def test_qp_infeasible_picks_its_optimum_among_nearest(method: str) -> None:
    """Row 1 is out of reach (f1 + f2 ≤ 20 < 30), row 2 is met by any f3 + f4 = 5: min-norm splits it."""
    c = Case("split", np.array([[1.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 1.0]]), np.array([30.0, 5.0]),
             np.zeros(4), np.full(4, 10.0))
    res = make_tda(method).solve(c.W, c.w, c.lb, c.ub)
    assert res.status == "infeasible"
    assert res.residual == pytest.approx(best_residual(c)) == pytest.approx(10.0)
    np.testing.assert_allclose(res.tensions, [10.0, 10.0, 2.5, 2.5], atol=1e-9)


@pytest.mark.parametrize("method", ALL)
def test_non_finite_input_keeps_last_feasible(method: str) -> None:
    case = FEASIBLE[0]
    tda = make_tda(method)
    W_nan = case.W.copy()
    W_nan[2, 3] = np.nan
    first = tda.solve(W_nan, case.w, case.lb, case.ub)
    assert first.status == "invalid_input"
    assert not first.feasible
    np.testing.assert_array_equal(first.tensions, case.lb)
    good = tda.solve(case.W, case.w, case.lb, case.ub)
    assert good.feasible
    bad = tda.solve(case.W, np.r_[case.w[:-1], np.inf], case.lb, case.ub)
    assert bad.status == "invalid_input"
    assert not bad.feasible
    np.testing.assert_array_equal(bad.tensions, good.tensions)
    assert np.all(np.isfinite(bad.tensions))
    tda.reset()
    np.testing.assert_array_equal(tda.solve(W_nan, case.w, case.lb, case.ub).tensions, case.lb)


@pytest.mark.parametrize("method", ALL)
def test_programming_errors_raise(method: str) -> None:
    case = FEASIBLE[0]
    tda = make_tda(method)
    with pytest.raises(ValueError, match="w must have shape"):
        tda.solve(case.W, case.w[:3], case.lb, case.ub)
    with pytest.raises(ValueError, match="tmin must not exceed tmax"):
        tda.solve(case.W, case.w, 100.0, 50.0)
    with pytest.raises(ValueError, match="tmin and tmax"):
        tda.solve(case.W, case.w, np.zeros(3), 100.0)


@pytest.mark.parametrize("method", ["qp", "improved-closed-form", "continuity"])
def test_pinned_cable(method: str) -> None:
    """A cable with tmin == tmax keeps exactly that tension."""
    case = FEASIBLE[0]
    f_qp = quadprog_qp(case)
    lb, ub = case.lb.copy(), case.ub.copy()
    lb[4] = ub[4] = f_qp[4] + 30.0
    pinned = Case("pinned", case.W, case.w, lb, ub)
    res = make_tda(method).solve(pinned.W, pinned.w, pinned.lb, pinned.ub)
    check_result(res, pinned, method)
    assert res.feasible
    assert res.tensions[4] == lb[4]
    if method == "qp":
        np.testing.assert_allclose(res.tensions, quadprog_qp(pinned), rtol=0, atol=1e-6)


def test_closed_form_is_the_pseudo_inverse_formula() -> None:
    hits = 0
    for c in FEASIBLE:
        res = make_tda("closed-form").solve(c.W, c.w, c.lb, c.ub)
        if res.status != "optimal":
            continue
        fm = 0.5 * (c.lb + c.ub)
        expect = fm + np.linalg.pinv(c.W) @ (c.w - c.W @ fm)
        np.testing.assert_allclose(res.tensions, expect, rtol=0, atol=1e-8)
        improved = make_tda("improved-closed-form").solve(c.W, c.w, c.lb, c.ub)
        np.testing.assert_allclose(improved.tensions, res.tensions, rtol=0, atol=1e-8)
        hits += 1
    assert hits >= 5


def test_improved_closed_form_is_the_closed_form_of_the_remaining_cables() -> None:
    checked = 0
    for c in FEASIBLE:
        if make_tda("closed-form").solve(c.W, c.w, c.lb, c.ub).status != "out_of_bounds":
            continue
        f = make_tda("improved-closed-form").solve(c.W, c.w, c.lb, c.ub).tensions
        fixed = (f == c.lb) | (f == c.ub)
        assert fixed.any()
        free = ~fixed
        fm = 0.5 * (c.lb + c.ub)
        Wf = c.W[:, free]
        expect = fm[free] + np.linalg.pinv(Wf) @ (c.w - c.W[:, fixed] @ f[fixed] - Wf @ fm[free])
        np.testing.assert_allclose(f[free], expect, rtol=0, atol=1e-8)
        checked += 1
    assert checked >= 3


def step_sizes(method: str, W_seq, w_seq, lb, ub, **options) -> tuple[np.ndarray, np.ndarray, set[str]]:
    tda = make_tda(method, **options)
    results = [tda.solve(W, w, lb, ub) for W, w in zip(W_seq, w_seq, strict=True)]
    F = np.array([r.tensions for r in results])
    return np.abs(np.diff(F, axis=0)).max(axis=1), F, {r.status for r in results}


def test_continuity_does_not_jump_when_qp_switches_active_set() -> None:
    """Two cables share a load, a third carries almost none of it (lever δ): while cable 1 sits at its
    lower bound the min-norm answer moves cable 3 by Δw/δ per call; continuity moves cable 1 by Δw."""
    delta = 0.002
    W = np.array([[1.0, 0.0, delta], [0.0, 1.0, 1.0]])
    lb, ub = np.array([10.0, 0.0, 0.0]), np.full(3, 1000.0)
    w_seq = [np.array([w1, 100.0]) for w1 in np.linspace(10.0, 11.0, 51)]
    qp_steps, F_qp, qp_status = step_sizes("qp", [W] * 51, w_seq, lb, ub)
    c_steps, F_c, c_status = step_sizes("continuity", [W] * 51, w_seq, lb, ub)
    assert qp_status == c_status == {"optimal"}
    assert F_qp[0, 0] == lb[0]
    assert F_qp[-1, 0] > lb[0] + 0.1
    assert qp_steps.max() > 5.0
    assert c_steps.max() < 0.1 * qp_steps.max()
    np.testing.assert_allclose(F_c[0], F_qp[0])  # same start


def caroca_trajectory(n: int = 201):
    robot = load_robot("caroca").with_payload(15.0)
    a, b, T = np.array([0.9, 0.9, 0.2]), np.array([-0.9, -0.9, 1.0]), 5.0
    W_seq, w_seq = [], []
    for t in np.linspace(0.0, T, n):
        s = t / T
        p = a + (b - a) * (10 * s**3 - 15 * s**4 + 6 * s**5)
        v = (b - a) * (30 * s**2 - 60 * s**3 + 30 * s**4) / T
        acc = (b - a) * (60 * s - 180 * s**2 + 120 * s**3) / T**2
        W_seq.append(inverse_kinematics(robot, p).wrench_matrix)
        w_seq.append(required_wrench(robot, np.eye(3), np.r_[v, 0, 0, 0], np.r_[acc, 0, 0, 0]))
    return robot, W_seq, w_seq


def test_continuity_steps_never_larger_than_qp_along_a_trajectory() -> None:
    _, W_seq, w_seq = caroca_trajectory()
    lb, ub = np.full(8, PAPER_LIMITS[0]), np.full(8, PAPER_LIMITS[1])
    qp_steps, _, qp_status = step_sizes("qp", W_seq, w_seq, lb, ub)
    c_steps, _, c_status = step_sizes("continuity", W_seq, w_seq, lb, ub)
    assert qp_status == c_status == {"optimal"}
    assert c_steps.max() <= qp_steps.max() + 1e-9


def test_continuity_max_rate() -> None:
    _, W_seq, w_seq = caroca_trajectory(101)
    lb, ub = np.full(8, PAPER_LIMITS[0]), np.full(8, PAPER_LIMITS[1])
    free_steps, _, _ = step_sizes("continuity", W_seq, w_seq, lb, ub)
    steps, _, status = step_sizes("continuity", W_seq, w_seq, lb, ub, max_rate=6.0)
    assert free_steps.max() > 6.5  # without the limit some tension changes faster
    assert status == {"optimal"}
    assert steps.max() <= 6.0 + 1e-9
    assert np.count_nonzero(steps > 6.0 - 1e-6) >= 5  # the limit was active
    # A sudden wrench change the rate limit cannot follow: the limit is dropped, the wrench is met.
    tda = make_tda("continuity", max_rate=1.0)
    tda.solve(W_seq[0], w_seq[0], lb, ub)
    jump = tda.solve(W_seq[0], w_seq[0] * 1.5, lb, ub)
    assert jump.status == "rate_relaxed"
    assert jump.feasible
    assert jump.residual < 1e-6


@pytest.mark.parametrize("solver", ["osqp", "quadprog"])
@pytest.mark.parametrize("method", QP_LIKE)
def test_warm_start_does_not_change_the_optimum(method: str, solver: str) -> None:
    cases = [c for c in FEASIBLE if c.W.shape == (6, 8)]
    warm = make_tda("qp", solver=solver)
    for prev, case in itertools.pairwise(cases):
        warm.solve(prev.W, prev.w, prev.lb, prev.ub)
        got = warm.solve(case.W, case.w, case.lb, case.ub)
        cold = make_tda("qp", solver=solver).solve(case.W, case.w, case.lb, case.ub)
        np.testing.assert_allclose(got.tensions, cold.tensions, rtol=0, atol=1e-9)
    # reset() forgets the previous answer: continuity's next call is the qp problem again.
    tda = make_tda(method, solver=solver)
    tda.solve(cases[0].W, cases[0].w, cases[0].lb, cases[0].ub)
    tda.reset()
    after = tda.solve(cases[1].W, cases[1].w, cases[1].lb, cases[1].ub)
    np.testing.assert_allclose(after.tensions, quadprog_qp(cases[1]), rtol=0, atol=1e-6)


def test_registry_and_factory() -> None:
    assert set(METHODS) == {"qp", "closed-form", "improved-closed-form", "continuity"}
    for name, cls in METHODS.items():
        assert cls.name == name
        assert make_tda(name).name == name
    with pytest.raises(ValueError, match=r"unknown TDA method 'lp'.*closed-form.*continuity.*qp"):
        make_tda("lp")
    with pytest.raises(ValueError, match="not installed"):
        make_tda("qp", solver="no-such-solver")
    with pytest.raises(ValueError, match="epsilon"):
        make_tda("continuity", epsilon=-1.0)
    with pytest.raises(TypeError):
        make_tda("closed-form", solver="osqp")


def test_tensions_are_read_only() -> None:
    c = FEASIBLE[0]
    res = make_tda("qp").solve(c.W, c.w, c.lb, c.ub)
    with pytest.raises(ValueError, match="read-only"):
        res.tensions[0] = 0.0


@pytest.mark.parametrize("method", ALL)
def test_cli_case_caroca_static_150kg(method: str) -> None:
    """What `cdpr tda` computes for caroca at (0, 0, 1.5), static, 150 kg, with the robot's limits."""
    robot = load_robot("caroca").with_mass(150.0)
    W = inverse_kinematics(robot, [0.0, 0.0, 1.5]).wrench_matrix
    w = -gravity_wrench(robot)
    res = make_tda(method).solve(W, w, robot.tmin, robot.tmax)
    assert res.feasible
    assert res.status == "optimal"
    assert np.all(res.tensions >= robot.tmin)
    assert np.all(res.tensions <= robot.tmax)
    # The platform hangs still: the cables carry its weight and no net moment.
    np.testing.assert_allclose(W @ res.tensions, [0, 0, 150.0 * 9.81, 0, 0, 0], atol=1e-6)


def test_the_cholesky_routines_load_without_scipy_linalg() -> None:
    """The first solve loads LAPACK's dpotrf/dpotrs alone (scipy.linalg costs ~0.5 s to import: a third of a
    session's start-up); they are scipy's own wrappers, which a later ``import scipy.linalg`` shares."""
    import subprocess
    import sys

    probe = (
        "import sys, numpy as np\n"
        "from cdpr.mechanics.tda import base\n"
        "lapack = base._lapack()\n"
        "loaded = [m for m in sys.modules if m.startswith('scipy.linalg')]\n"
        "assert loaded == ['scipy.linalg._flapack'], loaded\n"
        "from scipy.linalg import lapack as full\n"
        "assert full.dpotrf is lapack.dpotrf and full.dpotrs is lapack.dpotrs\n"
        "A = np.random.default_rng(1).standard_normal((6, 8))\n"
        "L, info = lapack.dpotrf(A @ A.T, lower=1, clean=0)\n"
        "y, info2 = lapack.dpotrs(L, np.ones(6), lower=1)\n"
        "assert info == info2 == 0 and np.allclose(A @ A.T @ y, 1.0)\n"
    )
    subprocess.run([sys.executable, "-c", probe], check=True, timeout=60)
