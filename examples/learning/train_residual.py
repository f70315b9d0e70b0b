"""Train a residual policy with Stable-Baselines3 (TD3, or SAC) on a perturbed CAROCA, plot its learning curve.

The platform is heavier than the controller's model says (plant only: 15 kg nominal, 16.5 to 18 kg real, drawn
per episode from the env's seed): feedback linearisation then sags below its setpoint. The policy adds a wrench
to the law's (action ``residual``) every 10 ms. Every ``--eval-every`` env steps the deterministic policy runs
one episode of a fixed 17.25 kg platform; its RMS position error and return go into the curve, beside the plain
law's (a residual of 0) and the untrained policy's (step 0).

    pip install torch==2.13.0 -e '.[train]'                # the CPU build of torch, then SB3 and the rest
    OMP_NUM_THREADS=1 python examples/learning/train_residual.py --out runs/learning   # 30 000 env steps, ~5 min
    cdpr run caroca_15kg --duration 3 --algo td3 --policy runs/learning/td3_residual.zip --rrd runs/td3.rrd

Writes ``td3_residual.zip`` (the model) and ``td3_residual.env.json`` (the environment it was trained in: observations
normalised onto [-1, 1], position error weighted 1000 per m, terminated beyond 5 mm or 0.05 rad of error),
``curve.json`` and ``learning_curve.png`` to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import cdpr.gym  # noqa: F401  (registers cdpr/Track-v0)

SCENARIO, DURATION = "caroca_15kg", 3.0
TRAIN_MASS = [{"path": "platform.mass", "op": "scale", "uniform": [1.10, 1.20], "plant_only": True}]
EVAL_MASS = [{"path": "platform.mass", "op": "scale", "choice": [1.15], "plant_only": True}]


# what the policy was trained in: saved beside the model (td3_residual.env.json), read by `cdpr run --policy`
ENV = {"action": "residual", "control_every": 10, "normalize": True, "reward_weights": {"position": 1000.0},
       "limits": {"max_position_error": 0.005, "max_orientation_error": 0.05}}  # mm-scale errors: a visible input


def make(randomize: list[dict]) -> gym.Env:
    return gym.make("cdpr/Track-v0", scenario=SCENARIO, duration=DURATION, randomize=randomize, **ENV)


def evaluate(env: gym.Env, policy) -> dict[str, float]:
    """One deterministic episode: its return and RMS position error (m)."""
    obs, _ = env.reset(seed=0)
    total, done = 0.0, False
    while not done:
        obs, reward, terminated, truncated, info = env.step(policy(obs))
        total += reward
        done = terminated or truncated
    return {"return": total, "rms_position_error": info["episode_stats"]["rms_position_error"],
            "terminated": bool(terminated)}


def main() -> None:
    import stable_baselines3
    from stable_baselines3.common.callbacks import BaseCallback

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=30000, help="env steps of training")
    parser.add_argument("--eval-every", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--out", type=Path, default=Path("runs/learning"))
    parser.add_argument("--algo", choices=("td3", "sac"), default="td3")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)

    env, eval_env = make(TRAIN_MASS), make(EVAL_MASS)
    algo = getattr(stable_baselines3, args.algo.upper())
    model = algo("MlpPolicy", env, seed=args.seed, learning_starts=1000, batch_size=256, gamma=0.98,
                 policy_kwargs={"net_arch": [64, 64]}, verbose=0, device="cpu")
    zero = np.zeros(env.action_space.shape, dtype=np.float32)
    curve = {"algo": args.algo.upper(), "seed": args.seed, "plain_law": evaluate(eval_env, lambda obs: zero),
             "points": []}
    started = time.monotonic()

    def point(steps: int) -> None:
        e = evaluate(eval_env, lambda obs: model.predict(obs, deterministic=True)[0])
        e.update(steps=steps, wall_s=time.monotonic() - started)
        curve["points"].append(e)
        print(f"{steps:7d} env steps  {e['wall_s']:6.0f} s  return {e['return']:8.2f}  "
              f"RMS error {1e3 * e['rms_position_error']:.3f} mm (plain law "
              f"{1e3 * curve['plain_law']['rms_position_error']:.3f} mm)", flush=True)

    class Evaluate(BaseCallback):
        def _on_step(self) -> bool:
            if self.num_timesteps % args.eval_every == 0:
                point(self.num_timesteps)
            return True

    point(0)
    model.learn(total_timesteps=args.steps, callback=Evaluate())
    model.save(args.out / f"{args.algo}_residual.zip")
    (args.out / f"{args.algo}_residual.env.json").write_text(json.dumps(ENV) + "\n", encoding="utf-8")
    (args.out / "curve.json").write_text(json.dumps(curve, indent=1) + "\n", encoding="utf-8")
    plot(curve, args.out / "learning_curve.png")


def plot(curve: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pts = curve["points"]
    steps = [p["steps"] for p in pts]
    fig, (a, b) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    a.plot(steps, [p["return"] for p in pts], "o-", label=f"{curve['algo']} residual policy")
    a.axhline(curve["plain_law"]["return"], color="k", ls="--", label="feedback linearisation alone")
    a.set_ylabel("evaluation return")
    a.legend()
    b.plot(steps, [1e3 * p["rms_position_error"] for p in pts], "o-")
    b.axhline(1e3 * curve["plain_law"]["rms_position_error"], color="k", ls="--")
    b.set_ylabel("RMS position error, mm")
    b.set_xlabel("env steps of training (10 ms each)")
    fig.suptitle(f"cdpr/Track-v0, caroca_15kg 3 s, platform 15 % heavier than the model: {curve['algo']}")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
