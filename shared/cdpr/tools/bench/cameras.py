"""``cdpr bench``'s cameras part (#26): what a camera costs the loop.

The same ``caroca_15kg`` session without a camera, with a 60 Hz camera whose frames carry marker features
only, and with a 30 Hz camera that also draws 640 × 480 images (``image: true``), in fast mode, in rounds of
adjacent runs (none, features, images; none, …): a camera's cost is the median over the rounds of
1 − its rate / the rate without a camera in the same round (identical runs spread by ~10 % on this shared
machine; a round's runs share its minutes). Then realtime at 1 kHz without and with the image camera, in
rounds too, a sleeping probe beside each run (the share of steps started on time): the drop is the median of
the rounds' drops.
The camera looks down from the frame's top at the platform's four top corners (scenario files written to a
temporary directory). Images need OpenCV (``pip install 'cdpr[camera]'``).
"""

from __future__ import annotations

import statistics
import tempfile
from importlib.util import find_spec
from pathlib import Path
from typing import Any

import yaml

from cdpr.config.scenario import load_scenario
from cdpr.tools.bench.loops import SleeperProbe, _run_sessions

SCENARIO = "caroca_15kg"
CORNERS = [[0.6, 0.3, 0.2], [-0.6, 0.3, 0.2], [-0.6, -0.3, 0.2], [0.6, -0.3, 0.2]]


def camera_spec(rate: float, image: bool) -> dict[str, Any]:
    return {
        "name": "top",
        "mount": {"body": "frame", "position": [0.0, 0.0, 3.4], "look_at": [0.0, 0.0, 0.0], "up": [0.0, 1.0, 0.0]},
        "intrinsics": {"fx": 600.0, "fy": 600.0, "cx": 320.0, "cy": 240.0, "width": 640, "height": 480},
        "distortion": [-0.05, 0.01, 0.0, 0.0, 0.0],
        "rate": rate,
        "pixel_sigma": 0.5,
        "image": image,
        "markers": {"frame": "platform", "points": CORNERS},
    }


def _scenarios(folder: Path) -> dict[str, str]:
    base = yaml.safe_load(Path(load_scenario(SCENARIO).source).read_text(encoding="utf-8"))
    out = {"none": SCENARIO}
    for name, cam in (("features_60hz", camera_spec(60.0, False)), ("images_30hz", camera_spec(30.0, True))):
        spec = {**base, "name": f"bench_camera_{name}", "sim": {**base.get("sim", {}), "cameras": [cam]}}
        path = folder / f"{name}.yaml"
        path.write_text(yaml.safe_dump(spec, sort_keys=False), encoding="utf-8")
        out[name] = str(path)
    return out


def bench_cameras(duration: float, rounds: int, realtime_duration: float, realtime_rounds: int = 1) -> dict[str, Any]:
    """The fast-mode rates and costs of each camera, and the realtime on-time share with the image camera."""
    if find_spec("cv2") is None:  # the image camera's drawing (in the sim's image process: not imported here)
        return {"available": False, "reason": "opencv-python-headless is not installed (pip install 'cdpr[camera]')"}
    with tempfile.TemporaryDirectory(prefix="cdpr-bench-cameras-") as tmp:
        scenarios = _scenarios(Path(tmp))
        rates: dict[str, list[float]] = {name: [] for name in scenarios}
        faults: dict[str, int] = {}
        for _ in range(rounds):
            for name, path in scenarios.items():
                s = _run_sessions([[path, "--duration", repr(duration)]], f"cam{name.split('_')[0]}", 900.0)[0]
                rates[name].append(s["rate"])
                for k, v in s["faults"].get("sim", {}).items():
                    faults[k] = faults.get(k, 0) + v
        fast = {name: statistics.median(r) for name, r in rates.items()}
        costs = {name: [1.0 - x / base for x, base in zip(rates[name], rates["none"], strict=True)]
                 for name in ("features_60hz", "images_30hz")}
        runs: dict[str, list[dict[str, Any]]] = {"none": [], "images_30hz": []}
        for _ in range(realtime_rounds):
            for name, got in runs.items():
                with SleeperProbe(0.001) as probe:
                    s = _run_sessions([[scenarios[name], "--mode", "realtime", "--duration",
                                        repr(realtime_duration)]], "camrt", 900.0)[0]
                got.append({"on_time_fraction": s["on_time_fraction"], "probe_on_time_fraction":
                            probe.on_time_fraction, "lateness_p99_ms": s["lateness_p99_ms"],
                            "images_skipped": s["faults"].get("sim", {}).get("camera_images_skipped", 0)})
    realtime = {name: {k: statistics.median([r[k] for r in got]) for k in got[0]} for name, got in runs.items()}
    drops = [100.0 * (a["on_time_fraction"] - b["on_time_fraction"])
             for a, b in zip(runs["none"], runs["images_30hz"], strict=True)]
    probe_drops = [100.0 * (a["probe_on_time_fraction"] - b["probe_on_time_fraction"])
                   for a, b in zip(runs["none"], runs["images_30hz"], strict=True)]
    return {
        "available": True, "duration_s": duration, "repeats": rounds, "realtime_duration_s": realtime_duration,
        "realtime_repeats": realtime_rounds,
        "steps_per_s": fast, "runs_steps_per_s": rates, "runs_costs": costs,
        "features_60hz_cost": statistics.median(costs["features_60hz"]),
        "images_30hz_cost": statistics.median(costs["images_30hz"]),
        "faults": faults,
        "realtime": realtime, "realtime_runs": runs,
        "realtime_on_time_drop_points": statistics.median(drops), "realtime_runs_drop_points": drops,
        "realtime_probe_drop_points": statistics.median(probe_drops),
    }
