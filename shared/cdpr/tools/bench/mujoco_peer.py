"""The MuJoCo peer of ``cdpr bench``: the scenario's robot as a MuJoCo model, driven by the project's own
controller and trajectory cores — the loop a user would build for speed, and an independent check of the
sim's dynamics (optional: ``pip install 'cdpr[bench]'``).

The model (:func:`mjcf`): a free body with the platform's mass and full inertia about its centre of mass, a
site at each platform point ``b_i`` and one in the world at each frame point ``a_i``, one spatial tendon per
cable between them with the robot's cable damping (MuJoCo's tendon damping: ``−c·l̇`` along the tendon, the
sim's cable damping), and one motor per tendon (gear −1: a positive control shortens the tendon, i.e. pulls,
within [0, tmax]). Gravity −9.81 along z, no contact, integrator RK4 by default (the sim: DART's
semi-implicit Euler; both are consistent, their trajectories differ by O(dt) over a run).
Only spatial robots (a free rigid body).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from cdpr.config.scenario import Scenario
from cdpr.mechanics.rotation import Array, matrix_to_quat, quat_to_matrix
from cdpr.protocol import Setpoint, State


def mjcf(scenario: Scenario, integrator: str = "RK4") -> str:
    """The MJCF text of the scenario's robot at its initial pose (see the module docstring)."""
    robot = scenario.robot
    if robot.mode != "spatial":
        raise ValueError(f"the MuJoCo peer models spatial robots (a free body); {robot.name} is {robot.mode}")
    inertia = np.asarray(robot.inertia, dtype=float)  # about the centre of mass, platform frame
    full_inertia = " ".join(repr(float(inertia[i, j])) for i, j in ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)))
    p = np.asarray(scenario.initial_position, dtype=float)
    qx, qy, qz, qw = matrix_to_quat(np.asarray(scenario.initial_rotation, dtype=float))

    def vec(v: Any) -> str:
        return " ".join(repr(float(x)) for x in v)

    frame_sites = "\n".join(f'    <site name="a{i}" pos="{vec(a)}"/>' for i, a in enumerate(robot.frame_points))
    platform_sites = "\n".join(f'      <site name="b{i}" pos="{vec(b)}"/>' for i, b in enumerate(robot.platform_points))
    tendons = "\n".join(f'    <spatial name="cable{i}" damping="{float(robot.cable_damping)!r}">'
                        f'<site site="a{i}"/><site site="b{i}"/></spatial>' for i in range(robot.m))
    motors = "\n".join(f'    <motor name="winch{i}" tendon="cable{i}" gear="-1" ctrllimited="true" '
                       f'ctrlrange="0 {float(robot.tmax[i])!r}"/>' for i in range(robot.m))
    return f"""<mujoco model="{robot.name}">
  <option timestep="{scenario.dt!r}" integrator="{integrator}" gravity="0 0 -9.81"/>
  <worldbody>
{frame_sites}
    <body name="platform" pos="{vec(p)}" quat="{vec((qw, qx, qy, qz))}">
      <freejoint/>
      <inertial pos="0 0 0" mass="{float(robot.mass)!r}"
                fullinertia="{full_inertia}"/>
{platform_sites}
    </body>
  </worldbody>
  <tendon>
{tendons}
  </tendon>
  <actuator>
{motors}
  </actuator>
</mujoco>
"""


class MujocoPlant:
    """The scenario's platform in MuJoCo, stepped by tensions; its state as a ``sim/state`` message."""

    def __init__(self, scenario: Scenario, integrator: str = "RK4") -> None:
        import mujoco

        self._mj = mujoco
        self.model = mujoco.MjModel.from_xml_string(mjcf(scenario, integrator))
        self.data = mujoco.MjData(self.model)
        mujoco.mj_forward(self.model, self.data)
        self.dt, self.step_count = scenario.dt, 0
        self._tensions = np.zeros(scenario.robot.m)

    def message(self) -> State:
        d = self.data
        x, y, z, qw, qx, qy, qz = d.qpos.tolist()
        R = quat_to_matrix((qx, qy, qz, qw))
        w = R @ d.qvel[3:6]  # a free joint's angular velocity is in the body's frame
        return State(self.step_count, self.step_count * self.dt, (x, y, z, qx, qy, qz, qw),
                     (*d.qvel[:3].tolist(), *w.tolist()), tuple(d.ten_length.tolist()), tuple(self._tensions.tolist()))

    def step(self, tensions: Array) -> None:
        self.data.ctrl[:] = tensions  # clamped to [0, tmax] by the motors' control range
        self._mj.mj_step(self.model, self.data)
        self._tensions = np.clip(tensions, 0.0, float(self.model.actuator_ctrlrange[0, 1]))
        self.step_count += 1


def peer_steps(scenario: Scenario, steps: int) -> float:
    """Run ``steps`` steps of the project's trajectory and controller cores on the MuJoCo plant; the wall
    time (s). The monolithic loop's work minus the messages, with MuJoCo's step instead of the sim's (the
    setpoints computed in the monolithic loop's blocks too)."""
    from cdpr.runtime.registry import node_class
    from cdpr.tools.bench.loops import MONOLITHIC_WINDOW

    plant = MujocoPlant(scenario)
    core = node_class("controller").make_core(scenario)
    setpoints_between = node_class("trajectory").make_block_core(scenario)
    setpoints: tuple[Setpoint, ...] = ()
    t0 = time.perf_counter()
    for k in range(steps):
        if k % MONOLITHIC_WINDOW == 0:
            setpoints = setpoints_between(k, min(steps, k + MONOLITHIC_WINDOW) - 1)
        plant.step(core.step(plant.message(), setpoints[k % MONOLITHIC_WINDOW]).tensions)
    return time.perf_counter() - t0


def agreement(scenario: Scenario, steps: int, every: int = 100) -> dict[str, Any]:
    """The same session on both engines (each with its own copy of the controller): the largest difference
    of the platform's position (m) and orientation (rad) over ``steps`` steps, and the curve every ``every``
    steps."""
    from cdpr.mechanics.rotation import orientation_error
    from cdpr.runtime.registry import node_class

    plant, sim = MujocoPlant(scenario), node_class("sim").make_core(scenario)
    cores = [node_class("controller").make_core(scenario) for _ in range(2)]
    setpoint_at = node_class("trajectory").make_core(scenario)
    curve: list[tuple[float, float, float]] = []
    worst_p = worst_r = 0.0
    for k in range(steps + 1):
        a, b = sim.message(0), plant.message()
        dp = float(np.linalg.norm(np.subtract(a.pose[:3], b.pose[:3])))
        dr = float(np.linalg.norm(orientation_error(quat_to_matrix(a.pose[3:]), quat_to_matrix(b.pose[3:]))))
        worst_p, worst_r = max(worst_p, dp), max(worst_r, dr)
        if k % every == 0:
            curve.append((k * scenario.dt, dp, dr))
        if k == steps:
            break
        sp = setpoint_at(k)
        sim.step(np.asarray(cores[0].step(a, sp).tensions))
        plant.step(cores[1].step(b, sp).tensions)
    return {"steps": steps, "max_position_difference_m": worst_p, "max_orientation_difference_rad": worst_r,
            "curve": curve}


def bench_mujoco(scenario: Scenario, steps: int, repeats: int = 3) -> dict[str, Any]:
    """``cdpr bench``'s part 7: the peer loop and the monolithic loop, interleaved (M P M P …, medians), and the
    two engines' agreement over the whole scenario; ``available: false`` with the reason without MuJoCo."""
    try:
        import mujoco
    except ImportError as exc:
        return {"available": False, "reason": f"MuJoCo is not installed ({exc}): pip install 'cdpr[bench]'"}
    from cdpr.tools.bench.loops import monolithic_steps

    steps = min(steps, scenario.total_steps)
    mono, peer = [], []
    for _ in range(repeats):
        mono.append(steps / monolithic_steps(scenario, steps))
        peer.append(steps / peer_steps(scenario, steps))
    agree = agreement(scenario, scenario.total_steps)
    m, p = float(np.median(mono)), float(np.median(peer))
    return {"available": True, "mujoco": mujoco.__version__, "integrator": "RK4", "steps": steps,
            "steps_per_s": p, "monolithic_steps_per_s": m, "monolithic_to_peer": m / p, "agreement": agree}
