"""Calibration (cdpr.mechanics.calibration, cdpr calibrate): the pure math on synthetic readings, then the whole
loop a researcher runs: a plant that differs from the nominal robot, the shipped excitation recorded on it, the
calibration read back from the .rrd, and the controller on the calibrated file against the nominal one."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from cdpr.config.loading import read_yaml, resolve
from cdpr.config.robot import load_robot
from cdpr.mechanics.calibration import Samples, calibrate_geometry, calibrate_mass, rigid_motions
from cdpr.mechanics.robot import GRAVITY
from cdpr.mechanics.rotation import rpy_to_matrix
from conftest import cdpr


def _path(n: int) -> tuple[np.ndarray, np.ndarray]:
    """A continuous excursion over CAROCA's workspace, turned up to ~0.3 rad (the samples of a session)."""
    t = np.linspace(0.0, 1.0, n)
    p = np.stack([1.5 * np.sin(2 * np.pi * t), np.sin(4 * np.pi * t + 0.5), 1.2 + 0.8 * np.sin(6 * np.pi * t)], 1)
    R = np.array([rpy_to_matrix(0.25 * np.sin(6 * np.pi * s), 0.25 * np.sin(10 * np.pi * s + 1),
                                0.3 * np.sin(4 * np.pi * s)) for s in t])
    return p, R


def _synthetic(seed: int, n: int = 3000, sigma: float = 2e-5):
    robot = load_robot("caroca")
    rng = np.random.default_rng(seed)
    A = robot.frame_points + rng.uniform(-0.02, 0.02, (8, 3))
    offsets = rng.uniform(-0.01, 0.01, 8)
    p, R = _path(n)
    v = A[None] - p[:, None] - np.einsum("kxy,iy->kix", R, robot.platform_points)
    E = np.linalg.norm(v, axis=2) + offsets + sigma * rng.normal(size=(n, 8))
    c = np.array([0.6, 0.3, 0.2])
    Y = p + R @ c
    st = 15e-6 + 6e-6 * np.linalg.norm(Y - np.array([-3.5, -2.0, 0.0]), axis=1)
    Y = Y + st[:, None] * rng.normal(size=Y.shape)
    return robot, A, offsets, p, R, Samples(E, sigma, Y, st, c)


@pytest.mark.parametrize("seed", [1, 2])
def test_exit_points_and_offsets_from_encoders_and_a_tracker(seed: int) -> None:
    robot, A, offsets, _, _, samples = _synthetic(seed)
    g = calibrate_geometry(robot, samples)
    assert g.rank == g.unknowns == 32
    assert all(p.identifiable for p in g.parameters)
    assert np.abs(g.frame_points - A).max() < 0.5e-3
    assert np.abs(g.encoder_offsets - offsets).max() < 0.2e-3
    assert 0.8 < g.chi2_dof < 1.2  # the noise as given
    assert g.after.rms()[0] < 3e-5 < 1e-3 < g.before.rms()[0]
    # each error within 4.5 of its standard uncertainties
    truth = np.concatenate([A.ravel(), offsets])
    z = [(p.value - t) / p.sigma for p, t in zip(g.parameters, truth, strict=True)]
    assert np.abs(z).max() < 4.5


def test_self_calibration_names_the_frame_it_cannot_place() -> None:
    robot, A, offsets, _, _, samples = _synthetic(3)
    g = calibrate_geometry(robot, Samples(samples.encoders, samples.encoder_sigma))
    assert (g.rank, g.unknowns) == (26, 32)
    assert g.gauge == "frame"
    named = {p.name for p in g.parameters if not p.identifiable}
    assert named == {f"cables.{i}.frame.{x}" for i in range(8) for x in "xyz"}
    assert np.abs(g.encoder_offsets - offsets).max() < 2e-3
    # the exit points are right up to a rigid motion of the frame: after the best one, within 2 mm
    G = rigid_motions(robot.frame_points)[:24]
    d = (g.frame_points - A).ravel()
    coef, *_ = np.linalg.lstsq(G, d, rcond=None)
    assert np.abs(d - G @ coef).max() < 2e-3


def test_mass_damping_and_load_cell_biases_from_newtons_law() -> None:
    robot, A, _, p, R, _ = _synthetic(4)
    rng = np.random.default_rng(5)
    mass, c, bias = 15.0, 1.0, rng.uniform(-0.3, 0.3, 8)
    v = A[None] - p[:, None] - np.einsum("kxy,iy->kix", R, robot.platform_points)
    u = v / np.linalg.norm(v, axis=2)[..., None]
    accel = rng.normal(0.0, 2.0, (len(p), 3))  # the centre of mass's accelerations, world frame
    rates = rng.normal(0.0, 0.5, (len(p), 8))
    force = mass * (accel - GRAVITY)  # Σ (f_i + c l̇_i) u_i must give it: tensions by least squares
    f = np.array([np.linalg.lstsq(u[k].T, force[k], rcond=None)[0] for k in range(len(p))]) - c * rates
    readings = f + bias + 0.5 * rng.normal(size=f.shape)
    specific = np.einsum("kyx,ky->kx", R, accel - GRAVITY) + 0.02 * rng.normal(size=accel.shape)
    mc = calibrate_mass(robot, A, p, R, readings, specific, rates)
    assert abs(mc.mass - mass) < 0.01 * mass
    values = {q.name: q.value for q in mc.parameters}
    assert abs(values["damping.cable"] - c) < 0.05
    sigmas = np.array([q.sigma for q in mc.parameters if q.name.startswith("load_cells.bias.")])
    assert np.abs((mc.biases - bias) / sigmas).max() < 4.5
    assert sigmas.max() < 0.5


def _plant(tmp: Path, seed: int = 7) -> Path:
    """CAROCA as built: exit points displaced up to 20 mm, encoders up to 10 mm off (seeded)."""
    data = read_yaml(resolve("caroca", "robots", "robot"))
    rng = np.random.default_rng(seed)
    for cable in data["cables"]:
        cable["frame"] = [float(x + d) for x, d in zip(cable["frame"], rng.uniform(-0.02, 0.02, 3), strict=True)]
        cable["encoder_offset"] = float(rng.uniform(-0.01, 0.01))
    path = tmp / "plant_robot.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return path


def _on_plant(scenario: str, robot_file: str) -> str:
    text = resolve(scenario, "scenarios", "scenario").read_text(encoding="utf-8")
    assert "\nrobot: caroca\n" in text
    return text.replace("\nrobot: caroca\n", f"\nrobot: {robot_file}\n")


@pytest.mark.slow
def test_calibrate_a_plant_from_its_recording_and_control_it_better(tmp_path: Path) -> None:
    from cdpr.tools.study.runner import run_point

    plant_file = _plant(tmp_path)
    plant = load_robot(plant_file)
    scenario = tmp_path / "excitation.yaml"
    scenario.write_text(_on_plant("caroca_calibration", plant_file.name), encoding="utf-8")
    rrd = tmp_path / "excitation.rrd"
    run = cdpr("run", str(scenario), "--in-process", "--quiet", "--rrd", str(rrd), timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]

    out = tmp_path / "calibrated.yaml"
    res = cdpr("calibrate", str(rrd), "--robot", "caroca", "-o", str(out), "--json", "--plot",
               str(tmp_path / "residuals.png"), timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    report = json.loads(res.stdout)
    calibrated = load_robot(out)
    assert np.abs(calibrated.frame_points - plant.frame_points).max() < 0.5e-3
    assert np.abs(calibrated.encoder_offsets - plant.encoder_offsets).max() < 0.2e-3
    mass = next(p for p in report["parameters"] if p["name"] == "platform.mass")
    assert mass["identifiable"]
    assert abs(mass["value"] - 15.0) < 0.15
    assert report["encoder_rms_after"] < 0.05 * report["encoder_rms_before"]
    assert (tmp_path / "residuals.png").stat().st_size > 10_000

    selfcal = cdpr("calibrate", str(rrd), "--robot", "caroca", "-o", str(tmp_path / "self.yaml"), "--json",
                   "--without-tracker", timeout=600)
    assert selfcal.returncode == 0, selfcal.stderr[-2000:]
    params = json.loads(selfcal.stdout)["parameters"]
    truth = {f"cables.{i}.frame.{x}": plant.frame_points[i][j] for i in range(8) for j, x in enumerate("xyz")}
    truth |= {f"cables.{i}.encoder_offset": plant.encoder_offsets[i] for i in range(8)}
    identified = [p for p in params if p["name"] in truth and p["identifiable"]]
    assert len(identified) == 8  # the offsets; the frame is named, not placed (a rigid motion)
    assert all(abs(p["value"] - truth[p["name"]]) < 2e-3 for p in identified)
    table = cdpr("calibrate", str(rrd), "--robot", "caroca", "-o", str(tmp_path / "self.yaml"),
                 "--without-tracker", timeout=600).stdout
    assert "not identifiable" in table
    assert "rigid motion" in table

    # the controller fed from the sensors, on the nominal file and on the calibrated one, drives the plant
    rms = {}
    for label, ctl in (("nominal", resolve("caroca", "robots", "robot")), ("calibrated", out)):
        files = {"scenario.yaml": _on_plant("caroca_15kg_sensors", "robot.yaml"),
                 "robot.yaml": plant_file.read_text(encoding="utf-8"),
                 "controller.yaml": _on_plant("caroca_15kg_sensors", "controller_robot.yaml"),
                 "controller_robot.yaml": Path(ctl).read_text(encoding="utf-8")}
        result = run_point({"id": f"calibration-{label}", "files": files, "mode": "multi-process", "split": True,
                            "timeout": 600})
        assert result["status"] == "ok", result.get("error")
        rms[label] = result["summary"]["rms_position_error"]
    assert rms["calibrated"] * 5.0 <= rms["nominal"], rms


def _refused(tmp: Path, recording: Path, robot: str, why: str) -> None:
    res = cdpr("calibrate", str(recording), "--robot", robot, "-o", str(tmp / "x.yaml"))
    assert res.returncode == 2, res.stderr
    assert why in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1, res.stderr


@pytest.mark.parametrize(("scenario", "robot", "why"), [("caroca_15kg", "caroca", "no encoder readings"),
                                                         ("caroca_15kg_sensors", "cogiro", "not of 'cogiro'")])
def test_a_recording_without_encoders_or_of_another_robot_exits_2(tmp_path: Path, scenario: str, robot: str,
                                                                   why: str) -> None:
    rrd = tmp_path / "session.rrd"
    run = cdpr("run", scenario, "--in-process", "--quiet", "--duration", "0.05", "--rrd", str(rrd))
    assert run.returncode == 0, run.stderr[-2000:]
    _refused(tmp_path, rrd, robot, why)


def test_a_file_that_is_no_recording_exits_2(tmp_path: Path) -> None:
    junk = tmp_path / "junk.rrd"
    junk.write_bytes(b"not a recording")
    _refused(tmp_path, junk, "caroca", "junk.rrd")
    _refused(tmp_path, tmp_path / "missing.rrd", "caroca", "no such recording")
