"""``cdpr bench``'s learning-environment part (#27): how fast ``cdpr/Track-v0`` steps the loop.

Local mode, 10 sim steps per env step, for each action space, interleaved with the monolithic loop (M W M R M T,
``rounds`` times): sim steps per second over one whole episode of the scenario, the env's first episode (its
trajectory's setpoints computed as it goes) and its second (the setpoints are the same every episode: kept). The
target compares the ``wrench`` space's later episodes — one tension distribution per env step, no messages — with
the monolithic loop's median. Then session mode (the env as the controller of ``cdpr up --without controller``,
one episode), and two local envs vectorised (Gymnasium's Sync and AsyncVectorEnv: one process, or one each).
"""

from __future__ import annotations

import statistics
import subprocess
import sys
import time
from typing import Any

import numpy as np

from cdpr.config.scenario import load_scenario
from cdpr.tools.bench.loops import monolithic_steps

ACTIONS = ("wrench", "residual", "tensions")


def _episode(env: Any, seed: int) -> tuple[int, float]:
    """(sim steps, seconds) of one whole episode of zero actions."""
    env.reset(seed=seed)
    action = np.zeros(env.action_space.shape or (), dtype=np.float32)
    done = False
    t0 = time.perf_counter()
    while not done:
        _, _, terminated, truncated, info = env.step(action)
        done = terminated or truncated
    elapsed = time.perf_counter() - t0
    steps = info["step"]
    return steps, elapsed


def bench_gym(scenario: str, duration: float | None, rounds: int, session_duration: float,
              vector_steps: int) -> dict[str, Any]:
    try:
        import gymnasium as gym

        import cdpr.gym  # noqa: F401  (registers cdpr/Track-v0)
        from cdpr.gym.env import TrackEnv
    except ImportError:
        return {"available": False, "reason": "gymnasium is not installed (pip install 'cdpr[gym]')"}
    sc = load_scenario(scenario, None if duration is None else {"duration": duration})
    mono: list[float] = []
    runs: dict[str, dict[str, list[float]]] = {a: {"first": [], "later": []} for a in ACTIONS}
    for _ in range(rounds):
        for action in ACTIONS:
            mono.append(sc.total_steps / monolithic_steps(sc, sc.total_steps))
            env = TrackEnv(scenario, action, 10, duration=duration)  # type: ignore[arg-type]
            for which, seed in (("first", 0), ("later", 1)):
                steps, seconds = _episode(env, seed)
                runs[action][which].append(steps / seconds)
            env.close()
    mono_rate = statistics.median(mono)
    local: dict[str, dict[str, Any]] = {a: {k: statistics.median(v) for k, v in r.items()} | {"runs": r}
                                        for a, r in runs.items()}
    result: dict[str, Any] = {
        "available": True, "scenario": scenario, "episode_steps": sc.total_steps, "rounds": rounds,
        "control_every": 10, "monolithic_steps_per_s": mono_rate, "monolithic_runs": mono, "local": local,
        "local_to_monolithic": local["wrench"]["later"] / mono_rate,
    }
    result["session"] = _bench_session(TrackEnv, scenario, session_duration)
    result["vector"] = {}
    for name, vector in (("sync_2", gym.vector.SyncVectorEnv), ("async_2", gym.vector.AsyncVectorEnv)):
        def make() -> Any:
            return gym.make("cdpr/Track-v0", scenario=scenario, action="wrench", duration=duration)

        envs = vector([make, make])
        envs.reset(seed=[0, 1])
        zeros = np.zeros(envs.action_space.shape or (), dtype=np.float32)
        envs.step(zeros)  # the async workers' first step pays their imports
        t0 = time.perf_counter()
        for _ in range(vector_steps):
            envs.step(zeros)
        seconds = time.perf_counter() - t0
        envs.close()
        result["vector"][name] = {"env_steps": 2 * vector_steps, "sim_steps_per_s": 2 * vector_steps * 10 / seconds}
    return result


def _bench_session(env_class: Any, scenario: str, duration: float) -> dict[str, Any]:
    """One episode of the env as the controller of ``cdpr up --without controller`` on loopback."""
    from cdpr.tools.launch import free_port

    port = free_port()
    up = subprocess.Popen([sys.executable, "-m", "cdpr", "up", scenario, "--duration", repr(duration), "--without",
                           "controller", "--listen", f"tcp/127.0.0.1:{port}", "--quiet"],
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        env = env_class(scenario, "residual", 10, duration=duration, connect=f"tcp/127.0.0.1:{port}",
                        session_timeout=120.0)
        steps, seconds = _episode(env, 0)
        env.close()
        _, err = up.communicate(timeout=120.0)
    finally:
        if up.poll() is None:
            up.kill()
            up.communicate()
    if up.returncode != 0:
        raise RuntimeError(f"the session of the gym bench failed: {err[-2000:]}")
    return {"duration_s": duration, "sim_steps": steps, "sim_steps_per_s": steps / seconds,
            "env_steps_per_s": steps / 10 / seconds}
