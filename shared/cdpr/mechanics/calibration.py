"""Calibration from what a cable robot measured: its frame's exit points, its encoders' zero errors, its platform's
mass. Pure numpy, no I/O (``cdpr calibrate`` reads the recording: :mod:`cdpr.tools.calibrate`).

The geometric model (straight cables, a spatial robot; docs/calibration.md)
-------------------------------------------------------------------------
At sample k the platform's centre of mass is at ``p_k`` with orientation ``R_k``; cable i's encoder reads

    e_ik = ‖a_i − p_k − R_k b_i‖ + o_i + noise      (σ_e: the encoders' noise and quantisation, √(σ² + q²/12))

with ``a_i`` the frame's exit point, ``b_i`` the platform point (from the centre of mass, as everywhere in
:mod:`cdpr.mechanics`) and ``o_i`` the encoder's zero error (the robot file's ``encoder_offset``). A laser tracker
reads its reflector ``c`` (platform frame) at ``y_k = p_k + R_k c + noise`` (σ_t per axis, growing with range).
Unknowns: every sample's pose (6 each) and the parameters θ = [a_i (3m), o_i (m), optionally b_i (3m)]. The
whitened least-squares problem is solved by Gauss–Newton with the poses eliminated (the Schur complement: each
pose's 6 × 6 block is independent of the others'), a halving line search on the cost, the poses first fitted by
forward kinematics of the nominal robot.

Identifiability: the reduced normal matrix ``S`` (θ × θ, the poses eliminated) is the information the data hold
on θ. Its eigenvalues below ``1e-10 ×`` the largest span what the data cannot tell apart (without a tracker, a
rigid motion of the whole frame and of every pose changes no length: 6 such directions); a parameter is
*identifiable* when its unit vector lies within 1 % of S's range. The step is the minimum-norm one (the change
from the nominal robot that the data ask for and no more), so a parameter that is not identifiable is reported at
the value the least change gives, and named. Each parameter's standard uncertainty is √(S⁺)_jj (the noise as
given; the reduced χ² says whether it was); the condition number is √(λ_max / λ_min) over S's range.

Mass (dynamic part): Newton's law for the centre of mass, ``Σ_i (f_i + c l̇_i) u_i = M (a − g) = M R s``, with
``u_i`` the unit vector from the platform point to the exit point, ``f_i`` the tension the load cell measures,
``c l̇_i`` the cable's viscous damping (the robot file's ``damping.cable``: a cable lengthening at l̇ pulls that
much more than its winch's tension; l̇ from the encoders) and ``s`` the IMU's specific force (platform frame, the
IMU at the centre of mass). Each load cell's bias β_i (its reading f̃_i minus the tension) is identified with the
mass and the damping: ``Σ (f̃_i − β_i + c l̇_i) u_i = M R s``, linear least squares over every sample.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from cdpr.errors import InputError
from cdpr.mechanics.forward import ForwardKinematics
from cdpr.mechanics.robot import Robot
from cdpr.mechanics.rotation import Array, rotvec_to_matrix, skew

NULL_EIGENVALUE = 1e-10  # × the largest: S's eigenvalues below this span what the data cannot tell apart
IDENTIFIABLE = 0.01  # a parameter whose unit vector lies farther than this (squared norm) from S's range: not
MAX_ITERATIONS = 60
STEP_TOL = 1e-10  # m (and rad): the largest parameter and pose step at convergence


@dataclass(frozen=True)
class Samples:
    """What the robot measured at N instants: encoder readings and, when there is a tracker, its positions."""

    encoders: Array  # (N, m) readings, m
    encoder_sigma: float  # each reading's standard deviation, m
    tracker: Array | None = None  # (N, 3) the reflector's measured positions, world frame (NaN rows: no reading)
    tracker_sigma: Array | None = None  # (N,) each axis's standard deviation, m
    reflector: Array = field(default_factory=lambda: np.zeros(3))  # c, platform frame from the centre of mass


@dataclass(frozen=True)
class Parameter:
    """One identified parameter: ``name`` as the robot file says it (``cables.3.frame.x``)."""

    name: str
    nominal: float
    value: float
    sigma: float  # standard uncertainty (as identified; for a parameter not identifiable, along S's range only)
    identifiable: bool
    unit: str = "m"


@dataclass(frozen=True)
class Fit:
    """The residuals of a fit: encoders (N, m) and tracker (N, 3), m (NaN where no reading)."""

    encoders: Array
    tracker: Array | None

    def rms(self) -> tuple[float, float | None]:
        e = float(np.sqrt(np.nanmean(self.encoders ** 2)))
        t = None if self.tracker is None else float(np.sqrt(np.nanmean(self.tracker ** 2)))
        return e, t


@dataclass(frozen=True)
class GeometryCalibration:
    parameters: tuple[Parameter, ...]
    frame_points: Array  # (m, 3)
    encoder_offsets: Array  # (m,)
    platform_points: Array  # (m, 3) (the nominal ones unless identified)
    positions: Array  # (N, 3) every sample's fitted pose
    rotations: Array  # (N, 3, 3)
    before: Fit  # the nominal robot, its poses fitted
    after: Fit
    chi2_dof: float  # the reduced χ² of the fit (≈ 1 when the noise is as given)
    condition: float  # of the whitened identification problem over S's range
    rank: int
    unknowns: int  # parameters (the poses eliminated)
    null_space: Array  # (unknowns, unknowns − rank): what the data cannot tell apart
    gauge: str  # what the null space is: "frame" / "platform" / "frame and platform" (rigid motions), "" else
    iterations: int


@dataclass(frozen=True)
class MassCalibration:
    parameters: tuple[Parameter, ...]  # platform.mass, damping.cable (when the rates are given), load_cells.bias.i
    mass: float
    mass_sigma: float
    biases: Array  # (m,)
    residual_rms: float  # N, of the force balance
    samples: int


def _names(m: int, platform: bool) -> list[str]:
    names = [f"cables.{i}.frame.{x}" for i in range(m) for x in "xyz"]
    names += [f"cables.{i}.encoder_offset" for i in range(m)]
    if platform:
        names += [f"cables.{i}.platform.{x}" for i in range(m) for x in "xyz"]
    return names


class _Problem:
    """The whitened least-squares problem over N samples (module docstring)."""

    def __init__(self, robot: Robot, samples: Samples, platform: bool) -> None:
        E = np.asarray(samples.encoders, dtype=float)
        self.N, self.m = E.shape
        self.E = E
        self.se = float(samples.encoder_sigma)
        self.platform = platform
        self.tracked = samples.tracker is not None
        if self.tracked:
            Y = np.asarray(samples.tracker, dtype=float)
            sigma = np.asarray(samples.tracker_sigma, dtype=float)
            self.has_y = np.all(np.isfinite(Y), axis=1)
            self.Y = np.where(self.has_y[:, None], Y, 0.0)
            self.wy = np.where(self.has_y, 1.0 / sigma, 0.0)  # no reading: a zero-weight row
            self.c = np.asarray(samples.reflector, dtype=float)
        self.rows = self.m + (3 if self.tracked else 0)
        self.P = 4 * self.m + (3 * self.m if platform else 0)

    def unpack(self, theta: Array, b0: Array) -> tuple[Array, Array, Array]:
        m = self.m
        A = theta[:3 * m].reshape(m, 3)
        o = theta[3 * m:4 * m]
        B = theta[4 * m:].reshape(m, 3) if self.platform else b0
        return A, o, B

    def residuals(self, theta: Array, b0: Array, p: Array, R: Array) -> tuple[Array, Array | None]:
        """Unwhitened residuals (prediction − reading): encoders (N, m), tracker (N, 3) or None."""
        A, o, B = self.unpack(theta, b0)
        Rb = np.einsum("kxy,iy->kix", R, B)
        v = A[None] - p[:, None, :] - Rb
        e = np.linalg.norm(v, axis=2) + o - self.E
        if not self.tracked:
            return e, None
        y = p + R @ self.c - self.Y
        return e, np.where(self.has_y[:, None], y, np.nan)

    def cost(self, theta: Array, b0: Array, p: Array, R: Array) -> float:
        e, y = self.residuals(theta, b0, p, R)
        c = float(np.sum((e / self.se) ** 2))
        if y is not None:
            c += float(np.sum(np.nan_to_num(y * self.wy[:, None]) ** 2))
        return c

    def linearise(self, theta: Array, b0: Array, p: Array, R: Array) -> tuple[Array, Array, Array]:
        """Whitened residuals r (N, rows), ∂r/∂pose (N, rows, 6), ∂r/∂θ (N, rows, P)."""
        m, N = self.m, self.N
        A, o, B = self.unpack(theta, b0)
        Rb = np.einsum("kxy,iy->kix", R, B)
        v = A[None] - p[:, None, :] - Rb
        lengths = np.linalg.norm(v, axis=2)
        d = v / lengths[..., None]
        r = np.zeros((N, self.rows))
        Jx = np.zeros((N, self.rows, 6))
        Jt = np.zeros((N, self.rows, self.P))
        w = 1.0 / self.se
        r[:, :m] = (lengths + o - self.E) * w
        Jx[:, :m, :3] = -d * w
        Jx[:, :m, 3:] = np.cross(d, Rb) * w
        cables = np.arange(m)
        for x in range(3):
            Jt[:, cables, 3 * cables + x] = d[..., x] * w
        Jt[:, cables, 3 * m + cables] = w
        if self.platform:
            dR = -np.einsum("kix,kxy->kiy", d, R) * w  # ∂l/∂b_i = −dᵀ R
            for x in range(3):
                Jt[:, cables, 4 * m + 3 * cables + x] = dR[..., x]
        if self.tracked:
            Rc = R @ self.c
            wy = self.wy[:, None]
            r[:, m:] = (p + Rc - self.Y) * wy
            Jx[:, m:, :3] = np.eye(3)[None] * wy[..., None]
            Jx[:, m:, 3:] = -np.array([skew(x) for x in Rc]) * wy[..., None]
        return r, Jx, Jt


def _moved(p: Array, R: Array, dx: Array) -> tuple[Array, Array]:
    turns = np.array([rotvec_to_matrix(w) for w in dx[:, 3:]])
    return p + dx[:, :3], turns @ R


def fit_poses(robot: Robot, encoders: ArrayLike, offsets: ArrayLike | None = None) -> tuple[Array, Array]:
    """Each sample's pose by forward kinematics of its encoder readings (minus ``offsets``), warm-started from the
    sample before (the first from the robot's home pose)."""
    fk = ForwardKinematics(robot)
    E = np.asarray(encoders, dtype=float) - (0.0 if offsets is None else np.asarray(offsets, dtype=float))
    positions, rotations = np.zeros((len(E), 3)), np.zeros((len(E), 3, 3))
    for k, lengths in enumerate(E):
        res = fk.solve(lengths)
        positions[k], rotations[k] = res.position, res.rotation
    return positions, rotations


def _pose_steps(r: Array, Jx: Array) -> Array:
    U = np.einsum("kra,krb->kab", Jx, Jx)
    g = np.einsum("kra,kr->ka", Jx, r)
    return -np.linalg.solve(U, g[..., None])[..., 0]


def calibrate_geometry(robot: Robot, samples: Samples, *, platform_points: bool = False,
                       max_iterations: int = MAX_ITERATIONS) -> GeometryCalibration:
    """Identify the exit points and the encoders' zero errors (and the platform points) from ``samples``
    (module docstring); InputError for a robot or samples this model does not cover."""
    if robot.mode != "spatial":
        raise InputError(f"calibration: a spatial robot's (this one is {robot.mode})")
    if robot.pulleys is not None:
        raise InputError("calibration: robots with exit pulleys are not covered (their exit points move with the "
                         "cable): give the robot's straight-cable model")
    E = np.asarray(samples.encoders, dtype=float)
    if E.ndim != 2 or E.shape[1] != robot.m:
        raise InputError(f"encoders: expected readings of {robot.m} cables, got shape {E.shape}")
    if not np.all(np.isfinite(E)):
        raise InputError("encoders: every sample needs every cable's reading (NaN found)")
    if not samples.encoder_sigma > 0.0:
        raise InputError("encoder_sigma: must be > 0 (the readings' noise)")
    if samples.tracker is not None and not np.all(np.asarray(samples.tracker_sigma, dtype=float) > 0.0):
        raise InputError("tracker_sigma: must be > 0 (the readings' noise)")
    problem = _Problem(robot, samples, platform_points)
    m, N = robot.m, len(E)
    unknowns = problem.P
    if N * (problem.rows - 6) < unknowns:
        raise InputError(f"samples: {N} samples of {problem.rows} readings leave {N * (problem.rows - 6)} equations "
                         f"beyond the poses for {unknowns} parameters: record more poses")
    b0 = np.array(robot.platform_points, dtype=float)
    theta0 = np.concatenate([np.array(robot.frame_points).ravel(), np.array(robot.encoder_offsets),
                             b0.ravel() if platform_points else np.zeros(0)])
    p, R = fit_poses(robot, E, robot.encoder_offsets)
    # the nominal robot, its poses fitted: the residuals before
    for _ in range(20):
        r, Jx, _ = problem.linearise(theta0, b0, p, R)
        dx = _pose_steps(r, Jx)
        p, R = _moved(p, R, dx)
        if np.abs(dx).max() < STEP_TOL:
            break
    before = Fit(*problem.residuals(theta0, b0, p, R))
    theta = theta0.copy()
    cost = problem.cost(theta, b0, p, R)
    iterations = 0
    S = np.eye(unknowns)
    for iterations in range(1, max_iterations + 1):  # noqa: B007 (the count is reported)
        r, Jx, Jt = problem.linearise(theta, b0, p, R)
        U = np.einsum("kra,krb->kab", Jx, Jx)
        W = np.einsum("kra,krj->kaj", Jx, Jt)
        gx = np.einsum("kra,kr->ka", Jx, r)
        V = np.einsum("kri,krj->ij", Jt, Jt)
        gt = np.einsum("kri,kr->i", Jt, r)
        Uinv_W = np.linalg.solve(U, W)
        Uinv_g = np.linalg.solve(U, gx[..., None])[..., 0]
        S = V - np.einsum("kai,kaj->ij", W, Uinv_W)
        rhs = gt - np.einsum("kai,ka->i", W, Uinv_g)
        dtheta = -_min_norm_solve(S, rhs)
        dx = -(Uinv_g + np.einsum("kaj,j->ka", Uinv_W, dtheta))
        scale = 1.0
        while True:
            p1, R1 = _moved(p, R, scale * dx)
            theta1 = theta + scale * dtheta
            cost1 = problem.cost(theta1, b0, p1, R1)
            if cost1 <= cost * (1.0 + 1e-12) or scale < 1e-3:
                break
            scale *= 0.5
        if cost1 > cost * (1.0 + 1e-12):  # no step lowers the cost: at the minimum, to rounding
            break
        theta, p, R, cost = theta1, p1, R1, cost1
        if scale * max(np.abs(dtheta).max(), np.abs(dx).max()) < STEP_TOL:
            break
    after = Fit(*problem.residuals(theta, b0, p, R))
    # the information on θ at the solution (S of the last linearisation is at the step before: once more)
    r, Jx, Jt = problem.linearise(theta, b0, p, R)
    U = np.einsum("kra,krb->kab", Jx, Jx)
    W = np.einsum("kra,krj->kaj", Jx, Jt)
    S = np.einsum("kri,krj->ij", Jt, Jt) - np.einsum("kai,kaj->ij", W, np.linalg.solve(U, W))
    S = 0.5 * (S + S.T)
    lam, Q = np.linalg.eigh(S)
    keep = lam > NULL_EIGENVALUE * lam.max()
    rank = int(keep.sum())
    null = Q[:, ~keep]
    cov = (Q[:, keep] / lam[keep]) @ Q[:, keep].T
    dof = max(1, int(np.sum(np.isfinite(after.encoders))) + (0 if after.tracker is None else int(
        np.sum(np.isfinite(after.tracker)))) - 6 * N - rank)
    chi2 = float(cost / dof)
    # for the noise as given; a reduced χ² above 1 says the readings were noisier: the uncertainties grow with it
    sigma = np.sqrt(np.clip(np.diag(cov), 0.0, None) * max(1.0, chi2))
    in_null = np.sum(null ** 2, axis=1)
    condition = float(np.sqrt(lam[keep].max() / lam[keep].min())) if rank else float("inf")
    names = _names(m, platform_points)
    params = tuple(Parameter(n, float(v0), float(v), float(s), bool(q <= IDENTIFIABLE))
                   for n, v0, v, s, q in zip(names, theta0, theta, sigma, in_null, strict=True))
    A, o, B = problem.unpack(theta, b0)
    return GeometryCalibration(params, A.copy(), o.copy(), np.array(B, dtype=float), p, R, before, after,
                               chi2, condition, rank, unknowns, null,
                               _gauge(null, A, B if platform_points else None), iterations)


def _min_norm_solve(S: Array, b: Array) -> Array:
    """The minimum-norm solution of S x = b over S's range (its eigenvalues above NULL_EIGENVALUE × the largest)."""
    lam, Q = np.linalg.eigh(0.5 * (S + S.T))
    keep = lam > NULL_EIGENVALUE * lam.max()
    return np.asarray((Q[:, keep] / lam[keep]) @ (Q[:, keep].T @ b))


def rigid_motions(frame_points: ArrayLike, platform_points: ArrayLike | None = None) -> Array:
    """The directions in θ (:func:`calibrate_geometry`'s order) of a rigid motion of the frame's exit points (3
    translations, 3 small rotations about the origin) and, when the platform points are unknowns too, of theirs:
    columns, not normalised. A rigid motion of the frame (or of the platform frame) with every pose moved to match
    changes no cable length."""
    A = np.asarray(frame_points, dtype=float)
    m = len(A)
    B = None if platform_points is None else np.asarray(platform_points, dtype=float)
    G = np.zeros((4 * m + (0 if B is None else 3 * m), 6 if B is None else 12))
    for i in range(m):
        G[3 * i:3 * i + 3, :3] = np.eye(3)
        G[3 * i:3 * i + 3, 3:6] = -skew(A[i])
        if B is not None:
            G[4 * m + 3 * i:4 * m + 3 * i + 3, 6:9] = np.eye(3)
            G[4 * m + 3 * i:4 * m + 3 * i + 3, 9:] = -skew(B[i])
    return G


def _gauge(null: Array, frame_points: Array, platform_points: Array | None) -> str:
    """What the directions the data cannot tell apart are: rigid motions of the ``frame``, of the ``platform``
    frame's points, of ``frame and platform``, or "" (none, or not only rigid motions)."""
    if null.shape[1] == 0:
        return ""
    G = rigid_motions(frame_points, platform_points)

    def within(cols: Array) -> bool:
        coef, *_ = np.linalg.lstsq(cols, null, rcond=None)
        return bool(np.abs(cols @ coef - null).max() < 1e-3)

    if within(G[:, :6]):
        return "frame"
    if platform_points is not None and within(G[:, 6:]):
        return "platform"
    return "frame and platform" if platform_points is not None and within(G) else ""


def calibrate_mass(robot: Robot, frame_points: ArrayLike, positions: ArrayLike, rotations: ArrayLike,
                   tensions: ArrayLike, accel: ArrayLike, rates: ArrayLike | None = None, *,
                   biases: bool = True) -> MassCalibration:
    """The platform's mass, the cables' viscous damping (with ``rates``) and each load cell's bias from Newton's law
    for the centre of mass over the samples (module docstring): ``frame_points`` as calibrated, the poses as fitted,
    ``tensions`` (N, m) the load cells', ``accel`` (N, 3) the IMU's specific force, ``rates`` (N, m) the cables'
    length rates (m/s, from the encoders)."""
    A = np.asarray(frame_points, dtype=float)
    p, R = np.asarray(positions, dtype=float), np.asarray(rotations, dtype=float)
    F, s = np.asarray(tensions, dtype=float), np.asarray(accel, dtype=float)
    rate = None if rates is None else np.asarray(rates, dtype=float)
    ok = np.all(np.isfinite(F), axis=1) & np.all(np.isfinite(s), axis=1)
    if rate is not None:
        ok &= np.all(np.isfinite(rate), axis=1)
    if ok.sum() < 2:
        raise InputError("load_cells and imu: the mass needs samples with both readings (found "
                         f"{int(ok.sum())})")
    p, R, F, s = p[ok], R[ok], F[ok], s[ok]
    N, m = F.shape
    v = A[None] - p[:, None, :] - np.einsum("kxy,iy->kix", R, np.asarray(robot.platform_points, dtype=float))
    u = v / np.linalg.norm(v, axis=2)[..., None]  # (N, m, 3): the pull of each cable on the platform
    y = np.einsum("ki,kix->kx", F, u).ravel()  # Σ f̃_i u_i
    columns = [np.einsum("kxy,ky->kx", R, s).ravel()]  # M
    names: list[tuple[str, float, str]] = [("platform.mass", float(robot.mass), "kg")]
    if rate is not None:  # a cable lengthening at l̇ pulls c l̇ more than its tension: −c
        columns.append(np.einsum("ki,kix->kx", rate[ok], u).ravel())
        names.append(("damping.cable", float(robot.cable_damping), "N·s/m"))
    if biases:
        columns += list(u.transpose(0, 2, 1).reshape(3 * N, m).T)
        names += [(f"load_cells.bias.{i}", 0.0, "N") for i in range(m)]
    X = np.stack(columns, axis=1)
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    res = y - X @ coef
    s2 = float(res @ res) / max(1, len(y) - X.shape[1])
    XtX = X.T @ X
    lam, Q = np.linalg.eigh(XtX)
    keep = lam > NULL_EIGENVALUE * lam.max()
    sig = np.sqrt(np.clip(np.diag(s2 * (Q[:, keep] / lam[keep]) @ Q[:, keep].T), 0.0, None))
    ident = np.sum(Q[:, ~keep] ** 2, axis=1) <= IDENTIFIABLE
    if rate is not None:
        coef[1] = -coef[1]
    params = tuple(Parameter(n, nominal, float(c), float(sd), bool(ok_), unit)
                   for (n, nominal, unit), c, sd, ok_ in zip(names, coef, sig, ident, strict=True))
    b = coef[len(names) - m:] if biases else np.zeros(m)
    return MassCalibration(params, float(coef[0]), float(sig[0]), np.array(b, dtype=float),
                           float(np.sqrt(np.mean(res ** 2))), N)
