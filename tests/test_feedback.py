"""Control from what a real robot measures (``controller.feedback: sensors``): the estimator
(cdpr.mechanics.estimation) against the truth, and whole sessions whose controller never reads ``sim/state``."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from cdpr.config.scenario import load_scenario
from cdpr.errors import InputError
from cdpr.laws.feedback_linearisation import ControllerCore
from cdpr.mechanics.estimation import PoseEstimator
from cdpr.mechanics.forward import ForwardKinematics
from cdpr.mechanics.rotation import matrix_to_rotvec, quat_to_matrix
from cdpr.runtime.feedback import SensorFeedback, noise_of
from cdpr.runtime.registry import node_class
from cdpr_sim.models import make_sim
from cdpr_sim.node import SimNode

ROOT = Path(__file__).resolve().parents[1]
CDPR = [sys.executable, "-m", "cdpr"]


def test_the_estimate_is_closer_to_the_truth_than_forward_kinematics_alone() -> None:
    """2 s of caroca_15kg_sensors driven by the truth-fed controller; the estimator runs beside it on the sensors'
    readings: its position error is a fraction of the FK's (the encoders' noise and quantisation), its twist
    follows the platform's."""
    sc = load_scenario("caroca_15kg_sensors")
    sim, sensors, core = make_sim(sc), SimNode.make_sensors(sc), ControllerCore.from_scenario(sc)
    setpoint_at = node_class("trajectory").make_core(sc)
    noise, imu = noise_of(sc.spec.sim.sensors.model_dump())
    assert imu
    estimator, fk = PoseEstimator(sc.robot, sc.dt, noise, sc.initial_position, sc.initial_rotation), \
        ForwardKinematics(sc.robot)
    est, raw, twist, angle = [], [], [], []
    for k in range(2000):
        truth, reading = sim.message(0), sensors.read(sim)
        e = estimator.update(k, reading.encoders, reading.accel, reading.gyro)
        f = fk.solve(reading.encoders)
        if k >= 200:  # after the filter's start
            est.append(np.linalg.norm(e.position - truth.pose[:3]))
            raw.append(np.linalg.norm(f.position - truth.pose[:3]))
            twist.append(np.linalg.norm(e.twist[:3] - truth.twist[:3]))
            angle.append(np.linalg.norm(matrix_to_rotvec(e.rotation @ quat_to_matrix(truth.pose[3:]).T)))
        sim.step(core.step(truth, setpoint_at(k)).tensions)
    rms = lambda x: float(np.sqrt(np.mean(np.square(x))))  # noqa: E731
    assert rms(est) < 0.5 * rms(raw)
    assert rms(est) < 2e-5  # m
    assert rms(angle) < 1e-4  # rad
    assert rms(twist) < 2e-3  # m/s, while the platform moves at up to ~0.2 m/s


def test_the_filter_takes_the_stretch_out_of_the_encoders_lengths_with_the_load_cells() -> None:
    """Stretching cables (caroca_15kg_sag_sensors: EA = 1 MN) pay out unstretched lengths: the filter, told EA by the
    scenario or by session/info, solves for the lengths the load cells' tensions stretch them to — its estimate is
    much closer to the truth than one that takes the encoders' lengths as they are (what is left: the sag)."""
    from cdpr.protocol.session import SessionInfo, encode_session_info

    sc = load_scenario("caroca_15kg_sag_sensors")
    feedback = SensorFeedback.from_scenario(sc)
    assert feedback.EA == 1.0e6
    assert SensorFeedback.from_info(SessionInfo.from_payload(encode_session_info(sc))).EA == 1.0e6
    assert SensorFeedback.from_scenario(load_scenario("caroca_15kg_sensors")).EA is None  # ideal cables
    sim, sensors, core = make_sim(sc), SimNode.make_sensors(sc), ControllerCore.from_scenario(sc)
    setpoint_at = node_class("trajectory").make_core(sc)
    noise, _ = noise_of(sc.spec.sim.sensors.model_dump())
    rigid = PoseEstimator(sc.robot, sc.dt, noise, sc.initial_position, sc.initial_rotation)
    corrected, plain = [], []
    for k in range(600):
        truth, reading = sim.message(0), sensors.read(sim)
        assert reading.load_cells is not None
        state = feedback.state(reading)
        assert state is not None
        e = rigid.update(k, reading.encoders, reading.accel, reading.gyro)
        if k >= 100:
            corrected.append(np.linalg.norm(np.asarray(state.pose[:3]) - truth.pose[:3]))
            plain.append(np.linalg.norm(e.position - truth.pose[:3]))
        sim.step(core.step(truth, setpoint_at(k)).tensions)
    rms = lambda x: float(np.sqrt(np.mean(np.square(x))))  # noqa: E731
    assert rms(plain) > 1e-4  # the stretch: ~0.1 mm and more
    assert rms(corrected) < 0.25 * rms(plain)  # measured: 0.27 mm and 17 µm


def test_feedback_from_sensors_needs_encoders_and_a_law_of_states(tmp_path: Path) -> None:
    spec = yaml.safe_load((ROOT / "shared/cdpr/scenarios/caroca_15kg_sensors.yaml").read_text(encoding="utf-8"))
    del spec["sim"]["sensors"]["encoders"]
    spec["sim"]["sensors"]["encoders"] = None
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(spec), encoding="utf-8")
    with pytest.raises(InputError, match=r"controller\.feedback: sensors needs sim\.sensors\.encoders"):
        load_scenario(path)
    spec = yaml.safe_load((ROOT / "shared/cdpr/scenarios/caroca_15kg_ibvs.yaml").read_text(encoding="utf-8"))
    spec["controller"]["feedback"] = "sensors"
    spec["sim"]["sensors"] = {"encoders": {"sigma": 1e-5}}
    path.write_text(yaml.safe_dump(spec), encoding="utf-8")
    with pytest.raises(InputError, match=r"controller\.feedback: sensors .*law ibvs"):
        load_scenario(path)
    # stretching cables: the filter takes their stretch out with the load cells, read every step as the encoders are
    spec = yaml.safe_load((ROOT / "shared/cdpr/scenarios/caroca_15kg_sag_sensors.yaml").read_text(encoding="utf-8"))
    spec["sim"]["sensors"]["load_cells"]["dropout"] = 0.1
    path.write_text(yaml.safe_dump(spec), encoding="utf-8")
    with pytest.raises(InputError, match=r"sim\.sensors\.load_cells every step .* dropout must stay 0"):
        load_scenario(path)


def test_a_resent_reading_gets_the_state_it_got_before() -> None:
    sc = load_scenario("caroca_15kg_sensors")
    sim, sensors, feedback = make_sim(sc), SimNode.make_sensors(sc), SensorFeedback.from_scenario(sc)
    first = feedback.state(sensors.read(sim))
    sim.step(np.full(sc.robot.m, 60.0))
    second = feedback.state(sensors.read(sim))
    assert first is not None
    assert second is not None
    assert feedback.state(sensors.read(sim)) is second
    assert second.step == 1
    assert second.cable_lengths == sensors.read(sim).encoders


def _run(scenario: str | Path, *args: str) -> tuple[dict, str]:
    run = subprocess.run([*CDPR, "run", str(scenario), "--quiet", *args], capture_output=True, text=True,
                         timeout=900, check=False)
    assert run.returncode == 0, run.stderr[-3000:]
    return json.loads(run.stdout.strip().splitlines()[-1]), run.stderr


@pytest.mark.slow
def test_caroca_15kg_from_its_sensors_tracks_within_the_bounds(tmp_path: Path) -> None:
    """The whole caroca_15kg with its controller fed by the encoders and the IMU: RMS tracking error (the truth's)
    ≤ 1 mm and ≤ 3 × the truth-fed session's; the distributed loop and the in-process one give the same digest; the
    controller received no sim/state message (its own count). Its estimate of every state goes with its command into
    the recording (estimate/* beside actual/*, and the estimate's errors) and the summary; a truth-fed session has
    none."""
    spec = yaml.safe_load((ROOT / "shared/cdpr/scenarios/caroca_15kg_sensors.yaml").read_text(encoding="utf-8"))
    spec["controller"]["feedback"] = "state"
    spec["name"] = "caroca_15kg_sensors_truth"
    truth_fed = tmp_path / "truth.yaml"
    truth_fed.write_text(yaml.safe_dump(spec), encoding="utf-8")
    truth, _ = _run(truth_fed, "--in-process")
    local, local_log = _run("caroca_15kg_sensors", "--in-process")
    rrd = tmp_path / "sensors.rrd"
    distributed, log = _run("caroca_15kg_sensors", "--rrd", str(rrd))
    for s in (truth, local, distributed):
        assert s["exit_ok"], s
        assert s["steps"] == s["total_steps"] == 11000
    _check_the_recorded_estimate(rrd, distributed)
    assert "rms_estimate_position_error" not in truth  # it read the truth: no estimate
    assert local["rms_estimate_position_error"] == distributed["rms_estimate_position_error"]
    assert local["state_digest"] == distributed["state_digest"]
    assert local["rms_position_error"] <= 1e-3
    assert local["rms_position_error"] <= 3 * truth["rms_position_error"]
    for text in (local_log, log):
        received = re.search(r"\[controller\] .*received: (.*)$", text, re.MULTILINE)
        assert received, text[-3000:]
        counts = dict((name, int(n)) for n, name in re.findall(r"(\d+) (\w+)", received.group(1)))
        assert "state" not in counts, received.group(0)
        assert counts["sensors"] >= 11000, received.group(0)


def _check_the_recorded_estimate(rrd: Path, summary: dict) -> None:
    """The estimate of every state the controller answered is in the recording, its errors are those of the estimate
    against the recorded state, and the summary's figures are those of the recording (cdpr report's too)."""
    from cdpr.mechanics.estimation import estimate_errors
    from cdpr.tools.report import read_recording, summarize

    data = read_recording(rrd)
    position, quaternion = data.get("estimate/position"), data.get("estimate/quaternion")
    assert position.step.tolist() == list(range(11000))  # one per command: states 0 … 10999
    actual = np.hstack([data.get("actual/position").at(position.step), data.get("actual/quaternion").at(position.step)])
    estimated = np.hstack([position.values, quaternion.at(position.step)])
    dp, dr = estimate_errors(estimated, actual)
    assert np.array_equal(data.get("estimate/error/position").values[:, 0], dp)
    assert np.array_equal(data.get("estimate/error/orientation").values[:, 0], dr)
    assert data.get("estimate/twist").values.shape == (11000, 6)
    assert 0.0 < summary["rms_estimate_position_error"] <= 1e-4  # the encoders' noise, filtered (~7 µm)
    assert summary["rms_estimate_position_error"] == pytest.approx(float(np.sqrt(np.mean(dp * dp))), rel=1e-12)
    assert 0.0 < summary["rms_estimate_orientation_error"] <= 1e-3
    converted = rrd.with_suffix(".mcap")  # cdpr convert writes the estimate's channel as the live recorder does
    subprocess.run([*CDPR, "convert", str(rrd), "--to", "mcap", "-o", str(converted)], check=True, timeout=300,
                   capture_output=True)
    from mcap.reader import make_reader

    with converted.open("rb") as f:
        rows = [json.loads(m.data) for _, _, m in make_reader(f).iter_messages(topics=["/platform/estimate"])]
    assert [r["step"] for r in rows] == list(range(11000))
    assert rows[-1]["position_error"] == pytest.approx(float(dp[-1]), rel=1e-12)
    report = summarize(data)
    for key in ("rms_estimate_position_error", "max_estimate_position_error", "rms_estimate_orientation_error",
                "max_estimate_orientation_error"):
        assert report[key] == pytest.approx(summary[key], rel=1e-12), key


@pytest.mark.slow
def test_the_remote_example_from_its_sensors_tracks_within_the_bounds(tmp_path: Path) -> None:
    """examples/remote_controller.py (the SDK) with ``--feedback sensors`` drives caroca_15kg_sensors' plant to the
    end, never subscribing to sim/state: RMS ≤ 1 mm and ≤ 3 × the same example fed the truth."""
    from conftest import free_port, last_json_line
    from test_compose import Processes

    results = {}
    for feedback in ("state", "sensors"):
        port, procs, session = free_port(), Processes(), f"fb{feedback}"
        try:
            up = [*CDPR, "up", "caroca_15kg_sensors", "--session", session, "--without", "controller", "--listen",
                  f"tcp/127.0.0.1:{port}", "--quiet"]
            procs.start("up", up, tmp_path, tmp_path / f"up_{feedback}.log")
            procs.start("remote", [sys.executable, str(ROOT / "examples" / "remote_controller.py"), "--connect",
                                   f"tcp/127.0.0.1:{port}", "--session", session, "--feedback", feedback],
                        tmp_path, tmp_path / f"remote_{feedback}.log")
            codes = procs.wait(["up", "remote"], timeout=600)
            assert codes == {"up": 0, "remote": 0}, procs.report()
            results[feedback] = last_json_line(procs.log("up"))
        finally:
            procs.close()
    for s in results.values():
        assert s["exit_ok"] is True
        assert s["steps"] == 11000
    assert results["sensors"]["rms_position_error"] <= 1e-3
    assert 0.0 < results["sensors"]["rms_estimate_position_error"] <= 1e-4  # the SDK sends its estimate too
    assert "rms_estimate_position_error" not in results["state"]
    assert results["sensors"]["rms_position_error"] <= 3 * results["state"]["rms_position_error"]
