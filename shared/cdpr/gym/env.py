"""``cdpr/Track-v0``: a Gymnasium environment around the session's own sim, trajectory and controller cores.

One env step is one control period: ``control_every`` sim steps (default 10 at the scenario's dt). The
policy's action is held over the period; what it means depends on ``action``:

* ``residual`` (default): a wrench added to the scenario's law's (``controller.law``, :data:`cdpr.laws.LAWS`: any
  law of states and setpoints, feedback linearisation by default), which runs every sim step as the session's
  controller does, before the scenario's tension distribution. An action of 0 is the scenario's own controller,
  step for step.
* ``wrench``: the wrench the cables must exert (on top of the platform's weight), distributed once per
  env step by the scenario's tension distribution at the period's first state; the tensions are held.
* ``tensions``: the m tensions themselves, [-1, 1] → [tmin, tmax], held.

``connect=None`` (local mode) steps the sim's and trajectory's cores in this process. ``connect="tcp/host:7447"``
(session mode) is the controller of a running session (``cdpr up SCENARIO --without controller
--episodes 0``): each episode is one session, each sim step one ``sim/state`` answered with one
``controller/command``. docs/learning.md has the spaces, the reward and the figures.
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from cdpr.config.scenario import Scenario, load_scenario
from cdpr.errors import InputError
from cdpr.gym.loop import LocalLoop, Reached, SessionLoop
from cdpr.gym.task import ActionKind, Limits, RewardWeights, Task
from cdpr.laws import LAWS
from cdpr.mechanics.kinematics import WrenchMatrix
from cdpr.mechanics.rotation import Array, quat_to_matrix
from cdpr.mechanics.tda import TdaResult
from cdpr.protocol import Command, Setpoint, State
from cdpr.runtime.registry import node_class


class TrackEnv(gym.Env[np.ndarray, np.ndarray]):
    """Track the scenario's trajectory with CAROCA (or any shipped robot): see the module's docstring."""

    metadata = {"render_modes": []}  # noqa: RUF012  (Gymnasium's own attribute: a dict on the class)

    def __init__(
        self,
        scenario: str = "caroca_15kg",
        action: ActionKind = "residual",
        control_every: int = 10,
        *,
        duration: float | None = None,
        reward_weights: dict[str, float] | None = None,
        limits: dict[str, float] | None = None,
        randomize: Sequence[dict[str, Any]] | None = None,
        connect: str | Sequence[str] | None = None,
        session: str = "default",
        zenoh_config: str | None = None,
        session_timeout: float = 120.0,
        normalize: bool = False,
        render_mode: str | None = None,
    ) -> None:
        if render_mode is not None:
            raise ValueError(f"render_mode: this environment renders nothing itself (got {render_mode!r}); "
                             f"record a session to Rerun instead (docs/learning.md)")
        overrides = None if duration is None else {"duration": float(duration)}
        self.base = load_scenario(scenario, overrides)
        try:
            bounds = Limits(**(limits or {}))
        except TypeError as exc:
            raise ValueError(f"limits: {exc}") from None
        self.task = Task(self.base, action, control_every, RewardWeights.of(reward_weights), bounds)
        self._check_scenario(self.base)
        low, high = self.task.bounds()
        # normalize: the same observation mapped affinely from its bounds onto [-1, 1] (a fixed map, no running
        # statistics: a policy trained on it runs unchanged in session mode and in `cdpr run --policy`)
        self.normalize = bool(normalize)
        self._mid, self._half = (high.astype(np.float64) + low) / 2.0, (high.astype(np.float64) - low) / 2.0
        if self.normalize:
            low, high = -np.ones_like(low), np.ones_like(high)
        self.observation_space = spaces.Box(low, high, dtype=np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, (self.task.action_size,), dtype=np.float32)
        self.randomizer = None if not randomize else Randomizer(scenario, randomize, duration)
        if connect is not None and self.randomizer is not None:
            raise ValueError("randomize: the plant of a session is the session's (randomise it with `cdpr study`); "
                             "domain randomisation needs local mode (connect=None)")
        self.loop: LocalLoop | SessionLoop = (LocalLoop() if connect is None else
                                              SessionLoop(connect, session, zenoh_config, timeout=session_timeout))
        self.controller: Any = None
        self.wrench_matrix = WrenchMatrix(self.base.robot)
        self.plant = self.base
        self._reached: Reached | None = None
        self._previous: Array | None = None
        self._sq_sum, self._count, self._infeasible, self._return = 0.0, 0, 0, 0.0

    @staticmethod
    def _check_scenario(scenario: Scenario) -> None:
        spec = scenario.spec
        law = LAWS[spec.controller.law]
        if set(law.inputs) - {"setpoints"}:
            raise InputError(f"scenario {scenario.name}: controller.law {law.name} — the environment gives its base "
                             f"law states and setpoints, not {', '.join(sorted(set(law.inputs) - {'setpoints'}))}")
        if spec.sim.command_latency is not None:
            raise InputError(f"scenario {scenario.name}: sim.command_latency — the environment holds its action "
                             f"over control_every steps instead (a latency of its own is not modelled)")

    # -- episodes ----------------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        controller = node_class("controller")  # its core: the scenario's law (cdpr.laws) and the distribution
        if self.randomizer is not None:
            self.plant, model = self.randomizer.draw(int(self.np_random.integers(2**31 - 1)))
            self.controller = controller.make_core(model)
            self.wrench_matrix = WrenchMatrix(model.robot)
        elif self.controller is None:
            self.controller = controller.make_core(self.base)
        else:
            self.controller.reset()
        self._reached = self.loop.start(self.plant)
        self._previous = None
        self._sq_sum, self._count, self._infeasible, self._return = 0.0, 0, 0, 0.0
        r = self._reached
        return self._observe(r), {"step": r.state.step}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._reached is None:
            raise RuntimeError("call reset() before step()")
        task = self.task
        a = np.asarray(action, dtype=float).reshape(-1)
        if a.shape != (task.action_size,) or not np.all(np.isfinite(a)):
            raise ValueError(f"action: expected {task.action_size} finite numbers in [-1, 1], got {action!r}")
        start = self._reached.state.step
        n = min(task.control_every, task.total_steps - start)
        infeasible_before = self._infeasible
        reached = self.loop.run(n, self._commander(a))
        self._reached = reached
        self._count += len(reached.errors)
        self._sq_sum += math.fsum(e * e for e in reached.errors)
        state, setpoint = reached.state, reached.setpoint
        e_p, e_r = task.errors(state, setpoint)
        mean_applied = np.mean(np.asarray(reached.applied, dtype=float), axis=0) if reached.applied else \
            np.asarray(state.tensions, dtype=float)
        reward = task.reward(task.cost(e_p, e_r, mean_applied, self._previous))
        self._previous = mean_applied
        why = task.termination(state, e_p, e_r)
        terminated = why is not None
        truncated = not terminated and (state.step >= task.total_steps or reached.ended is not None)
        if terminated:
            remaining = -(-(task.total_steps - state.step) // task.control_every)
            reward -= float(remaining)  # never better than staying in the episode: each step left costs the most
            self.loop.end(f"episode terminated at step {state.step}: {why}")
        self._return += reward
        info: dict[str, Any] = {"step": state.step, "position_error": float(np.linalg.norm(e_p)),
                                "orientation_error": float(np.linalg.norm(e_r)),
                                "infeasible": self._infeasible - infeasible_before}
        if why is not None:
            info["termination"] = why
        if reached.ended is not None:
            info["session"] = reached.ended
        if terminated or truncated:
            info["episode_stats"] = {
                "rms_position_error": math.sqrt(self._sq_sum / self._count) if self._count else None,
                "steps": self._count, "infeasible_commands": self._infeasible, "return": self._return,
            }
        return self._observe(reached), float(reward), terminated, truncated, info

    def _observe(self, reached: Reached) -> np.ndarray:
        obs = self.task.observe(reached.state, reached.setpoint, reached.sensors)
        if not self.normalize:
            return obs
        return np.clip((obs - self._mid) / self._half, -1.0, 1.0).astype(np.float32)

    def _commander(self, a: Array) -> Any:
        """The (state k, setpoint k) → command k function of this env step's action."""
        task, core = self.task, self.controller
        lengths_out = getattr(core, "output", "tensions") == "lengths"

        def command(state: State, setpoint: Setpoint, result: TdaResult, lengths: Array | None = None) -> Command:
            if not result.feasible:
                self._infeasible += 1
            if lengths is not None:
                return Command(state.step, state.t, (), result.feasible, result.status, tuple(lengths.tolist()))
            return Command(state.step, state.t, tuple(result.tensions.tolist()), result.feasible, result.status)

        if task.action == "residual":
            residual = task.wrench_of(a)
            zero = not np.any(residual)

            def residual_step(state: State, setpoint: Setpoint) -> Command:
                return command(state, setpoint, *core.command(state, setpoint, None if zero else residual))

            return residual_step
        held: list[TdaResult] = []
        if task.action == "tensions":
            f = task.tensions_of(a)
            f.flags.writeable = False
            held.append(TdaResult(f, True, 0.0, "ok", "policy"))
        wrench = task.wrench_of(a) if task.action == "wrench" else None

        def held_step(state: State, setpoint: Setpoint) -> Command:
            if not held:  # wrench: distributed once, at the period's first state
                W = self.wrench_matrix(state.pose[:3], quat_to_matrix(state.pose[3:]))[task.rows]
                held.append(core.tda.solve(W, wrench, task.tmin, task.tmax))
            lengths = core.lengths(setpoint, held[0].tensions) if lengths_out else None  # (a winch session)
            return command(state, setpoint, held[0], lengths)

        return held_step

    def close(self) -> None:
        self.loop.close()
        super().close()


class Randomizer:
    """Domain randomisation with ``cdpr study``'s parameter laws: a new plant (and, for ``plant_only``
    parameters, a controller model that keeps the nominal values) per episode, drawn from the env's seed."""

    def __init__(self, scenario: str, parameters: Sequence[dict[str, Any]], duration: float | None) -> None:
        from cdpr.config.loading import parse_model
        from cdpr.config.study import StudySpec
        from cdpr.config.variation import load_base

        doc = {"name": "randomize", "scenario": scenario, "parameters": list(parameters), "samples": 1}
        if duration is not None:
            doc["set"] = {"duration": float(duration)}
        self.spec = parse_model(StudySpec, doc, "randomize")
        self.base = load_base(self.spec, Path.cwd() / "randomize.yaml")
        self.folder = tempfile.TemporaryDirectory(prefix="cdpr-gym-")

    def draw(self, sample: int) -> tuple[Scenario, Scenario]:
        """(the plant's scenario, the controller's) of one draw."""
        from cdpr.config.variation import build_point

        point = build_point(self.spec, self.base, 0, {}, sample, "randomize")
        folder = Path(self.folder.name)
        for name, text in point.files.items():
            (folder / name).write_text(text, encoding="utf-8")
        plant = load_scenario(folder / "scenario.yaml", checks=())
        model = load_scenario(folder / "controller.yaml", checks=()) if point.split else plant
        return plant, model
