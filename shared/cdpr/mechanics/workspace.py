"""The wrench-feasible workspace: where cable tensions within [tmin, tmax] can produce a wrench.

A pose x is *wrench-feasible* for a wrench w when some tensions f with tmin ≤ f ≤ tmax satisfy
W(x) f = w, W the wrench matrix restricted to the controlled rows (k rows, m cables; see
:mod:`cdpr.mechanics.kinematics`). The static workspace uses w = −w_g, the weight of the platform plus payload;
a trajectory is checked with that and with the feed-forward wrench of its desired acceleration.

Test (exact, vectorised over poses)
-----------------------------------
{W f : tmin ≤ f ≤ tmax} is a zonotope with centre W f_m (f_m = (tmin + tmax)/2) and generators
r_i w_i (r = (tmax − tmin)/2, w_i the columns of W). When W has full row rank, w is inside it iff,
for every facet normal n, |nᵀ(w − W f_m)| ≤ Σ_i r_i |nᵀ w_i|; the facet normals are among the
normals of the hyperplanes spanned by k − 1 columns. Two equivalent forms, whichever has the smaller
dimension p is used:

* p = k (``k ≤ m − k + 1``, e.g. 3-DOF control with 8 cables): n = the generalised cross product of
  k − 1 columns, for every choice of k − 1 columns.
* p = m − k + 1 (e.g. 6 DOF with 8 cables: p = 3): with N (m × (m − k)) a basis of W's null space
  and f_p any solution of W f = w, the normals in tension space are y supported on p cables T with
  y_T ⊥ rows T of N, and the test reads |yᵀ (f_p − f_m)| ≤ Σ_i r_i |y_i|. Each y is projected onto W's
  row space (y ⊥ N) before use: for a choice of cables whose rows of N are dependent (CAROCA has such
  choices at every pose: its cables come in pairs from the same frame point) the cross product is
  rounding noise, and only a row-space y gives a valid inequality.

Any unit normal gives a necessary condition (the zonotope's support function), so the test never
rejects a feasible wrench beyond the tolerance; with every facet normal present it is also sufficient.
Both are exact up to a relative tolerance ``rtol``. Poses where a cable has zero length are
infeasible; poses where W loses rank (measure zero) fall back to one linear program each (scipy's
HiGHS). No I/O in this module (:func:`cdpr.recording.workspace.record_workspace` logs a workspace to Rerun).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from itertools import combinations
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cdpr.errors import InputError
from cdpr.mechanics.dynamics import gravity_wrench, required_wrench
from cdpr.mechanics.pulley import pulley_geometry
from cdpr.mechanics.rotation import Array

if TYPE_CHECKING:
    from cdpr.mechanics.control import Variant
    from cdpr.mechanics.robot import Robot
    from cdpr.mechanics.trajectory import Trajectory

Mask = NDArray[np.bool_]

RTOL = 1e-9  # relative tolerance of the facet inequalities
SAMPLE_PERIOD = 0.05  # s, trajectory samples checked when a scenario loads
_CHUNK = 4096  # poses per vectorised block (bounds the memory of the facet arrays)


# --------------------------------------------------------------------------------------------------
# The feasibility test


def _gcross(A: Array) -> Array:
    """Generalised cross product: (..., p, p−1) → (..., p), orthogonal to the p−1 columns of A.

    Component j is (−1)^j det(A without row j); zero when the columns are dependent.
    """
    p = A.shape[-2]
    if p == 1:
        return np.ones((*A.shape[:-2], 1))
    if p == 2:
        return np.stack([A[..., 1, 0], -A[..., 0, 0]], axis=-1)
    if p == 3:
        return np.cross(A[..., 0], A[..., 1])
    rows = np.arange(p)
    minors = np.stack([np.linalg.det(A[..., rows != j, :]) for j in range(p)], axis=-1)
    return minors * np.where(rows % 2 == 0, 1.0, -1.0)


def _unit(v: Array) -> Array:
    """Rows of ``v`` (…, p) scaled to unit length; zero rows stay zero (no facet).

    Any unit direction gives a valid support inequality of the zonotope, so normalising a nearly
    degenerate normal can never reject a feasible wrench; it only adds a redundant test.
    """
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.divide(v, norm, out=np.zeros_like(v), where=norm > 0.0)


def _lp_feasible(W: Array, w: Array, lb: Array, ub: Array) -> bool:
    """One linear program: is there f in [lb, ub] with W f = w? (HiGHS; rank-deficient W is fine)."""
    from scipy.optimize import linprog  # only for the rare rank-deficient pose

    res = linprog(np.zeros(W.shape[1]), A_eq=W, b_eq=w, bounds=np.column_stack([lb, ub]), method="highs")
    return bool(res.status == 0)


def wrenches_feasible(
    W: ArrayLike, w: ArrayLike, tmin: ArrayLike, tmax: ArrayLike, rtol: float = RTOL
) -> Mask:
    """For each of n problems: is there f with tmin ≤ f ≤ tmax and W f = w?

    ``W`` (n, k, m) or (k, m), ``w`` (n, k) or (k,), bounds scalars or (m,). Non-finite W or w → False.
    """
    Wn = np.asarray(W, dtype=float)
    wn = np.asarray(w, dtype=float)
    if Wn.ndim == 2:
        Wn = Wn[None]
    n, k, m = Wn.shape
    wn = np.broadcast_to(wn, (n, k))
    lb = np.broadcast_to(np.asarray(tmin, dtype=float), (m,)).copy()
    ub = np.broadcast_to(np.asarray(tmax, dtype=float), (m,)).copy()
    if not (np.all(np.isfinite(lb)) and np.all(np.isfinite(ub))) or np.any(lb > ub):
        raise ValueError("tension bounds must be finite with tmin <= tmax")
    out = np.zeros(n, dtype=bool)
    for start in range(0, n, _CHUNK):
        sl = slice(start, min(n, start + _CHUNK))
        out[sl] = _feasible_block(Wn[sl], wn[sl], lb, ub, rtol)
    return out


def _feasible_block(W: Array, w: Array, lb: Array, ub: Array, rtol: float) -> Mask:
    n, k, m = W.shape
    fm = 0.5 * (lb + ub)
    r = 0.5 * (ub - lb)
    finite = np.all(np.isfinite(W), axis=(1, 2)) & np.all(np.isfinite(w), axis=1)
    W = np.where(finite[:, None, None], W, 0.0)
    w = np.where(finite[:, None], w, 0.0)
    out = np.zeros(n, dtype=bool)
    if m < k:  # fewer cables than rows: only the LP can say
        for i in np.flatnonzero(finite):
            out[i] = _lp_feasible(W[i], w[i], lb, ub)
        return out
    d = m - k
    U, s, Vt = np.linalg.svd(W)  # s (n, k) descending; rows k.. of Vt span the null space
    full_rank = finite & (s[:, -1] > 1e-10 * s[:, 0])
    if k <= d + 1:
        # Facet normals ⊥ k−1 columns of W, in wrench space: |nᵀ(w − W f_m)| ≤ Σ r_i |nᵀ w_i|.
        combos = list(combinations(range(m), k - 1))
        subsets = np.array(combos, dtype=int).reshape(len(combos), k - 1)
        normals = _unit(_gcross(np.moveaxis(W[:, :, subsets], 1, 2)))  # (n, S, k)
        c = w - W @ fm
        lhs = np.abs(normals @ c[:, :, None])[..., 0]
        rhs = np.abs(normals @ W) @ r
        scale = np.linalg.norm(c, axis=1) + np.linalg.norm(W, axis=1) @ r
    else:
        # Facet normals y in tension space, on d+1 cables T, ⊥ the null space there:
        # |y_Tᵀ (f_p − f_m)_T| ≤ Σ_T r_i |y_i|, f_p = W⁺ w.
        N = np.swapaxes(Vt[:, k:, :], 1, 2)  # (n, m, d)
        coef = np.einsum("nkj,nk->nj", U, w) / np.where(s > 0.0, s, 1.0)
        e = np.einsum("njm,nj->nm", Vt[:, :k, :], coef) - fm
        subsets = np.array(list(combinations(range(m), d + 1)), dtype=int)
        y = np.zeros((n, len(subsets), m))
        y[:, np.arange(len(subsets))[:, None], subsets] = _gcross(N[:, subsets, :])
        # Projected onto W's row space, every y gives a valid support inequality, even from a subset
        # whose rows of N are (structurally) dependent, where the cross product above is rounding noise.
        y = _unit(y - (y @ N) @ np.swapaxes(N, 1, 2))
        lhs = np.abs(y @ e[:, :, None])[..., 0]
        rhs = np.abs(y) @ r
        scale = np.abs(e).sum(axis=1) + r.sum() + np.abs(fm).sum()
    ok = np.all(lhs <= rhs + rtol * scale[:, None], axis=1)
    out = full_rank & ok
    for i in np.flatnonzero(finite & ~full_rank):
        out[i] = _lp_feasible(W[i], w[i], lb, ub)
    return out


# --------------------------------------------------------------------------------------------------
# Robots: wrench matrices at many poses, the static workspace, a trajectory's check


def wrench_matrices(robot: Robot, positions: ArrayLike, rotations: ArrayLike | None = None) -> Array:
    """The 6×m wrench matrices (n, 6, m) at n poses: ``positions`` (n, 3), ``rotations`` (3, 3) or (n, 3, 3).

    Same columns as :func:`cdpr.mechanics.kinematics.cable_kinematics`, [d_i; (R b_i) × d_i]; a pose where a
    cable has zero length gets NaN columns.
    """
    p = np.asarray(positions, dtype=float).reshape(-1, 3)
    R = np.eye(3) if rotations is None else np.asarray(rotations, dtype=float)
    Rb = np.einsum("...ij,mj->...mi", R, robot.platform_points)  # (m, 3) or (n, m, 3)
    Rb = np.broadcast_to(Rb, (p.shape[0], robot.m, 3))
    if robot.pulleys is None:
        vectors = robot.frame_points[None] - p[:, None, :] - Rb
    else:  # the free spans from where the cables leave their pulleys
        vectors = pulley_geometry(robot.frame_points, robot.pulleys, p[:, None, :] + Rb).free_spans
    lengths = np.linalg.norm(vectors, axis=2, keepdims=True)
    d = np.divide(vectors, lengths, out=np.full_like(vectors, np.nan), where=lengths > 1e-9)
    return np.concatenate([d, np.cross(Rb, d)], axis=2).transpose(0, 2, 1)


def static_wrench(robot: Robot, rows: tuple[int, ...] | None = None) -> Array:
    """The wrench the cables must exert to hold ``robot`` (its mass includes any payload) at rest: −w_g."""
    w = -gravity_wrench(robot)
    w6 = np.r_[w, 0.0, 0.0, 0.0] if w.shape == (3,) else w
    return w6[list(robot.controlled_rows if rows is None else rows)]


def wrench_feasible(
    robot: Robot,
    positions: ArrayLike,
    R: ArrayLike | None = None,
    payload: float = 0.0,
    tmin: ArrayLike | None = None,
    tmax: ArrayLike | None = None,
    *,
    rows: tuple[int, ...] | None = None,
) -> Mask:
    """At each position (n, 3) with orientation R (default identity): can tensions in [tmin, tmax]
    (default the robot's) hold the platform plus ``payload`` kg (at its centre of mass) at rest?

    ``rows`` (default ``robot.controlled_rows``) selects the wrench components that must be produced.
    """
    rows = robot.controlled_rows if rows is None else rows
    loaded = robot.with_payload(payload)
    W = wrench_matrices(robot, positions, R)[:, list(rows), :]
    lo = robot.tmin if tmin is None else tmin
    hi = robot.tmax if tmax is None else tmax
    return wrenches_feasible(W, static_wrench(loaded, rows), lo, hi)


@dataclass(frozen=True)
class Workspace:
    """The static wrench-feasible workspace sampled on a grid over the robot's frame box."""

    points: Array  # (n, 3) centre-of-mass positions, world frame
    feasible: Mask  # (n,)
    shape: tuple[int, int, int]  # grid points along x, y, z (points are in C order over them)
    spacing: Array  # (3,) grid spacing, m (0 along an axis with one point)

    @property
    def fraction(self) -> float:
        return float(self.feasible.mean()) if self.feasible.size else 0.0

    def bounding_box(self) -> tuple[Array, Array] | None:
        """(min, max) corners of the feasible points, or None when there are none."""
        if not self.feasible.any():
            return None
        good = self.points[self.feasible]
        return good.min(axis=0), good.max(axis=0)


def grid_points(robot: Robot, step: float) -> tuple[Array, tuple[int, int, int], Array]:
    """Cell-centred grid over the frame box: along each axis ⌈L/step⌉ cells of size L/⌈L/step⌉ ≤ step.

    Planar robots are sampled in their plane only (0 along its normal). Returns (points (n, 3), shape, spacing).
    """
    if not (math.isfinite(step) and step > 0.0):
        raise ValueError(f"step must be a positive length (got {step})")
    lo, hi = np.asarray(robot.frame_min, dtype=float), np.asarray(robot.frame_max, dtype=float)
    axes, spacing = [], np.zeros(3)
    for j in range(3):
        if robot.mode == "planar" and j == robot.normal_axis:
            axes.append(np.zeros(1))
            continue
        count = max(1, math.ceil((hi[j] - lo[j]) / step - 1e-9))
        spacing[j] = (hi[j] - lo[j]) / count
        axes.append(lo[j] + spacing[j] * (np.arange(count) + 0.5))
    shape = (len(axes[0]), len(axes[1]), len(axes[2]))
    points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    return points, shape, spacing


def compute_workspace(
    robot: Robot,
    step: float,
    R: ArrayLike | None = None,
    payload: float = 0.0,
    tmin: ArrayLike | None = None,
    tmax: ArrayLike | None = None,
) -> Workspace:
    """The static workspace of ``robot`` (+ ``payload``) at orientation R on a grid of ``step`` m."""
    points, shape, spacing = grid_points(robot, step)
    return Workspace(points, wrench_feasible(robot, points, R, payload, tmin, tmax), shape, spacing)


@dataclass(frozen=True)
class Violation:
    """The first trajectory sample whose wrench no admissible tensions produce."""

    t: float
    position: Array
    kind: str  # "static" (holding the pose) or "dynamic" (the desired acceleration's wrench)


def sample_times(trajectory: Trajectory, period: float = SAMPLE_PERIOD) -> Array:
    """Every ``period`` s from the first waypoint to the end, plus each waypoint's time, sorted."""
    stops = [t for t, _ in trajectory.waypoints()]
    t0, t1 = stops[0], trajectory.duration
    grid = t0 + period * np.arange(math.floor((t1 - t0) / period) + 1)
    return np.unique(np.concatenate([grid[grid <= t1], stops]))


def first_violation(
    robot: Robot, trajectory: Trajectory, variant: Variant = "6dof", period: float = SAMPLE_PERIOD
) -> Violation | None:
    """The earliest sample of ``trajectory`` (see :func:`sample_times`) that leaves the workspace, or None.

    Each sample is checked twice on the rows ``variant`` controls (:func:`cdpr.mechanics.control.controlled_rows`):
    static (−w_g, the platform at rest there) and dynamic (the feed-forward wrench of the desired
    acceleration, :func:`cdpr.mechanics.dynamics.required_wrench`), with the robot's tmin, tmax and mass.
    """
    from cdpr.mechanics.control import controlled_rows

    rows = list(controlled_rows(robot, variant))
    times = sample_times(trajectory, period)
    samples = [trajectory.sample(float(t)) for t in times]
    positions = np.array([s.position for s in samples])
    rotations = np.array([s.rotation for s in samples])
    dynamic = np.array(
        [
            required_wrench(
                robot, s.rotation, s.twist, s.accel[:3] if robot.mode == "point_mass" else s.accel
            )
            for s in samples
        ]
    )
    if dynamic.shape[1] == 3:
        dynamic = np.pad(dynamic, ((0, 0), (0, 3)))
    W = wrench_matrices(robot, positions, rotations)[:, rows, :]
    static_ok = wrenches_feasible(W, static_wrench(robot, tuple(rows)), robot.tmin, robot.tmax)
    dynamic_ok = wrenches_feasible(W, dynamic[:, rows], robot.tmin, robot.tmax)
    bad = np.flatnonzero(~(static_ok & dynamic_ok))
    if bad.size == 0:
        return None
    i = int(bad[0])
    return Violation(float(times[i]), positions[i].copy(), "static" if not static_ok[i] else "dynamic")


def check_trajectory(robot: Robot, trajectory: Trajectory, variant: Variant, where: str) -> None:
    """Raise :class:`InputError` (one line, naming ``where``) if the trajectory leaves the workspace."""
    v = first_violation(robot, trajectory, variant)
    if v is None:
        return
    what = (
        "hold the platform there" if v.kind == "static" else "produce the wrench of the desired acceleration"
    )
    pos = ", ".join(f"{x:.3f}" for x in v.position)
    raise InputError(
        f"{where}: trajectory: leaves the wrench-feasible workspace at t = {v.t:.2f} s (position [{pos}]): "
        f"no tensions in {robot.tension_limits_text()} {what}"
    )


def why_not_held(robot: Robot, position: ArrayLike, R: ArrayLike | None = None) -> str:
    """Why no tensions within the limits hold the platform at rest at this pose, in words a robot file's author
    can act on: the cables that would need more than their ``tmax`` (when pulling harder would do), or else the
    cables that would have to push and the wrench no pulling produces here (the least-squares tensions that
    pull at least ``tmin`` leave it unmet)."""
    from scipy.optimize import lsq_linear

    rows = list(robot.controlled_rows)
    W = wrench_matrices(robot, np.asarray(position, dtype=float)[None, :], R)[0][rows, :]
    w = static_wrench(robot, tuple(rows))
    scale = float(np.max(np.abs(w))) or 1.0
    pulled = lsq_linear(W, w, bounds=(robot.tmin, np.inf), method="bvls")
    unmet = W @ pulled.x - w
    if np.linalg.norm(unmet) <= 1e-6 * scale:  # pulling harder holds it: the limits are what is short
        over = np.flatnonzero(pulled.x > robot.tmax * (1 + 1e-9))
        return ("the cables would have to pull harder than their tmax: " + ", ".join(
            f"cable {i + 1} {pulled.x[i]:.0f} N > {robot.tmax[i]:g} N" for i in over))
    names = ("fx", "fy", "fz", "mx", "my", "mz")
    slack = [i + 1 for i in np.flatnonzero(pulled.x <= robot.tmin + 1e-9 * scale)]
    wrench = ", ".join(f"{names[r]} {-u:+.4g}" for r, u in zip(rows, unmet, strict=True) if abs(u) > 1e-6 * scale)
    return (f"pulling alone cannot: the wrench {wrench} (N, N·m) is missing"
            + (f", and cable(s) {', '.join(map(str, slack))} would have to push" if slack else ""))


def find_held_pose(robot: Robot, near: ArrayLike, R: ArrayLike | None = None, step: float | None = None
                   ) -> Array | None:
    """The centre-of-mass position nearest ``near`` at which tensions within the limits hold the platform at rest
    with orientation ``R`` (on a grid over the frame box, refined once around the best point); None when none
    is."""
    lo, hi = np.asarray(robot.frame_min), np.asarray(robot.frame_max)
    coarse = step if step is not None else float(np.max(hi - lo)) / 20
    best: Array | None = None
    target = np.asarray(near, dtype=float)
    for h, box in ((coarse, (lo, hi)), (coarse / 10, None)):
        if box is None:
            if best is None:
                return None
            box = (np.maximum(lo, best - coarse), np.minimum(hi, best + coarse))
        axes = [np.arange(a, b + 1e-12, h) if b - a > 1e-12 else np.array([a]) for a, b in zip(*box, strict=True)]
        if robot.mode == "planar":  # its points stay in its plane
            axes[robot.normal_axis] = np.array([0.0])
        pts = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        ok = wrench_feasible(robot, pts, R)
        if ok.any():
            good = pts[ok]
            best = good[int(np.argmin(np.linalg.norm(good - target, axis=1)))]
    return best
