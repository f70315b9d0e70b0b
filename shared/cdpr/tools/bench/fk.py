"""`cdpr bench` part ``fk``: forward kinematics (:mod:`cdpr.mechanics.forward`) by the protocol of Mahnke &
Caverly (2025), on ``cogiro`` (their CoGiRo geometry) and ``caroca``.

Each robot gets ``poses`` random statically feasible poses (:func:`feasible_poses`: the platform frame's origin
uniform in the frame box, its orientation the home one turned about a random axis by up to 30°; tensions in
[10, 6000] N hold the platform plus a 100 kg payload at rest there, :func:`cdpr.mechanics.workspace.wrench_feasible`)
and their cable lengths by IK. FK then runs at tolerance 1e-9 with at most 30 iterations:

* ``cold``: from a guess off by up to 1 m in position (a random direction, a length uniform in [0, 1] m) and by
  2–40° in orientation (a turn about a random axis, its angle uniform in [2°, 40°]);
* ``warm``: from the pose 1 ms of motion away at 1 m/s and 1 rad/s (1 mm along a random direction, 1 mrad about a
  random axis), one :class:`~cdpr.mechanics.forward.ForwardKinematics` for all (a control loop's);
* ``noisy``: the lengths with Gaussian noise of σ = 5 mm, from the warm guess; the pose error
  e = [Δt; Δφ] (Δφ the world-frame rotation vector of R R_trueᵀ) against the analytic covariance
  P = J⁺ Σ J⁺ᵀ = σ² (JᵀJ)⁻¹ at the true pose: ``nees_ratio`` is the mean of eᵀ P⁻¹ e over the DOF (1 when
  they agree), ``position_ratio`` and ``orientation_ratio`` the means of |Δt|² / tr P_tt and |Δφ|² / tr P_φφ
  (each 1 as well).

A clean solve succeeds when it converged and the pose is the true one within 1e-6 m and 1e-6 rad (the error
of the successes is reported: ~1e-12). Times are µs per solve (``time.perf_counter`` around each), on one core,
beside whatever else the machine runs. ``python -m cdpr.tools.bench.fk [--quick]`` runs this part alone.
"""

from __future__ import annotations

import json
import math
import sys
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from cdpr.config.robot import load_robot
from cdpr.mechanics.forward import MAX_ITERATIONS, TOL, ForwardKinematics
from cdpr.mechanics.kinematics import inverse_kinematics
from cdpr.mechanics.pulley import pulley_geometry
from cdpr.mechanics.robot import Robot
from cdpr.mechanics.rotation import Array, matrix_to_rotvec, rotvec_to_matrix
from cdpr.mechanics.workspace import wrench_feasible

ROBOTS = ("cogiro", "caroca")
POSES, QUICK_POSES = 10_000, 500
PAYLOAD = 100.0  # kg
TENSIONS = (10.0, 6000.0)  # N
MAX_ANGLE = math.radians(30.0)  # the poses' orientations: turned from home by up to this
COLD_POSITION = 1.0  # m: the cold guesses' largest position error
COLD_ANGLES = (math.radians(2.0), math.radians(40.0))  # their orientation error's range
WARM_DT, WARM_SPEED, WARM_RATE = 1e-3, 1.0, 1.0  # s, m/s, rad/s: the warm guess, 1 ms of motion away
NOISE = 5e-3  # m: the noisy variant's length noise (σ)
SUCCESS = 1e-6  # m and rad: a clean solve's pose error at most this
SEED = 46
ROUND = 1000  # solves: the rounds of best_round_median_us


def reference_op_us(repeats: int = 20_000) -> float:
    """µs of one small numpy call (an 8 × 3 subtraction), the median of 5 runs: what this machine's numpy costs now
    (a warm-started FK solve is about forty such calls and their Python)."""
    x, y = np.ones((8, 3)), np.ones((8, 3))
    runs = []
    for _ in range(5):
        start = time.perf_counter()
        for _ in range(repeats):
            x - y  # the call timed
        runs.append((time.perf_counter() - start) / repeats)
    return 1e6 * float(np.median(runs))


def unit_vectors(rng: np.random.Generator, n: int) -> Array:
    u = rng.normal(size=(n, 3))
    return u / np.linalg.norm(u, axis=1, keepdims=True)


def turns(axes: Array, angles: Array) -> Array:
    return np.array([rotvec_to_matrix(w) for w in axes * angles[:, None]]).reshape(-1, 3, 3)


def pose_lengths(robot: Robot, positions: Array, rotations: Array) -> Array:
    """Cable lengths (n, m) at n poses of the centre of mass, vectorised (:func:`inverse_kinematics`'s, to
    rounding; a check of many candidate poses, not what a test compares with)."""
    world = positions[:, None, :] + np.einsum("nij,mj->nmi", rotations, robot.platform_points)
    if robot.pulleys is not None:
        return pulley_geometry(robot.frame_points, robot.pulleys, world).lengths
    return np.linalg.norm(robot.frame_points[None] - world, axis=2)


def feasible_poses(robot: Robot, n: int, rng: np.random.Generator, *, payload: float = 0.0,
                   tmin: float | None = None, tmax: float | None = None, max_angle: float = MAX_ANGLE,
                   spread: float = 1.0, static: bool = True) -> tuple[Array, Array]:
    """``n`` random poses ``(positions (n, 3) of the centre of mass, rotations (n, 3, 3))`` the robot can take:
    the platform frame's origin uniform in the frame box (shrunk about the home position by ``spread``; a planar
    robot's in its plane), turned from the home orientation about a random axis (a planar robot's normal; a point
    mass not at all) by an angle uniform in [0, ``max_angle``]; every cable within its max_length and longer than
    1 mm, and with ``static`` tensions in [tmin, tmax] (default the robot's) hold the platform plus ``payload`` kg
    at rest (:func:`wrench_feasible`). RuntimeError when too few candidates are."""
    home = robot.home_position - robot.home_rotation @ robot.com_offset
    lo = home + spread * (robot.frame_min - home)
    hi = home + spread * (robot.frame_max - home)
    lo_t = tmin if tmin is not None else robot.tmin
    hi_t = tmax if tmax is not None else robot.tmax
    positions: list[Array] = []
    rotations: list[Array] = []
    found, drawn = 0, 0
    batch = max(256, n)
    while found < n:
        if drawn > 200 * n + 10_000:
            raise RuntimeError(f"{robot.name}: {found} feasible poses of {drawn} drawn, {n} wanted")
        origin = rng.uniform(lo, hi, (batch, 3))
        angles = rng.uniform(0.0, max_angle, batch)
        if robot.mode == "point_mass":
            axes, angles = np.zeros((batch, 3)), np.zeros(batch)
        elif robot.mode == "planar":
            origin[:, robot.normal_axis] = 0.0
            axes = np.zeros((batch, 3))
            axes[:, robot.normal_axis] = rng.choice([-1.0, 1.0], batch)
        else:
            axes = unit_vectors(rng, batch)
        R = turns(axes, angles) @ robot.home_rotation
        p = origin + R @ robot.com_offset
        drawn += batch
        with np.errstate(invalid="ignore"):
            lengths = pose_lengths(robot, p, R)
            ok = np.all(np.isfinite(lengths) & (lengths <= robot.max_length) & (lengths > 1e-3), axis=1)
        if static and ok.any():
            idx = np.flatnonzero(ok)
            ok[idx] = wrench_feasible(robot, p[idx], R[idx], payload, lo_t, hi_t)
        positions.append(p[ok])
        rotations.append(R[ok])
        found += int(ok.sum())
    return np.concatenate(positions)[:n], np.concatenate(rotations)[:n]


def _guesses(rng: np.random.Generator, positions: Array, rotations: Array, distance: Array, angle: Array
             ) -> tuple[Array, Array]:
    n = len(positions)
    return (positions + unit_vectors(rng, n) * distance[:, None],
            turns(unit_vectors(rng, n), angle) @ rotations)


def pose_error(robot: Robot, p: Array, R: Array, p_true: Array, R_true: Array) -> Array:
    """[Δt; Δφ] in the solver's coordinates (spatial 6, planar 3: the plane's two and the turn, point mass 3)."""
    e = np.r_[p - p_true, matrix_to_rotvec(R @ R_true.T)]
    if robot.mode == "spatial":
        return e
    if robot.mode == "point_mass":
        return e[:3]
    n = robot.normal_axis
    return e[[j for j in range(3) if j != n] + [3 + n]]


def _percentile(values: Sequence[float], q: float) -> float:
    return float(np.percentile(np.asarray(values, dtype=float), q))


def _run(fk: ForwardKinematics, lengths: Array, guess_p: Array, guess_R: Array, true_p: Array, true_R: Array,
         clean: bool) -> tuple[dict[str, Any], list[Array]]:
    robot = fk.robot
    times: list[float] = []
    iterations: list[int] = []
    converged = successes = 0
    worst = 0.0
    errors: list[Array] = []
    residuals: list[float] = []
    clock = time.perf_counter
    for k in range(len(lengths)):
        a = clock()
        res = fk.solve(lengths[k], guess_p[k], guess_R[k])
        times.append(clock() - a)
        iterations.append(res.iterations)
        converged += res.converged
        e = pose_error(robot, res.position, res.rotation, true_p[k], true_R[k])
        errors.append(e)
        residuals.append(res.residual)
        if clean:
            err = float(np.abs(e).max())
            if res.converged and err <= SUCCESS:
                successes += 1
                worst = max(worst, err)
    n = len(lengths)
    rounds = [times[i:i + ROUND] for i in range(0, n - ROUND + 1, ROUND)] or [times]
    out: dict[str, Any] = {
        "solves": n,
        "converged": converged / n,
        "iterations_median": float(np.median(iterations)),
        "iterations_p99": _percentile(iterations, 99),
        "iterations_max": int(max(iterations)),
        "median_us": 1e6 * float(np.median(times)),
        "p99_us": 1e6 * _percentile(times, 99),
        # the host's speed drifts within a minute here: the median of the fastest run of ROUND solves
        "best_round_median_us": 1e6 * min(float(np.median(r)) for r in rounds),
    }
    if clean:
        out["success"] = successes / n
        out["failures"] = n - successes
        out["max_error_of_successes"] = worst
    else:
        out["residual_median_m"] = float(np.median(residuals))
    return out, errors


def bench_robot(name: str, poses: int, seed: int = SEED) -> dict[str, Any]:
    """The protocol on one robot (module docstring)."""
    robot = load_robot(name)
    rng = np.random.default_rng(seed)
    started = time.perf_counter()
    p, R = feasible_poses(robot, poses, rng, payload=PAYLOAD, tmin=TENSIONS[0], tmax=TENSIONS[1])
    lengths = np.array([inverse_kinematics(robot, p[k], R[k]).lengths for k in range(poses)])
    sampled = time.perf_counter() - started
    cold_p, cold_R = _guesses(rng, p, R, rng.uniform(0.0, COLD_POSITION, poses), rng.uniform(*COLD_ANGLES, poses))
    warm_p, warm_R = _guesses(rng, p, R, np.full(poses, WARM_SPEED * WARM_DT), np.full(poses, WARM_RATE * WARM_DT))
    fk = ForwardKinematics(robot, TOL, MAX_ITERATIONS)
    fk.solve(lengths[0], p[0], R[0])  # numpy's first calls out of the timings
    cold, _ = _run(fk, lengths, cold_p, cold_R, p, R, clean=True)
    before = reference_op_us()
    warm, _ = _run(fk, lengths, warm_p, warm_R, p, R, clean=True)
    warm["reference_op_us"] = [before, reference_op_us()]  # before and after the warm solves
    noisy_lengths = lengths + rng.normal(0.0, NOISE, lengths.shape)
    noisy, errors = _run(fk, noisy_lengths, warm_p, warm_R, p, R, clean=False)
    noisy.update(_covariance(fk, p, R, np.array(errors)))
    return {"robot": robot.name, "cables": robot.m, "poses": poses, "sampling_s": sampled, "cold": cold,
            "warm": warm, "noisy": noisy}


def _covariance(fk: ForwardKinematics, p: Array, R: Array, errors: Array) -> dict[str, Any]:
    """The noisy solves' pose errors e against P = σ² (JᵀJ)⁻¹ at each true pose: the means over the poses of
    eᵀ P⁻¹ e / dof, of |e_t|² / tr P_tt and of |e_φ|² / tr P_φφ (each 1 where the errors have covariance P)."""
    nees, pos, rot, var_p = [], [], [], []
    for k in range(len(p)):
        J = fk.jacobian(p[k], R[k])
        info = J.T @ J / NOISE**2  # P⁻¹
        P = np.linalg.inv(info)
        e = errors[k]
        nees.append(float(e @ info @ e) / len(e))
        pos.append(float(e[:3] @ e[:3]) / float(np.trace(P[:3, :3])))
        var_p.append(float(np.trace(P[:3, :3])))
        if len(e) == 6:
            rot.append(float(e[3:] @ e[3:]) / float(np.trace(P[3:, 3:])))
    out = {
        "noise_m": NOISE,
        "nees_ratio": float(np.mean(nees)),
        "position_ratio": float(np.mean(pos)),
        "rms_position_error_mm": 1e3 * float(np.sqrt(np.mean(np.sum(errors[:, :3] ** 2, axis=1)))),
        "rms_position_predicted_mm": 1e3 * math.sqrt(float(np.mean(var_p))),
    }
    if rot:
        out["orientation_ratio"] = float(np.mean(rot))
        out["rms_orientation_error_mrad"] = 1e3 * float(np.sqrt(np.mean(np.sum(errors[:, 3:] ** 2, axis=1))))
    return out


def bench_fk(quick: bool = False, robots: Sequence[str] = ROBOTS, seed: int = SEED) -> dict[str, Any]:
    """The part: the protocol on each robot (``QUICK_POSES`` poses with ``quick``, else ``POSES``)."""
    poses = QUICK_POSES if quick else POSES
    return {
        "protocol": {"poses": poses, "payload_kg": PAYLOAD, "tensions_N": list(TENSIONS),
                     "max_angle_deg": math.degrees(MAX_ANGLE), "tol": TOL, "max_iterations": MAX_ITERATIONS,
                     "cold_position_m": COLD_POSITION, "cold_angles_deg": [math.degrees(a) for a in COLD_ANGLES],
                     "warm_dt_s": WARM_DT, "warm_speed_m_s": WARM_SPEED, "warm_rate_rad_s": WARM_RATE,
                     "noise_m": NOISE, "success_m_rad": SUCCESS, "seed": seed},
        "robots": {name: bench_robot(name, poses, seed) for name in robots},
    }


def fk_targets(fk: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """#46's targets, on cogiro (the protocol's robot)."""
    r = fk["robots"].get("cogiro")
    if r is None:
        return {}
    cov = r["noisy"]["nees_ratio"]
    return {
        "fk_cold_success>=0.99": {"value": r["cold"]["success"], "met": r["cold"]["success"] >= 0.99},
        "fk_warm_success>=0.9999": {"value": r["warm"]["success"], "met": r["warm"]["success"] >= 0.9999},
        "fk_warm_median_us<=60": {"value": r["warm"]["median_us"], "met": r["warm"]["median_us"] <= 60.0},
        "fk_noisy_covariance_ratio_within_0.1": {"value": cov, "met": abs(cov - 1.0) <= 0.1},
    }


def fk_lines(fk: dict[str, Any]) -> list[str]:
    """The part's rows of the table (:func:`cdpr.tools.bench.table`)."""
    proto = fk["protocol"]
    lines = [f"11 forward kinematics, the Mahnke & Caverly protocol: {proto['poses']} feasible poses a robot "
             f"({proto['payload_kg']:g} kg payload, tensions in [{proto['tensions_N'][0]:g}, "
             f"{proto['tensions_N'][1]:g}] N), tol {proto['tol']:g}, <= {proto['max_iterations']} iterations",
             f"    {'':34s}{'success':>10s}{'iter. median/p99':>18s}{'us median':>11s}{'us p99':>9s}"]
    for name, r in fk["robots"].items():
        for label, run in (("cold (1 m, 2-40 deg off)", r["cold"]), ("warm (1 ms of motion away)", r["warm"]),
                           (f"noisy ({1e3 * proto['noise_m']:g} mm), warm: converged", r["noisy"])):
            share = run.get("success", run["converged"])
            lines.append(f"    {name + ' ' + label:34s}{100 * share:>9.2f}%"
                         f"{run['iterations_median']:>9.0f} / {run['iterations_p99']:<6.0f}"
                         f"{run['median_us']:>11.1f}{run['p99_us']:>9.1f}")
        w = r["warm"]
        lines.append(f"    {name} warm: best {ROUND}-solve round's median {w['best_round_median_us']:.1f} us; one "
                     f"small numpy call {' / '.join(f'{x:.2f}' for x in w['reference_op_us'])} us (before / after)")
        n = r["noisy"]
        orientation = (f", orientation {n['orientation_ratio']:.3f}" if "orientation_ratio" in n else "")
        lines.append(f"    {name} noisy pose error / J+ S J+T: NEES/dof {n['nees_ratio']:.3f}, position "
                     f"{n['position_ratio']:.3f}{orientation} (RMS {n['rms_position_error_mm']:.2f} mm)")
    return lines


if __name__ == "__main__":
    result = bench_fk(quick="--quick" in sys.argv[1:])
    print("\n".join(fk_lines(result)))
    print(json.dumps(fk_targets(result)))
