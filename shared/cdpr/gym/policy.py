"""A trained policy as a session's controller: ``python -m cdpr.gym.policy POLICY --connect tcp/host:7447``.

The policy acts through ``cdpr/Track-v0`` in session mode (the same observations, actions and hold as in
training), so it is a controller like any other: ``cdpr run SCENARIO --policy POLICY --rrd run.rrd`` runs it in
a normal session, recorded to Rerun, and it can join a session on another machine. ``POLICY`` is

* a Stable-Baselines3 model file ``*.zip`` (``--algo`` names its algorithm: sac, ppo, td3, a2c, ddpg), or
* ``module:function``, a Python function from an observation to an action (numpy arrays); ``cdpr.gym.policy:zero``
  is the policy that always answers 0 (with ``--action residual``: the scenario's own controller).

A model file may carry the environment it was trained in beside it: ``model.zip`` → ``model.env.json``, a map of
``cdpr/Track-v0`` options (``action``, ``control_every``, ``normalize``, ``reward_weights``, ``limits``). Options
given on the command line win over it.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from cdpr.errors import InputError

Policy = Callable[[np.ndarray], np.ndarray]
ALGORITHMS = ("sac", "ppo", "td3", "a2c", "ddpg")


def zero(observation: np.ndarray) -> np.ndarray:
    """The policy that never acts: 0 (its size is the action space's, set by :func:`run_policy`)."""
    return np.zeros(0, dtype=np.float32)


def load_policy(spec: str, algo: str = "sac") -> Policy:
    """The policy ``spec`` names (module docstring); an :class:`InputError` saying why it cannot be loaded."""
    if spec.endswith(".zip"):
        path = Path(spec)
        if not path.is_file():
            raise InputError(f"policy: no such file {spec}")
        if algo not in ALGORITHMS:
            raise InputError(f"--algo: one of {', '.join(ALGORITHMS)}, got {algo!r}")
        try:
            import stable_baselines3 as sb3  # type: ignore[import-not-found, unused-ignore]
        except ImportError:
            raise InputError(f"policy {spec}: a Stable-Baselines3 model needs pip install 'cdpr[train]'") from None
        try:
            model = getattr(sb3, algo.upper()).load(str(path), device="cpu")
        except Exception as exc:  # a file of another algorithm, or not a model at all
            raise InputError(f"policy {spec}: not a {algo.upper()} model ({type(exc).__name__}: {exc})") from None

        def predict(observation: np.ndarray) -> np.ndarray:
            action, _ = model.predict(observation, deterministic=True)
            return np.asarray(action, dtype=np.float32)

        return predict
    module, _, name = spec.partition(":")
    if not module or not name:
        raise InputError(f"policy: {spec!r} is neither a model file (*.zip) nor module:function")
    try:
        fn = getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError) as exc:
        raise InputError(f"policy {spec}: {exc}") from None
    if not callable(fn):
        raise InputError(f"policy {spec}: not a function")
    return fn  # type: ignore[no-any-return, unused-ignore]


ENV_OPTIONS = ("action", "control_every", "normalize", "reward_weights", "limits")


def env_options(spec: str) -> dict[str, Any]:
    """The environment options a model file carries (``model.env.json`` beside ``model.zip``; {} if none)."""
    if not spec.endswith(".zip"):
        return {}
    path = Path(spec[: -len(".zip")] + ".env.json")
    if not path.is_file():
        return {}
    try:
        options = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: not a JSON map of environment options ({exc})") from None
    if not isinstance(options, dict) or (unknown := set(options) - set(ENV_OPTIONS)):
        raise InputError(f"{path}: a map of {', '.join(ENV_OPTIONS)} (unknown: "
                         f"{', '.join(sorted(unknown)) if isinstance(options, dict) else 'not a map'})")
    return options


def run_policy(policy: Policy, scenario: str, options: dict[str, Any] | None = None, *,
               duration: float | None = None, connect: str | Sequence[str] = "tcp/127.0.0.1:7447",
               session: str = "default", episodes: int = 1, timeout: float = 120.0) -> list[dict[str, Any]]:
    """Run ``episodes`` episodes of ``policy`` as the controller of the session(s); each one's statistics.
    ``options``: the environment's (:data:`ENV_OPTIONS`; default: the residual action, 10 sim steps per step)."""
    from cdpr.gym.env import TrackEnv

    env = TrackEnv(scenario, duration=duration, connect=connect, session=session, session_timeout=timeout,
                   **(options or {}))
    size = env.action_space.shape or ()
    out = []
    try:
        for _ in range(episodes):
            obs, _ = env.reset(seed=0)
            done, info = False, dict[str, Any]()
            while not done:
                a = np.asarray(policy(obs), dtype=np.float32)
                a = np.zeros(size, dtype=np.float32) if a.size == 0 else a.reshape(size)
                obs, _, terminated, truncated, info = env.step(a)
                done = terminated or truncated
            out.append({**info["episode_stats"], "termination": info.get("termination"),
                        "session": info.get("session")})
    finally:
        env.close()
    return out


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m cdpr.gym.policy", description=__doc__.splitlines()[0])
    parser.add_argument("policy", help="a Stable-Baselines3 model (*.zip) or module:function")
    parser.add_argument("--scenario", default="caroca_15kg", help="the session's scenario (default caroca_15kg)")
    parser.add_argument("--duration", type=float, default=None, help="the session's duration, if overridden")
    parser.add_argument("--action", choices=("residual", "wrench", "tensions"), default=None,
                        help="the action space (default: the model's env.json, else residual)")
    parser.add_argument("--control-every", type=int, default=None,
                        help="sim steps per policy step (default: the model's env.json, else 10)")
    parser.add_argument("--algo", default="sac", help=f"a model file's algorithm: {', '.join(ALGORITHMS)}")
    parser.add_argument("--connect", action="append", default=[], help="the session's router (default "
                        "tcp/127.0.0.1:7447)")
    parser.add_argument("--session", default="default")
    parser.add_argument("--episodes", type=int, default=1, help="sessions to answer one after the other")
    parser.add_argument("--timeout", type=float, default=120.0, help="seconds to wait for a session")
    args = parser.parse_args(argv)
    try:
        policy = load_policy(args.policy, args.algo)
        options = env_options(args.policy)
        options.update({k: v for k, v in (("action", args.action), ("control_every", args.control_every))
                        if v is not None})
        stats = run_policy(policy, args.scenario, options, duration=args.duration,
                           connect=args.connect or ["tcp/127.0.0.1:7447"], session=args.session,
                           episodes=args.episodes, timeout=args.timeout)
    except (InputError, ValueError) as exc:
        sys.stderr.write(f"cdpr: error: {exc}\n")
        return 2
    for s in stats:
        print(json.dumps(s), flush=True)
    return 0


if __name__ == "__main__":
    code = main()
    sys.stdout.flush()
    sys.stderr.flush()
    # Zenoh's runtime threads outlive the closed session; an interpreter teardown beside them can abort the
    # process ("FATAL: exception not rethrown": a thread taking the GIL during finalization). Everything is
    # closed and flushed by now: leave without the teardown, as cdpr run's services do (cdpr.tools.launch).
    os._exit(code)
