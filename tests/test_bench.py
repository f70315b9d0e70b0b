"""`cdpr bench --quick`: every part runs and the JSON has the documented shape (never its speed)."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from cdpr.config.robot import load_robot
from cdpr.config.scenario import load_scenario
from cdpr.tools.bench import QUICK, robot_spec, rt_priority_allowed, scenario_yaml, target_line, tda_path
from cdpr.tools.bench.loops import _process_cpu, cpu_latency_allowed
from conftest import cdpr, wait_no_processes

pytestmark = pytest.mark.slow


def _positive(x: object) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) and x > 0


@pytest.fixture(scope="module")
def bench(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, str]:
    out = tmp_path_factory.mktemp("bench") / "nested" / "bench.json"
    proc = cdpr("bench", "--quick", "--out", str(out), timeout=600, check=True)
    assert not wait_no_processes("--session bench", timeout=10.0), "bench sessions were left running"
    return json.loads(out.read_text()), proc.stdout


def test_top_level_and_machine(bench: tuple[dict, str]) -> None:
    r, _ = bench
    assert r["version"] == 13
    assert r["quick"] is True
    assert r["scenario"] == "caroca_15kg"
    for key in ("plan", "machine", "started", "elapsed_s", "monolithic", "distributed", "loops", "deliveries",
                "startup", "zenoh_rtt", "realtime", "realtime_2khz", "tda", "scaling", "mujoco", "ros2", "cameras",
                "gym", "fk", "targets"):
        assert key in r, key
    m = r["machine"]
    assert isinstance(m["nproc"], int)
    assert m["nproc"] >= 1
    assert isinstance(m["cpu_model"], str)
    assert len(m["loadavg"]) == 3
    assert len(m["loadavg_end"]) == 3
    parts = ["loops", "startup", "zenoh_rtt", "realtime", "tda", "scaling", "mujoco", "ros2", "cameras", "gym", "fk"]
    assert list(m["loadavg_by_part"]) == parts
    assert all(isinstance(x, float) and x >= 0 for x in m["loadavg_by_part"].values())
    assert _positive(r["elapsed_s"])
    assert r["plan"]["tda_sizes"] == list(QUICK.tda_sizes)


def test_loop_figures(bench: tuple[dict, str]) -> None:
    r, _ = bench
    mono, dist = r["monolithic"], r["distributed"]
    assert _positive(mono["steps_per_s"])
    assert mono["steps"] == QUICK.mono_steps
    variants = ("multi_process", "multi_process_recording", "multi_process_recording_both", "in_process")
    assert len(mono["runs_steps_per_s"]) == QUICK.mono_repeats * QUICK.loop_repeats * len(variants)
    assert all(map(_positive, mono["runs_steps_per_s"]))
    assert set(mono["us_per_step"]) == {"sim", "controller", "trajectory", "messages"}
    assert all(map(_positive, mono["us_per_step"].values()))
    assert dist["steps"] == round(QUICK.loop_duration / 0.001)
    for key in ("steps_per_s", "rtf", "ratio_to_monolithic"):
        assert _positive(dist[key]), key
    assert mono["steps_per_s"] == pytest.approx(statistics.median(mono["runs_steps_per_s"]))
    for name in variants:  # against the monolithic runs interleaved with them
        v = r["loops"][name]
        assert len(v["runs_steps_per_s"]) == QUICK.loop_repeats
        assert v["ratio_to_monolithic"] == pytest.approx(v["steps_per_s"] / mono["steps_per_s"])
    assert isinstance(dist["state_digest"], str)
    assert len(dist["state_digest"]) == 64
    assert dist["cpu_us_per_step"] is None or _positive(dist["cpu_us_per_step"])
    # /proc counts CPU in clock ticks (10 ms): over a short run a quiet process (`run`) may show none
    assert all(math.isfinite(v) and v >= 0 for v in dist["cpu_us_per_step_by_process"].values())
    if dist["cpu_us_per_step_by_process"]:  # each service under its own name (python -m cdpr.runtime NAME)
        assert {"sim", "controller", "trajectory", "clock"} <= set(dist["cpu_us_per_step_by_process"])
    loops = r["loops"]
    assert loops["multi_process"] == dist
    for name in ("multi_process_recording", "multi_process_recording_both", "in_process"):
        assert _positive(loops[name]["steps_per_s"]), name
        assert loops[name]["steps"] == dist["steps"], name
        assert loops[name]["state_digest"] == dist["state_digest"], name  # the same session, every way
    for name in ("multi_process_recording", "multi_process_recording_both"):
        by = loops[name]["cpu_us_per_step_by_process"]
        assert not by or "recorder" in by, name
    assert loops["recording_cost"] == pytest.approx(
        1 - loops["multi_process_recording"]["steps_per_s"] / dist["steps_per_s"])
    assert loops["recording_both_cost"] == pytest.approx(
        1 - loops["multi_process_recording_both"]["steps_per_s"] / dist["steps_per_s"])
    assert {"recording_cost<=0.15", "recording_both_cost<=0.15"} <= set(r["targets"])
    d = r["deliveries"]
    assert d["steps"] == QUICK.mono_steps
    assert set(d["topics"]) >= {"tick", "state", "setpoints", "command", "telemetry"}
    assert d["topics"]["state"]["messages_per_step"] == pytest.approx(1.0, abs=0.01)  # the loop's round trip
    assert d["topics"]["command"]["messages_per_step"] == pytest.approx(1.0, abs=0.01)
    assert d["deliveries_per_step"] == pytest.approx(sum(t["deliveries_per_step"] for t in d["topics"].values()))
    s = r["startup"]
    assert s["steps"] == 50
    assert len(s["multi_process_runs_s"]) == len(s["in_process_runs_s"]) == QUICK.startup_repeats
    assert _positive(s["multi_process_s"])
    assert _positive(s["in_process_s"])


def test_transport_and_realtime(bench: tuple[dict, str]) -> None:
    r, _ = bench
    rtt, rt = r["zenoh_rtt"], r["realtime"]
    for way in (rtt, rtt["peers"]):  # clients through the router, then peers linked directly
        assert way["count"] == QUICK.rtt_count
        for key in ("median_us", "p99_us", "min_us", "one_way_us", "ping_cpu_us", "echo_cpu_us"):
            assert _positive(way[key]), key
        assert way["min_us"] <= way["median_us"] <= way["p99_us"]
    fast = r["realtime_2khz"]
    assert rt["steps"] == round(QUICK.realtime_duration / 0.001)
    assert fast["steps"] == round(QUICK.realtime_2khz_duration / 0.0005)
    assert (rt["dt"], fast["dt"]) == (0.001, 0.0005)
    runs = []
    for part, names in ((rt, ("realtime_on_time_rt_priority>=0.999",)),
                        (fast, ("realtime_2khz_rt_priority>=0.999", "realtime_2khz>=0.99"))):
        runs += [part] + [part[k] for k in ("cpu_latency", "rt_priority") if part[k] is not None]
        if part["rt_priority"] is not None:  # SCHED_FIFO is permitted here: a run used it
            assert part["rt_priority"]["priority"] == 10
            assert part["rt_priority"]["steps"] == part["steps"]
            assert all(name in r["targets"] for name in names)
        assert part["rt_priority"] is None or rt_priority_allowed()
        assert (part["cpu_latency"] is not None) == cpu_latency_allowed()  # root here: the limit can be held
    assert "realtime_1khz>=probe-0.001" in r["targets"]
    for run in runs:
        assert 0.0 <= run["on_time_fraction"] <= 1.0
        assert isinstance(run["late_ticks"], int)
        lateness = [run[f"lateness_{p}_ms"] for p in ("p50", "p99", "p999", "max")]
        assert all(isinstance(x, float) for x in lateness)
        assert lateness == sorted(lateness)
        # the run's profile: the loop's processes, their CPU and their waits for a CPU, per step
        assert {"sim", "controller", "clock", "trajectory"} <= set(run["cpu_us_per_step_by_process"])
        assert all(_positive(run["cpu_us_per_step_by_process"][k]) for k in ("sim", "controller"))
        assert set(run["wait_us_per_step_by_process"]) == set(run["cpu_us_per_step_by_process"])
        assert all(w >= 0 for w in run["wait_us_per_step_by_process"].values())
        assert 0.0 <= run["machine_idle_fraction"] <= 1.0
        assert 0.0 <= run["machine_steal_fraction"] <= 1.0
        assert 0.0 < run["probe_on_time_fraction"] <= 1.0  # the sleeping probe reported
    assert r["targets"]["realtime_on_time>=0.999"]["machine"] == rt["probe_on_time_fraction"]


def test_tda_and_scaling(bench: tuple[dict, str]) -> None:
    r, _ = bench
    sizes = r["tda"]["sizes"]
    assert [s["cables"] for s in sizes] == list(QUICK.tda_sizes)
    for s in sizes:
        assert set(s["methods"]) == {"qp", "closed-form", "improved-closed-form", "continuity", "qp_solver"}
        for stats in s["methods"].values():
            assert _positive(stats["median_us"])
            assert stats["p90_us"] >= stats["median_us"]
            assert sum(stats["statuses"].values()) > 0
        assert s["methods"]["qp"]["statuses"] == {"optimal": s["calls"]}
        assert 0.0 <= s["qp_max_difference_N"] < 1e-6
    sessions = r["scaling"]["sessions"]
    assert [s["sessions"] for s in sessions] == list(QUICK.session_counts)
    for s in sessions:
        assert _positive(s["median_steps_per_s"])
        assert _positive(s["aggregate_steps_per_s"])
        assert s["aggregate_steps_per_s"] >= s["median_steps_per_s"]
    cables = r["scaling"]["cables"]
    assert [c["cables"] for c in cables] == list(QUICK.cable_counts)
    assert all(_positive(c["steps_per_s"]) and c["steps"] > 0 for c in cables)
    for name, t in r["targets"].items():
        assert isinstance(t["met"], bool), name
        assert isinstance(t["value"], (int, float)), name


def test_table_is_printed(bench: tuple[dict, str]) -> None:
    _, stdout = bench
    for text in ("monolithic loop", "distributed loop", "in-process composition", "cost of recording",
                 "with .rrd and .mcap", "cost of both sinks",
                 "messages delivered per step", "50-step session", "Zenoh round trip", "peers linked directly",
                 "realtime",
                 "tension distribution", "scaling", "targets", "load as each part started"):
        assert text in stdout


def test_a_missed_realtime_target_shows_what_the_machine_gave_a_sleeping_thread() -> None:
    missed = target_line("realtime_on_time>=0.999", {"value": 0.99587, "met": False, "machine": 0.99639})
    assert missed.endswith("MISSED (a sleeping probe beside it: 99.639 % on time)")
    met = target_line("realtime_on_time>=0.999", {"value": 0.9995, "met": True, "machine": 0.9999})
    assert met.endswith("met")
    assert target_line("deliveries_per_step<=3", {"value": 3.5, "met": False}).endswith("MISSED")


@pytest.mark.parametrize("m", [4, 8, 12, 16])
def test_generated_robots_load_and_hold_the_platform(tmp_path: Path, m: int) -> None:
    spec = robot_spec(m)
    (tmp_path / "robot.yaml").write_text(yaml.safe_dump(spec), encoding="utf-8")
    robot = load_robot(tmp_path / "robot.yaml")  # the loader's own checks (rank at home, …)
    assert robot.m == m
    assert robot.mode == ("point_mass" if m == 4 else "spatial")
    scenario = scenario_yaml("robot.yaml", m, 1.0)
    (tmp_path / "scenario.yaml").write_text(yaml.safe_dump(scenario), encoding="utf-8")
    sc = load_scenario(tmp_path / "scenario.yaml")
    assert sc.robot.m == m
    assert sc.total_steps == 1000
    path = tda_path(sc.robot, 20)
    rows = 3 if m == 4 else 6
    assert all(W.shape == (rows, m) and w.shape == (rows,) for W, w in path)
    # the path's wrenches carry the platform's weight (the motion is slow)
    assert all(abs(w[2] - sc.robot.mass * 9.81) < 0.2 * sc.robot.mass * 9.81 for _, w in path)
    assert robot_spec(m) == spec  # deterministic
    assert np.isfinite([c["frame"] for c in spec["cables"]]).all()


def test_process_cpu_by_role_and_none_once_a_child_has_exited() -> None:
    """The per-process CPU of a session's tree: by role from the command lines while the processes
    run, and no figure at all once one of them has exited and not been reaped (a zombie has no
    command line: the session's last progress line can come while its services are leaving)."""
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)", "-m", "cdpr.runtime", "sim"])
    try:
        deadline = time.monotonic() + 10
        while (cpu := _process_cpu(os.getpid())) is not None and "sim" not in cpu and time.monotonic() < deadline:
            time.sleep(0.05)
        assert cpu is not None
        assert "sim" in cpu  # `… -m cdpr.runtime sim` on its command line
        child.kill()
        while (state := Path(f"/proc/{child.pid}/stat").read_text().rsplit(")", 1)[1].split()[0]) != "Z":
            assert time.monotonic() < deadline, state
            time.sleep(0.05)
        assert _process_cpu(os.getpid()) is None
    finally:
        child.kill()
        child.wait()


def test_mujoco_agrees_with_the_project_s_dynamics_step_by_step() -> None:
    """An independent check of eq. 5: MuJoCo's acceleration of the peer model (cdpr.tools.bench.mujoco_peer)
    equals cdpr.mechanics.dynamics.forward_dynamics for the same pose, twist and tensions, cable damping
    included (MuJoCo's tendon damping)."""
    import mujoco

    from cdpr.mechanics.dynamics import forward_dynamics
    from cdpr.mechanics.kinematics import cable_length_rates, inverse_kinematics
    from cdpr.mechanics.rotation import quat_to_matrix
    from cdpr.tools.bench.mujoco_peer import MujocoPlant

    base = load_scenario("caroca_15kg")
    robot = base.robot.replace(cable_damping=20.0)  # a damping that shows
    plant = MujocoPlant(dataclasses.replace(base, robot=robot))
    rng = np.random.default_rng(3)
    for _ in range(5):
        p = np.array([0.3, -0.2, 0.7]) + 0.1 * rng.standard_normal(3)
        q = rng.standard_normal(4)
        q /= np.linalg.norm(q)
        q = 0.9 * np.array([0.0, 0.0, 0.0, 1.0]) + 0.1 * q  # near level
        q /= np.linalg.norm(q)
        R = quat_to_matrix(q)
        twist = 0.3 * rng.standard_normal(6)
        f = 20.0 + 30.0 * rng.random(robot.m)
        d = plant.data
        d.qpos[:] = [*p, q[3], q[0], q[1], q[2]]
        d.qvel[:3], d.qvel[3:] = twist[:3], R.T @ twist[3:]  # a free joint's angular velocity: body frame
        d.ctrl[:] = f
        mujoco.mj_forward(plant.model, d)
        kin = inverse_kinematics(robot, p, R)
        rates = cable_length_rates(kin, twist)
        expected = forward_dynamics(robot, R, twist, kin.wrench_matrix @ (f + robot.cable_damping * rates))
        got = np.r_[d.qacc[:3], R @ d.qacc[3:]]
        np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-9)


def test_the_mujoco_peer_in_the_bench(bench: tuple[dict, str]) -> None:
    r, text = bench
    mj = r["mujoco"]
    assert mj["available"] is True
    assert _positive(mj["steps_per_s"])
    assert _positive(mj["monolithic_steps_per_s"])
    assert mj["monolithic_to_peer"] == pytest.approx(mj["monolithic_steps_per_s"] / mj["steps_per_s"])
    agree = mj["agreement"]
    assert agree["steps"] == load_scenario("caroca_15kg").total_steps
    assert agree["max_position_difference_m"] < 5e-4  # two integrators, one controller: tens of µm
    assert agree["max_orientation_difference_rad"] < 1e-5
    assert "7 the MuJoCo peer" in text
    assert "monolithic/mujoco_peer>=1.0" in r["targets"]


def test_the_ros2_controller_in_the_bench(bench: tuple[dict, str]) -> None:
    r, text = bench
    ros = r["ros2"]
    assert ros["available"] is True
    assert ros["steps"] == round(QUICK.ros2_duration / load_scenario("caroca_15kg").dt)
    for kind in ("cdpr", "ros2"):
        assert _positive(ros[kind]["steps_per_s"])
        assert len(ros[kind]["runs_steps_per_s"]) == QUICK.ros2_repeats
        assert ros[kind]["rms_position_error"] < 1e-3
    assert ros["ratio"] == pytest.approx(ros["ros2"]["steps_per_s"] / ros["cdpr"]["steps_per_s"])
    by = ros["ros2"]["cpu_us_per_step_by_process"]
    assert "ros2" not in by  # the ros2 node in the sim's process
    assert "sim" not in by
    assert _positive(by["sim+ros2"])
    assert _positive(by["ros2_controller"])
    node = by["sim+ros2"] - ros["cdpr"]["cpu_us_per_step_by_process"]["sim"]
    assert ros["ros2"]["ros2_node_cpu_us_per_step"] == pytest.approx(node)
    assert ros["ros2"]["ros2_side_cpu_us_per_step"] == pytest.approx(node + by["ros2_controller"])
    assert "8 a ROS 2 controller" in text
    assert "ros2_controller/cdpr_controller>=0.5" in r["targets"]


def test_what_cameras_cost_in_the_bench(bench: tuple[dict, str]) -> None:
    r, text = bench
    cams = r["cameras"]
    assert cams["available"] is True
    for name in ("none", "features_60hz", "images_30hz"):
        assert _positive(cams["steps_per_s"][name])
        assert len(cams["runs_steps_per_s"][name]) == QUICK.camera_repeats
    runs = cams["runs_steps_per_s"]
    for name in ("features_60hz", "images_30hz"):  # each round's cost, against the run without a camera beside it
        pairs = zip(runs[name], runs["none"], strict=True)
        assert cams["runs_costs"][name] == pytest.approx([1 - x / y for x, y in pairs])
        assert cams[f"{name}_cost"] == pytest.approx(statistics.median(cams["runs_costs"][name]))
    for name in ("none", "images_30hz"):
        assert 0.0 <= cams["realtime"][name]["on_time_fraction"] <= 1.0
        assert len(cams["realtime_runs"][name]) == QUICK.camera_realtime_repeats
    rounds = zip(cams["realtime_runs"]["none"], cams["realtime_runs"]["images_30hz"], strict=True)
    assert cams["realtime_on_time_drop_points"] == pytest.approx(statistics.median(
        100 * (a["on_time_fraction"] - b["on_time_fraction"]) for a, b in rounds))
    assert "9 cameras" in text
    assert "camera_images_30hz_cost<=0.25" in r["targets"]


def test_the_gymnasium_environment_in_the_bench(bench: tuple[dict, str]) -> None:
    r, text = bench
    g = r["gym"]
    assert g["available"] is True
    assert g["episode_steps"] == round(QUICK.gym_duration / load_scenario("caroca_15kg").dt)
    for action in ("wrench", "residual", "tensions"):
        assert _positive(g["local"][action]["first"])
        assert _positive(g["local"][action]["later"])
        assert len(g["local"][action]["runs"]["later"]) == QUICK.gym_rounds
    assert g["local_to_monolithic"] == pytest.approx(g["local"]["wrench"]["later"] / g["monolithic_steps_per_s"])
    assert g["session"]["sim_steps"] == round(QUICK.gym_session_duration / load_scenario("caroca_15kg").dt)
    assert _positive(g["session"]["sim_steps_per_s"])
    assert _positive(g["vector"]["async_2"]["sim_steps_per_s"])
    assert "10 the Gymnasium environment" in text
    assert "gym_local/monolithic>=2" in r["targets"]
