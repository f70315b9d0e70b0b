"""A study's aggregate throughput against the same points run one at a time (``cdpr study-bench``).

The points are CAROCA 15 kg sessions cut to ``duration`` seconds, each with its own proportional gain
(so no two are the same session). First they run one after the other, each one alone on the machine,
through the same point runner a study uses; then the same points run as a study on a local Ray (its
workers warmed up first, as on a cluster that is already running). Both throughputs are simulated
steps over wall time, process start-up included: what a researcher waits for.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from cdpr.errors import InputError
from cdpr.tools.study.engine import connect_ray, need_ray, prepare, run_study
from cdpr.tools.study.runner import run_point


def bench_study_file(folder: Path, points: int, duration: float, mode: str) -> Path:
    gains = [round(float(k), 3) for k in np.linspace(1400.0, 1600.0, points)] if points > 1 else [1500.0]
    study = {"name": "study_bench", "description": "cdpr study-bench: throughput of a study",
             "scenario": "caroca_15kg", "set": {"duration": float(duration)}, "mode": mode,
             "parameters": [{"path": "controller.kp", "values": gains}],
             "metrics": ["rms_position_error", "rate"]}
    path = folder / "study_bench.yaml"
    path.write_text(yaml.safe_dump(study, sort_keys=False), encoding="utf-8")
    return path


def study_throughput(points: int, duration: float, mode: str = "auto", address: str | None = None,
                     progress: bool = False, repeats: int = 1) -> dict[str, Any]:
    """Steps/s of ``points`` sessions of ``duration`` s run alone, one at a time, and as a study.

    With ``repeats`` > 1 the two phases alternate that many times (alone, study, alone, study, ...), so
    that a load from elsewhere on the machine weighs on both alike; the figures are the medians.
    Returns ``{"alone_steps_per_s", "study_steps_per_s", "ratio", "mode", ...}``.
    """
    if points < 1 or not duration > 0 or repeats < 1:
        raise InputError(f"study-bench: needs points >= 1, duration > 0 and repeats >= 1 (got {points}, "
                         f"{duration}, {repeats})")
    need_ray()
    with tempfile.TemporaryDirectory(prefix="cdpr-study-bench-") as tmp:
        folder = Path(tmp)
        study_file = bench_study_file(folder, points, duration, mode)
        prep = prepare(study_file, folder / "alone", None)
        import ray

        cluster: dict[str, Any] = {}
        alone_rates, study_rates, rates, loads = [], [], [], []
        steps_per_point, failed, alone_walls, study_walls = 0, 0, [], []
        for r in range(repeats):
            load_before = os.getloadavg()[0]
            alone_steps, alone_wall = 0, 0.0
            for point in prep.todo:
                t0 = time.monotonic()
                result = run_point({"id": point.id, "files": point.files, "mode": prep.mode, "split": point.split,
                                    "record": False, "timeout": prep.spec.timeout})
                alone_wall += time.monotonic() - t0
                summary = result.get("summary") or {}
                failed += result["status"] != "ok"
                alone_steps += int(summary.get("steps") or 0)
                if summary.get("rate"):
                    rates.append(float(summary["rate"]))
            steps_per_point = alone_steps // points
            if not cluster:
                cluster = connect_ray(address)
                warm = ray.remote(_nothing).options(num_cpus=1)
                ray.get([warm.remote() for _ in range(max(1, int(cluster["cpus"])))])  # workers exist first
            summary = run_study(study_file, folder / f"study{r}", address=address, progress=progress)
            failed += summary["failed"]
            alone_rates.append(alone_steps / alone_wall if alone_wall > 0 else 0.0)
            study_rates.append(summary["steps_per_s"] or 0.0)
            alone_walls.append(round(alone_wall, 2))
            study_walls.append(summary["wall_s"])
            loads.append(round((load_before + os.getloadavg()[0]) / 2, 2))
        alone_rate, study_rate = float(np.median(alone_rates)), float(np.median(study_rates))
        paired = [s / a for a, s in zip(alone_rates, study_rates, strict=True) if a > 0]
        return {
            "alone_steps_per_s": round(alone_rate, 1),
            "study_steps_per_s": round(study_rate, 1),
            "ratio": round(float(np.median(paired)), 3) if paired else None,  # each study against the alone run
            #                                                            just before it, the median of those
            "mode": prep.mode,
            "points": points,
            "duration": duration,
            "steps_per_point": steps_per_point,
            "repeats": repeats,
            "ratios": [round(x, 3) for x in paired],
            "alone_wall_s": alone_walls,
            "study_wall_s": study_walls,
            "session_loop_steps_per_s": round(float(np.median(rates)), 1) if rates else None,
            "load_avg_1min": loads,
            "cpus": cluster["cpus"],
            "nodes": cluster["nodes"],
            "failed": failed,
        }


def _nothing() -> None:
    return None
