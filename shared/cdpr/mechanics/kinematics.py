"""Cable kinematics (seed paper eq. 2–4). Pure numpy, no I/O.

Sign convention, stated once for the whole project
--------------------------------------------------
* Cable vector (eq. 2): ``l_i = a_i − t − R b_i``, pointing from the platform to the frame.
  Length ``‖l_i‖``, unit vector ``d_i = l_i / ‖l_i‖``.
* Length Jacobian (eq. 3–4): ``l̇ = J v`` with the twist ``v = [ṫ; ω]`` (world frame, linear first)
  and row i of J equal to ``[−d_iᵀ, (d_i × R b_i)ᵀ]``, exactly as in the paper.
* Wrench matrix: ``W f`` is the wrench ``[force; moment about the centre of mass]`` (world frame) that
  the tensions ``f ≥ 0`` exert on the platform. Column i is ``[d_i; (R b_i) × d_i]``, so ``W = −Jᵀ``:
  the paper writes ``W = Jᵀ`` and absorbs the minus sign into its wrench, we keep it visible here.
  Equilibrium of eq. 5 then reads ``M ẍ + C ẋ = W f + w_g + w_e``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from cdpr.errors import InputError
from cdpr.mechanics.forward import MAX_ITERATIONS, TOL, ForwardKinematics
from cdpr.mechanics.pulley import Pulleys, pulley_geometry
from cdpr.mechanics.robot import Robot
from cdpr.mechanics.rotation import Array, cross_rows


@dataclass(frozen=True)
class CableKinematics:
    vectors: Array  # (m, 3) l_i, platform → frame (over a pulley: the free span, platform → where it leaves the wheel)
    lengths: Array  # (m,) (over a pulley: the wrapped arc plus the free span)
    directions: Array  # (m, 3) unit d_i
    platform_points_world: Array  # (m, 3) t + R b_i
    wrench_matrix: Array  # (6, m) W = −Jᵀ

    @property
    def jacobian(self) -> Array:
        """Length Jacobian J (m × 6) of eq. 4: l̇ = J v."""
        return -self.wrench_matrix.T


def cable_vectors(frame_points: Array, platform_points: Array, position: Array, R: Array
                  ) -> tuple[Array, Array, Array]:
    """Eq. 2 for every cable: ``(arms R b_i, vectors l_i, lengths ‖l_i‖)``, each row a cable. The one
    place cable lengths are computed (:func:`cable_geometry` and the others build on it)."""
    arms = platform_points @ R.T  # (m, 3) rows R b_i
    vectors = frame_points - position - arms  # rows l_i, platform → frame
    return arms, vectors, np.sqrt(np.einsum("ij,ij->i", vectors, vectors))


def _chords(frame_points: Array, platform_points: Array, position: Array, R: Array, pulleys: Pulleys | None = None
            ) -> tuple[Array, Array, Array, Array, Array]:
    """:func:`cable_vectors` and the directions: ``(arms, vectors, lengths, unit d_i, moments (R b_i) × d_i)``.
    A zero length gives NaN directions (and a numpy warning, which callers that expect it silence).

    With ``pulleys`` (:mod:`cdpr.mechanics.pulley`), a cable's vector is its free span T_i − B_i from the platform
    to where it leaves its pulley, d_i that span's direction and its length the wrapped arc plus the span."""
    if pulleys is None:
        arms, vectors, lengths = cable_vectors(frame_points, platform_points, position, R)
        d = vectors / lengths[:, None]
        return arms, vectors, lengths, d, cross_rows(arms, d)
    arms = platform_points @ R.T
    g = pulley_geometry(frame_points, pulleys, position + arms)
    d = g.free_spans / g.free_lengths[:, None]
    return arms, g.free_spans, g.lengths, d, cross_rows(arms, d)


def _wrench_matrix(d: Array, moments: Array) -> Array:
    W = np.empty((6, len(d)))
    W[:3] = d.T
    W[3:] = moments.T
    return W


def cable_kinematics(frame_points: Array, platform_points: Array, position: ArrayLike, R: ArrayLike,
                     pulleys: Pulleys | None = None) -> CableKinematics:
    """Eq. 2–4 for arbitrary attach points (vectorised over cables), over exit pulleys if given."""
    t = np.asarray(position, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):
        arms, vectors, lengths, d, moments = _chords(frame_points, platform_points, t, np.asarray(R, dtype=float),
                                                     pulleys)
    return CableKinematics(vectors, lengths, d, t + arms, _wrench_matrix(d, moments))


class WrenchMatrix:
    """The wrench matrix W (6×m) of one robot at any pose, with the attach points set up once.

    ``W(position, R)`` equals ``inverse_kinematics(robot, position, R).wrench_matrix`` bit for bit,
    without the other outputs of :func:`cable_kinematics` (for the controller's every step).
    """

    def __init__(self, robot: Robot) -> None:
        self._a = np.array(robot.frame_points, dtype=float)
        self._b = np.array(robot.platform_points, dtype=float)
        self._pulleys = robot.pulleys

    def __call__(self, position: ArrayLike, R: ArrayLike) -> Array:
        _, _, _, d, moments = _chords(self._a, self._b, np.asarray(position, dtype=float), np.asarray(R, dtype=float),
                                      self._pulleys)
        return _wrench_matrix(d, moments)


def cable_geometry(
    frame_points: Array, platform_points: Array, position: Array, R: Array, v: Array, omega: Array,
    pulleys: Pulleys | None = None,
) -> tuple[Array, Array, Array, Array, Array, Array]:
    """The cables of a moving platform: ``(arms, lengths, directions, moments, rates, spans)``.

    ``arms`` (m, 3) are R b_i, ``lengths`` (m,) ‖l_i‖, ``directions`` (m, 3) the unit d_i (rows of W's
    force block), ``moments`` (m, 3) (R b_i) × d_i (rows of W's moment block) and ``rates`` (m,) the
    length rates l̇ = J v = −(d_i · v + ((R b_i) × d_i) · ω), for the platform at (position, R) moving
    with linear velocity ``v`` and angular velocity ``omega`` (world frame). What a simulator reads
    off its body every step; no checks (the lengths must not be zero). ``spans`` (m, 3) are the vectors l_i from
    the platform points to the frame. Over exit ``pulleys``: the lengths include the wrapped arcs, the spans and
    directions are the free spans' from where each cable leaves its pulley (and l̇ = J v still holds exactly).
    """
    arms, spans, lengths, d, moments = _chords(frame_points, platform_points, position, R, pulleys)
    return arms, lengths, d, moments, -(d @ v + moments @ omega), spans


def inverse_kinematics(robot: Robot, position: ArrayLike, R: ArrayLike | None = None) -> CableKinematics:
    """Cable vectors, lengths, unit vectors and wrench matrix of ``robot`` at pose (position, R)."""
    return cable_kinematics(robot.frame_points, robot.platform_points, position, np.eye(3) if R is None else R,
                            robot.pulleys)


def cable_length_rates(kin: CableKinematics, twist: ArrayLike) -> Array:
    """l̇ = J v for a world-frame twist [v; ω]."""
    return kin.jacobian @ np.asarray(twist, dtype=float)


def length_rates(robot: Robot, position: ArrayLike, R: ArrayLike, twist: ArrayLike) -> Array:
    """The length rates l̇ = J v of ``robot``'s cables at pose (position, R) moving with the world-frame twist
    [v; ω]: :func:`cable_geometry`'s (what :func:`cable_length_rates` gives, to rounding, for a fraction of
    its cost: no wrench matrix or Jacobian built)."""
    twist = np.asarray(twist, dtype=float)
    return cable_geometry(robot.frame_points, robot.platform_points, np.asarray(position, dtype=float),
                          np.asarray(R, dtype=float), twist[:3], twist[3:], robot.pulleys)[4]


@dataclass(frozen=True)
class ForwardKinematicsResult:
    position: Array
    rotation: Array
    residual: float  # max |l(x) − l| over cables, m
    converged: bool  # the solver converged and the lengths are consistent (residual < 1e-6 m)
    iterations: int = 0


def forward_kinematics(
    robot: Robot,
    lengths: ArrayLike,
    guess_position: ArrayLike | None = None,
    guess_rotation: ArrayLike | None = None,
    tol: float = TOL,
    max_iterations: int = MAX_ITERATIONS,
) -> ForwardKinematicsResult:
    """Pose whose cable lengths are ``lengths``: :class:`cdpr.mechanics.forward.ForwardKinematics` (Gauss–Newton /
    Levenberg–Marquardt on the analytic length Jacobian) from the guess, else from the home pose.

    With more cables than DOF the lengths over-determine the pose; the result is the least-squares
    pose and ``residual`` says how far the lengths are from consistent (``converged`` only when they are, to
    1e-6 m). Point-mass robots solve for the position only; planar robots for their plane's two coordinates and
    the rotation about its normal.
    """
    r = ForwardKinematics(robot, tol, max_iterations).solve(lengths, guess_position, guess_rotation)
    return ForwardKinematicsResult(r.position, r.rotation, r.residual, r.converged and r.residual < 1e-6,
                                   r.iterations)


def check_robot(robot: Robot, where: str) -> None:
    """Checks that need the whole robot: mode-specific geometry and the wrench matrix's rank."""
    if robot.m < robot.dof:
        raise InputError(
            f"{where}: cables: {robot.m} cable(s) cannot control the {robot.dof} DOF of a {robot.mode} robot"
        )
    if robot.mode == "point_mass" and np.abs(robot.platform_points).max() > 1e-12:
        raise InputError(f"{where}: cables: a point_mass robot needs every platform point at [0, 0, 0]")
    if robot.mode == "planar":
        n, axis, plane = robot.normal_axis, "xyz"[robot.normal_axis], f"{robot.plane[0]}–{robot.plane[1]}"
        for field, pts in (("platform.com", robot.com_offset[None, :]), ("home.position", robot.home_position[None, :]),
                           ("cables", np.vstack([robot.frame_points, robot.platform_points]))):
            if np.abs(pts[:, n]).max() > 1e-12:
                raise InputError(f"{where}: {field}: a planar robot lives in the {plane} plane: every {axis} must be 0")
    ik = inverse_kinematics(robot, robot.home_position, robot.home_rotation)
    free = np.linalg.norm(ik.vectors, axis=1)  # (over a pulley: NaN with the platform point on its wheel)
    if not np.all(free >= 1e-9):
        i = int(np.flatnonzero(~(free >= 1e-9))[0])
        what = "zero cable length" if robot.pulleys is None else "zero free length (the platform point on its pulley)"
        raise InputError(f"{where}: cables.{i}: {what} at the home pose")
    W = ik.wrench_matrix[list(robot.controlled_rows), :]
    rank = int(np.linalg.matrix_rank(W, tol=1e-9 * max(1.0, float(np.abs(W).max()))))
    if rank < robot.dof:
        raise InputError(
            f"{where}: cables: the wrench matrix has rank {rank} < {robot.dof} at the home pose "
            "(the cables cannot hold the platform there)"
        )


def pose_problems(robot: Robot, position: ArrayLike, R: ArrayLike | None = None, tol: float = 1e-9) -> list[str]:
    """Why a pose of the platform (its centre of mass at ``position``, orientation ``R``) is not one the robot
    can take, one phrase each (none: it can): a cable longer than its ``max_length``; the platform frame's origin
    below the floor (the frame box's bottom) or else outside the frame box; for a planar robot, a pose off its
    plane (a coordinate along the plane's normal, or a rotation about another axis). Wrench feasibility is
    another question (cdpr tda)."""
    p = np.asarray(position, dtype=float)
    Rm = np.eye(3) if R is None else np.asarray(R, dtype=float)
    lengths = inverse_kinematics(robot, p, Rm).lengths
    out = []
    if (over := np.flatnonzero(lengths > robot.max_length + tol)).size:
        out.append("beyond max_length: " + ", ".join(f"cable {i + 1} {lengths[i]:.4g} m > {robot.max_length[i]:g} m"
                                                     for i in over))
    origin = p - Rm @ robot.com_offset  # the platform frame's origin (what --pose gives)
    lo, hi = np.asarray(robot.frame_min), np.asarray(robot.frame_max)
    where = f"the platform at [{', '.join(f'{x:.6g}' for x in origin)}] m"
    if origin[2] < lo[2] - tol:
        out.append(f"{where} is below the floor (z = {lo[2]:g} m, the frame box's bottom)")
    elif np.any(origin < lo - tol) or np.any(origin > hi + tol):
        out.append(f"{where} is outside the frame box [{', '.join(f'{x:g}' for x in lo)}] … "
                   f"[{', '.join(f'{x:g}' for x in hi)}] m")
    if robot.mode == "planar":
        n = robot.normal_axis
        axis = np.eye(3)[n]
        if abs(p[n]) > tol or not np.allclose(Rm @ axis, axis, atol=1e-9):
            out.append(f"off the {robot.plane} plane of this planar robot (its {'xyz'[n]} must be 0 and its only "
                       f"rotation about {'xyz'[n]})")
    return out
