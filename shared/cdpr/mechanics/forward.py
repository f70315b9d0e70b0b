"""Forward kinematics (FK): the pose whose cable lengths are the measured ones. Pure numpy, no I/O.

Damped Gauss–Newton (Levenberg–Marquardt) on the analytic length Jacobian, for every robot the project
loads: ``spatial`` (position and orientation), ``planar`` (the plane's two coordinates and the turn about its
normal), ``point_mass`` (position only; the orientation stays the guess's), straight cables or over exit
pulleys, any cable set (the solver sees the robot's cables), any ``platform.com`` (the pose solved for is the
centre of mass's, as everywhere in :mod:`cdpr.mechanics`; ``position − R c`` is the platform frame's origin).

Model and conventions
---------------------
* Lengths ``l(x)`` are :func:`cdpr.mechanics.kinematics.cable_vectors`' ``‖a_i − t − R b_i‖``, over a pulley
  :func:`cdpr.mechanics.pulley.pulley_geometry`'s wrapped arc plus free span: the lengths IK gives.
* The pose moves on SO(3): a step ``δ = [δt; δφ]`` (world frame, linear first, as the twist of
  :mod:`cdpr.mechanics.kinematics`) takes ``(t, R)`` to ``(t + δt, exp([δφ]×) R)``. Its Jacobian is the length
  Jacobian of eq. 4, ``∂l/∂δ = J = −Wᵀ``, row i ``[−d_iᵀ, (d_i × R b_i)ᵀ]``; over a pulley ``d_i`` is the free
  span's direction (the wrap's change and the swivel's cancel: :mod:`cdpr.mechanics.pulley`), so the same rows
  hold exactly. A planar robot's columns are its plane's two and the turn about its normal; a point mass's the
  first three.
* Least squares: the solver minimises ``‖l(x) − L‖²``. Consistent lengths (as many as DOF, or more measured
  without error) give ``l(x) = L`` to rounding; noisy or inconsistent ones give the least-squares pose and
  the ``residual`` says how far apart they are.
* Steps: Gauss–Newton (λ = 0) while it lowers the cost; a step that does not is retried with Marquardt's
  damping ``(JᵀJ + λ diag(JᵀJ)) δ = −Jᵀ r`` and λ grows until one does (Nielsen's update after each accepted
  step; λ back to 0 once small). Every linear solve is one iteration, at most ``max_iterations`` (30) in all.
* Converged: an undamped step no larger than ``tol`` (1e-9, m and rad, ∞-norm; what is left after it is smaller
  still), or a damped one with λ ≤ 1 (about a least-squares pose of noisy lengths where Gauss–Newton alone
  diverges: a small singular value of J and a large residual); or, when the step makes the lengths consistent
  (every residual within 1e-7 m to first order: Gauss–Newton converges quadratically there), one no larger than
  ``√tol / 10`` whose ratio ρ to the step before bounds what is left, ``|δ| ρ / (1 − ρ) ≤ tol``. That last step
  is taken without another evaluation of the lengths: the residual reported is ``r + J δ``, to first order in the
  step (its error is below 1e-11 m), which saves a third evaluation in the warm-started loop (two iterations from
  a pose 1 ms of motion away). Noisy or inconsistent lengths converge linearly, to the ``tol`` step; about a
  nearly singular pose (CAROCA: 0.1–0.2 % of the noisy protocol's) more slowly than 30 iterations allow.
* Cold starts: a guess whose lengths are more than 3 cm (2-norm) off the measured ones gets half the iterations;
  if it stops short, or at a residual above ``restart_residual`` (1e-6 m: a wrong local minimum, or noisy
  lengths), the solver starts again from the home pose and from the guess's position at the home orientation,
  then goes on from where the first run stopped, within the same ``max_iterations``, and returns the best
  (the least residual). From the Mahnke & Caverly protocol's cold guesses (1 m and 2–40° off) this
  takes CoGiRo's and CAROCA's success from ~97–98 % to ~99.9 % (:mod:`cdpr.tools.bench.fk`). With as many cables
  as DOF the lengths have several poses: the one found is the one the guess leads to.
* Speed: a warm-started solve is some forty numpy calls on m × 3 arrays (each costs about what its arithmetic
  does): straight cables' lengths and Jacobian are computed inline in :meth:`ForwardKinematics._iterate`, the
  6 × 6 normal equations solved by numpy's LAPACK gufunc without :func:`numpy.linalg.solve`'s checks.

Elastic cables (optional): a winch's encoder gives the cable's unstretched length l0. The project's elastic
cable (``cdpr_sim.elastic``, :func:`cdpr.mechanics.catenary.unstretched_lengths`) holds the static tension
``f = EA (l − l0) / l0`` at the geometric length ``l`` (the whole length, frame point to platform point, wrap
included), so given the tensions ``f`` and each cable's ``EA`` the lengths solved for are
``l = l0 (1 + f / EA)`` (:func:`cdpr.mechanics.catenary.stretched_lengths`). Sag is not modelled here.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from cdpr.errors import InputError
from cdpr.mechanics.catenary import stretched_lengths
from cdpr.mechanics.pulley import pulley_geometry
from cdpr.mechanics.robot import Robot
from cdpr.mechanics.rotation import Array

TOL = 1e-9  # m and rad: the largest step left at convergence (∞-norm)
MAX_ITERATIONS = 30  # linear solves per pose
RESTART_RESIDUAL = 1e-6  # m: a cold solve that ends with a larger residual tries again (the module docstring)
COLD_RESIDUAL = 0.03  # m: a guess whose lengths are farther than this (2-norm) from the measured is a cold one
_CONSISTENT = 1e-7  # m: lengths a pose matches this well converge as consistent ones (quadratically)
_SMALL_STEP = 0.1  # × √tol: the largest last step the ratio test may accept (Gauss–Newton near consistent lengths)
_LAMBDA_START = 1e-3  # Marquardt's λ (relative to diag JᵀJ) when a Gauss–Newton step fails
_LAMBDA_OFF = 1e-7  # below this λ, back to undamped Gauss–Newton steps

# (E ⊗ d) K = [d, a × d] for E = [1, a]: the row i·3 + j of the outer product E_i d_j, mapped to the force
# column j (i = 0) or to the moment column 3 + k with ε_kij (i = 1 + the arm's component).
_FORCE_MOMENT = np.zeros((12, 6))
for _j in range(3):
    _FORCE_MOMENT[_j, _j] = 1.0
for _k, _i, _j, _sign in ((0, 1, 2, 1.0), (0, 2, 1, -1.0), (1, 2, 0, 1.0), (1, 0, 2, -1.0), (2, 0, 1, 1.0),
                          (2, 1, 0, -1.0)):
    _FORCE_MOMENT[3 + 3 * _i + _j, 3 + _k] = _sign
_FORCE_MOMENT.flags.writeable = False


def _numpy_solve(A: Array, b: Array) -> Array:
    try:
        return np.asarray(np.linalg.solve(A, b), dtype=float)
    except np.linalg.LinAlgError:
        return np.full(b.shape, np.nan)


# numpy's solve without its wrapper's checks (a third of the time of a warm-started solve): NaN for a singular
# matrix under np.errstate(invalid="ignore"), where np.linalg.solve raises (the fallback, should numpy move it).
_solve_linear: Callable[[Array, Array], Array] = getattr(getattr(np.linalg, "_umath_linalg", None), "solve1",
                                                         _numpy_solve)



def _einsum_vecdot(a: Array, b: Array) -> Array:
    return np.einsum("ij,ij->i", a, b)


# the row-wise dot product: numpy ≥ 2's gufunc, or the same by einsum on numpy 1.26 (the project's floor)
_vecdot: Callable[[Array, Array], Array] = getattr(np, "vecdot", _einsum_vecdot)


class ForwardResult(NamedTuple):
    """A forward kinematics solve. ``position`` and ``rotation`` are the centre of mass's (world frame). (A named
    tuple: cheaper to make than a frozen dataclass, in a loop that runs every millisecond.)"""

    position: Array  # (3,)
    rotation: Array  # (3, 3)
    iterations: int  # linear solves taken (rejected damped steps included)
    converged: bool  # the step criterion met within max_iterations (consistent lengths or not)
    residual: float  # max_i |l_i(x) − L_i|, m: ~1e-12 for consistent lengths, the noise's size otherwise
    residual_norm: float  # ‖l(x) − L‖₂, m (the least-squares cost's square root)


def _rotvec_entries(wx: float, wy: float, wz: float) -> tuple[float, ...]:
    """The nine entries (row by row) of exp([w]×) (Rodrigues; its series below 1e-4 rad)."""
    t2 = wx * wx + wy * wy + wz * wz
    if t2 < 1e-8:
        A = 1.0 - t2 / 6.0
        B = 0.5 - t2 / 24.0
    else:
        t = math.sqrt(t2)
        A = math.sin(t) / t
        B = (1.0 - math.cos(t)) / t2
    xy, xz, yz = B * wx * wy, B * wx * wz, B * wy * wz
    return (1.0 - B * (wy * wy + wz * wz), xy - A * wz, xz + A * wy,
            xy + A * wz, 1.0 - B * (wx * wx + wz * wz), yz - A * wx,
            xz - A * wy, yz + A * wx, 1.0 - B * (wx * wx + wy * wy))


def rotvec_matrix(wx: float, wy: float, wz: float) -> Array:
    """exp([w]×) for a rotation vector of Python floats: the FK's update (as
    :func:`cdpr.mechanics.rotation.rotvec_to_matrix`, without its numpy calls)."""
    return np.array(_rotvec_entries(wx, wy, wz)).reshape(3, 3)


class ForwardKinematics:
    """The forward kinematics of one robot, set up once: :meth:`solve` for each set of lengths.

    ``solve`` warm-starts from the previous solution when given no guess (the first from the robot's home pose):
    in a control loop, one ``ForwardKinematics`` per robot, ``solve(lengths)`` every step. Not thread-safe (it
    keeps work arrays).
    """

    def __init__(self, robot: Robot, tol: float = TOL, max_iterations: int = MAX_ITERATIONS,
                 restart_residual: float = RESTART_RESIDUAL) -> None:
        if not tol > 0.0:
            raise InputError(f"tol: must be > 0 (got {tol:.12g})")
        if max_iterations < 1:
            raise InputError(f"max_iterations: must be >= 1 (got {max_iterations})")
        self.robot = robot
        self.tol = float(tol)
        self.max_iterations = int(max_iterations)
        self.restart_residual = float(restart_residual)
        self._home_p = np.array(robot.home_position, dtype=float)
        self._home_R = np.array(robot.home_rotation, dtype=float)
        self._started_cold = False  # set by each run of _iterate
        self.mode = robot.mode
        self.dof = robot.dof
        m = self.m = robot.m
        self._a = np.ascontiguousarray(robot.frame_points, dtype=float)
        self._b = np.ascontiguousarray(robot.platform_points, dtype=float)
        self._pulleys = robot.pulleys
        # v = [a, −1, −b] @ [I; t; Rᵀ]: every cable vector a_i − t − R b_i in one product
        self._abm = np.hstack([self._a, -np.ones((m, 1)), -self._b])
        self._pose = np.zeros((7, 3))
        self._pose[:3] = np.eye(3)
        # [1, a_i − t] ⊗ d_i, whose product with _FORCE_MOMENT is [d_i, (a_i − t) × d_i] = [d_i, (R b_i) × d_i]
        self._outer = np.ones((m, 4, 3))
        self._left = np.ones((m, 4))
        self._arm = self._left[:, 1:]
        self._left3 = self._left[:, :, None]
        self._outer2 = self._outer.reshape(m, 12)
        self._unit3 = np.empty((m, 1, 3))  # the unit vectors d_i, as the outer product's right factor
        self._unit = self._unit3.reshape(m, 3)
        if robot.mode == "planar":
            n = robot.normal_axis
            self._plane = [j for j in range(3) if j != n]
            self._normal = n
            cols = [*self._plane, 3 + n]
        else:
            cols = [0, 1, 2] if robot.mode == "point_mass" else list(range(6))
        self._columns = np.ascontiguousarray(_FORCE_MOMENT[:, cols])
        self._turn = np.empty((3, 3))  # a step's exp([δφ]×)
        self._turn_entries = self._turn.reshape(9)
        self.position = np.array(robot.home_position, dtype=float)  # the last solution (the next warm start)
        self.rotation = np.array(robot.home_rotation, dtype=float)

    # ---------------------------------------------------------------------------------------------
    # The model: lengths at a pose, their Jacobian in the solver's coordinates

    def _lengths(self, p: Array, R: Array) -> tuple[Array, Array, Array, Array]:
        """``(lengths, the points the free spans leave the frame (a_i, over a pulley T_i), the vectors platform →
        there, their lengths)``."""
        if self._pulleys is None:
            pose = self._pose
            pose[3] = p
            pose[4:] = R.T
            v = np.dot(self._abm, pose)
            lf = np.sqrt(_vecdot(v, v))
            return lf, self._a, v, lf
        g = pulley_geometry(self._a, self._pulleys, self._b @ R.T + p)
        return g.lengths, g.tangent_points, g.free_spans, g.free_lengths

    def _wrench_rows(self, p: Array, exits: Array, v: Array, lf: Array) -> Array:
        """G = −J (m × dof): rows [d_i, (R b_i) × d_i] (those of Wᵀ; (R b_i) × d_i = (exit_i − t) × d_i, the
        platform point and the exit point on one line along d_i), the columns of the robot's coordinates.
        (:meth:`_iterate` has it inline.)"""
        np.subtract(exits, p, out=self._arm)
        np.multiply(self._left3, (v / lf[:, None])[:, None, :], out=self._outer)
        return np.dot(self._outer2, self._columns)

    def lengths(self, position: ArrayLike, R: ArrayLike) -> Array:
        """The cable lengths at the pose (the centre of mass at ``position``, orientation ``R``)."""
        return self._lengths(np.asarray(position, dtype=float), np.asarray(R, dtype=float))[0].copy()

    def jacobian(self, position: ArrayLike, R: ArrayLike) -> Array:
        """∂l/∂δ (m × dof) at the pose, in the solver's coordinates: spatial [δt; δφ] (world frame, R ← exp(δφ) R),
        planar [the plane's two coordinates; the turn about its normal], point mass δt."""
        p, Rm = np.asarray(position, dtype=float), np.asarray(R, dtype=float)
        return -self._wrench_rows(p, *self._lengths(p, Rm)[1:])

    def moved(self, position: ArrayLike, R: ArrayLike, step: ArrayLike) -> tuple[Array, Array]:
        """The pose a step in the solver's coordinates (:meth:`jacobian`) takes (position, R) to."""
        return self._moved(np.asarray(position, dtype=float), np.asarray(R, dtype=float),
                           np.asarray(step, dtype=float), np.asarray(step, dtype=float).tolist())

    def _moved(self, p: Array, R: Array, step: Array, s: list[float]) -> tuple[Array, Array]:
        if self.dof == 6:
            self._turn_entries[:] = _rotvec_entries(s[3], s[4], s[5])
            return p + step[:3], np.dot(self._turn, R)
        if self.mode == "point_mass":
            return p + step, R
        q = p.copy()
        q[self._plane] += step[:2]
        w = [0.0, 0.0, 0.0]
        w[self._normal] = s[2]
        return q, rotvec_matrix(*w) @ R

    # ---------------------------------------------------------------------------------------------
    # The solver

    def solve(self, lengths: ArrayLike, position: ArrayLike | None = None, rotation: ArrayLike | None = None, *,
              tensions: ArrayLike | None = None, EA: ArrayLike | None = None) -> ForwardResult:
        """The pose whose cable lengths are ``lengths`` (m, one per cable), from the guess (``position``: the
        centre of mass's; ``rotation``: 3×3), else from the last solution (warm start; at first the home pose).

        With ``tensions`` (N) and ``EA`` (N, one number or one per cable), ``lengths`` are unstretched lengths
        l0 and the geometric lengths ``l0 (1 + f/EA)`` are solved for (the module's docstring). The solution is
        kept as the next warm start when it converged.
        """
        L = np.asarray(lengths, dtype=float)
        if L.shape != (self.m,):
            raise InputError(f"lengths: expected {self.m} (one per cable), got {L.size}")
        if (tensions is None) != (EA is None):
            raise InputError("tensions and EA: give both (the elastic correction) or neither")
        if tensions is not None:
            f = np.asarray(tensions, dtype=float)
            if f.shape != (self.m,):
                raise InputError(f"tensions: expected {self.m} (one per cable), got {f.size}")
            L = stretched_lengths(L, f, EA)  # type: ignore[arg-type]
        p = self.position if position is None else np.asarray(position, dtype=float)
        R = self.rotation if rotation is None else np.asarray(rotation, dtype=float)
        result = self._solve(L, p, R)
        if result.converged:
            self.position, self.rotation = result.position, result.rotation
        return result

    def _solve(self, L: Array, p: Array, R: Array) -> ForwardResult:
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):  # NaN steps are handled below
            budget = self.max_iterations
            result = self._iterate(L, p, R, budget, (budget + 1) // 2)
            if not self._started_cold or (result.converged and result.residual <= self.restart_residual):
                return result
            # a cold start that stopped at a residual that may be a wrong local minimum: again from the home pose and
            # from the guess's position at the home orientation; one that stopped short: then on from where it did
            used = result.iterations
            seeds = [] if result.converged else [(result.position, result.rotation)]
            if result.residual > self.restart_residual:
                seeds[:0] = [(self._home_p, self._home_R), (p, self._home_R)]
            for seed_p, seed_R in seeds:
                if used >= budget:
                    break
                if np.array_equal(seed_p, p) and np.array_equal(seed_R, R):  # where it started already
                    continue
                again = self._iterate(L, seed_p.copy(), seed_R.copy(), budget - used, budget - used)
                used += again.iterations
                if again.residual_norm < result.residual_norm - self.tol or (
                        again.converged and not result.converged and again.residual_norm <= result.residual_norm
                        + self.tol):
                    result = again
                if result.converged and result.residual <= self.restart_residual:
                    break
        return ForwardResult(result.position, result.rotation, used, result.converged, result.residual,
                             result.residual_norm)

    def _rounding(self, L: Array) -> float:
        """The cost rounding leaves at the solution (a step that does not lower a cost below it is no failure)."""
        return self.m * (16.0 * float(np.finfo(float).eps) * float(np.abs(L).max())) ** 2

    def _iterate(self, L: Array, p: Array, R: Array, max_iterations: int, cold_iterations: int) -> ForwardResult:
        """Levenberg–Marquardt from (p, R), at most ``max_iterations`` linear solves, ``cold_iterations`` from a
        cold guess (its lengths farther than COLD_RESIDUAL from L: ``_started_cold``).

        Written for speed (a warm-started solve is two iterations of some forty numpy calls on 8 × 3 arrays, each
        costing about as much as its arithmetic): straight cables' lengths and G = −J inline (:meth:`_lengths`
        and :meth:`_wrench_rows` are the same, and compute them over pulleys), numpy functions in locals."""
        tol, small = self.tol, _SMALL_STEP * math.sqrt(self.tol)
        dot, sqrt, vecdot, subtract, multiply, divide = np.dot, np.sqrt, _vecdot, np.subtract, np.multiply, np.divide
        solve = _solve_linear
        straight = self._pulleys is None
        pose, abm, exits, arm, left3, outer, outer2, columns = (self._pose, self._abm, self._a, self._arm, self._left3,
                                                                 self._outer, self._outer2, self._columns)
        unit, unit3 = self._unit, self._unit3
        moved, six, turn, turn_entries, rotvec_entries = (self._moved, self.dof == 6, self._turn, self._turn_entries,
                                                          _rotvec_entries)
        if straight:
            pose[3] = p
            pose[4:] = R.T
            v = dot(abm, pose)
            lf = lengths = sqrt(vecdot(v, v))
        else:
            lengths, exits, v, lf = self._lengths(p, R)
        r = lengths - L
        cost = float(dot(r, r))
        self._started_cold = not cost <= COLD_RESIDUAL * COLD_RESIDUAL
        if not math.isfinite(cost):
            return ForwardResult(p.copy(), R.copy(), 0, False, math.inf, math.inf)
        if self._started_cold:
            max_iterations = cold_iterations
        lam, nu = 0.0, 2.0
        last = math.inf  # the previous accepted undamped step's size
        it = 0
        subtract(exits, p, out=arm)  # G = [d_i, (exit_i − t) × d_i]: _wrench_rows
        divide(v, lf[:, None], out=unit)
        multiply(left3, unit3, out=outer)
        G = dot(outer2, columns)
        H, g = dot(G.T, G), dot(r, G)
        while it < max_iterations:
            it += 1
            if lam > 0.0:
                dH = H.diagonal()
                A = H + np.diag(lam * (dH + 1e-12 * dH.max()))
            else:
                A = H
            step = solve(A, g)
            s = step.tolist()
            size = max(max(s), -min(s))
            if not math.isfinite(size):  # singular (a degenerate pose): damp
                lam, nu, last = (_LAMBDA_START if lam == 0.0 else lam * nu), nu * 2.0, math.inf
                continue
            if lam > 0.0 and size <= tol:
                if lam <= 1.0:  # damped a little (Gauss–Newton alone diverges about some least-squares poses)
                    p, R = moved(p, R, step, s)
                    r = r - dot(G, step)
                    return ForwardResult(p, R, it, True, max(map(abs, r.tolist())), math.sqrt(float(dot(r, r))))
                lam, last = 0.0, math.inf  # damped to nothing: is the undamped step as small?
                continue
            if lam == 0.0 and size <= small:
                # converged? An undamped step within tol; or, for lengths the step makes consistent (Gauss–Newton
                # converging quadratically), one whose ratio to the step before bounds what is left
                r1 = r - dot(G, step)  # the residual after it, to first order
                worst = max(map(abs, r1.tolist()))
                if size <= tol or (worst <= _CONSISTENT and size < 0.9 * last
                                   and size * size / (last - size) <= tol):
                    if six:  # take this last step on the linear model (_moved, inline)
                        turn_entries[:] = rotvec_entries(s[3], s[4], s[5])
                        return ForwardResult(p + step[:3], dot(turn, R), it, True, worst,
                                             math.sqrt(float(dot(r1, r1))))
                    p, R = moved(p, R, step, s)
                    return ForwardResult(p, R, it, True, worst, math.sqrt(float(dot(r1, r1))))
            if six:
                turn_entries[:] = rotvec_entries(s[3], s[4], s[5])
                p1, R1 = p + step[:3], dot(turn, R)
            else:
                p1, R1 = moved(p, R, step, s)
            if straight:
                pose[3] = p1
                pose[4:] = R1.T
                v1 = dot(abm, pose)
                lf1 = lengths = sqrt(vecdot(v1, v1))
                exits1 = exits
            else:
                lengths, exits1, v1, lf1 = self._lengths(p1, R1)
            r1 = lengths - L
            cost1 = float(dot(r1, r1))
            if cost1 <= cost or (cost1 == cost1 and lam == 0.0 and size <= small) or cost1 <= self._rounding(L):
                # (False for NaN; a small undamped step is taken whatever rounding does to the cost)
                if lam > 0.0:
                    predicted = float(dot(step, 2.0 * g - dot(H, step)))  # the cost's decrease on the linear model
                    gain = (cost - cost1) / predicted if predicted > 0.0 else 1.0
                    lam *= max(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3)
                    if lam < _LAMBDA_OFF:
                        lam = 0.0
                    last = math.inf
                else:
                    last = size
                nu = 2.0
                p, R, r, cost = p1, R1, r1, cost1
                subtract(exits1, p, out=arm)  # the Jacobian there
                divide(v1, lf1[:, None], out=unit)
                multiply(left3, unit3, out=outer)
                G = dot(outer2, columns)
                H, g = dot(G.T, G), dot(r, G)
            else:
                lam, nu, last = (_LAMBDA_START if lam == 0.0 else lam * nu), nu * 2.0, math.inf
        return ForwardResult(p, R, it, False, max(map(abs, r.tolist())), math.sqrt(cost))


def forward_kinematics(robot: Robot, lengths: ArrayLike, position: ArrayLike | None = None,
                       rotation: ArrayLike | None = None, *, tol: float = TOL, max_iterations: int = MAX_ITERATIONS,
                       tensions: ArrayLike | None = None, EA: ArrayLike | None = None) -> ForwardResult:
    """One solve of :class:`ForwardKinematics` (from the guess, else from the robot's home pose)."""
    return ForwardKinematics(robot, tol, max_iterations).solve(lengths, position, rotation, tensions=tensions, EA=EA)
