"""``cdpr calibrate RECORDING.rrd --robot NOMINAL``: a better robot file from what a session measured.

Reads the recording's sensor readings (``sensors/encoders``; ``sensors/laser_tracker`` when it has one;
``sensors/load_cells`` and ``sensors/imu/accel`` for the mass), each at the step it was measured (its delivery
step minus the scenario's latency), and the noise the scenario gave them (its ``session/info``). Never the
recording's truth (``actual/*``) nor its robot's geometry: the recording names the robot, the geometry comes from
NOMINAL. The math is :mod:`cdpr.mechanics.calibration`; the workflow is docs/calibration.md.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cdpr.errors import InputError
from cdpr.mechanics.calibration import (
    MAX_ITERATIONS,
    GeometryCalibration,
    MassCalibration,
    Parameter,
    Samples,
    calibrate_geometry,
    calibrate_mass,
)
from cdpr.mechanics.robot import Robot
from cdpr.mechanics.rotation import Array

FLOOR_SIGMA = 1e-6  # m: the noise assumed for noise-free encoders (a weight must be finite)


@dataclass(frozen=True)
class Recorded:
    """The readings of one recording, aligned on the steps they were measured at."""

    steps: Array  # (N,) the steps with encoder readings
    encoders: Array  # (N, m)
    encoder_sigma: float
    tracker: Array | None  # (N, 3), NaN where none
    tracker_sigma: Array | None
    reflector: Array | None  # the robot file's platform frame
    load_cells: Array | None  # (N, m), NaN where none
    accel: Array | None  # (N, 3), NaN where none
    robot_name: str
    cables: int
    dt: float
    cable_set: str
    cable_model: str


def _latency(sensors: dict[str, Any], name: str, dt: float) -> int:
    return round(float((sensors.get(name) or {}).get("latency", 0.0)) / dt)


def read_readings(path: str | Path) -> Recorded:
    """A recording's sensor readings (module docstring); InputError naming the file for one that is not a cdpr
    recording or has no encoder readings."""
    from cdpr.sensors import SENSOR_COLUMNS
    from cdpr.tools.report import read_recording, sensor_columns

    if not Path(path).is_file():
        raise InputError(f"{path}: no such recording")
    data = read_recording(path)
    session = data.session
    info: dict[str, Any] = session["info"] if isinstance(session.get("info"), dict) else {}
    robot: dict[str, Any] = info["robot"] if isinstance(info.get("robot"), dict) else {}
    try:
        dt, m = float(session["dt"]), int(session["cables"])
    except (KeyError, TypeError, ValueError):
        raise InputError(f"{path}: the session description lacks dt or cables") from None
    sim: dict[str, Any] = info["sim"] if isinstance(info.get("sim"), dict) else {}
    sensors = sim.get("sensors") or {}
    steps, channels = sensor_columns(data, m, SENSOR_COLUMNS)
    if "encoders" not in channels:
        raise InputError(f"{path}: no encoder readings (sensors/encoders): record a scenario whose sim.sensors has "
                         "encoders")
    if not robot or not isinstance(sensors.get("encoders"), dict):
        raise InputError(f"{path}: the recording's session/info lacks its robot or its encoders' noise (sim.sensors."
                         "encoders): a recording made by cdpr run/up with encoders has them")

    def shifted(name: str, kind: str) -> tuple[Array, Array]:
        values = channels[name]
        rows = np.all(np.isfinite(values), axis=1)
        return np.asarray(steps[rows] - _latency(sensors, kind, dt)), values[rows]

    e_steps, E = shifted("encoders", "encoders")
    spec = sensors.get("encoders") or {}
    sigma = math.hypot(float(spec.get("sigma", 0.0)), float(spec.get("resolution", 0.0)) / math.sqrt(12.0))

    def aligned(name: str, kind: str) -> Array | None:
        if name not in channels:
            return None
        s, v = shifted(name, kind)
        out = np.full((len(e_steps), v.shape[1]), np.nan)
        idx = np.searchsorted(s, e_steps)
        hit = (idx < len(s)) & (s[np.clip(idx, 0, len(s) - 1)] == e_steps)
        out[hit] = v[idx[hit]]
        return out

    tracker = aligned("laser_tracker", "laser_tracker")
    tracker_sigma = reflector = None
    if tracker is not None:
        spec = sensors.get("laser_tracker") or {}
        station = np.asarray(spec.get("station", [0.0, 0.0, 0.0]), dtype=float)
        reflector = np.asarray(spec.get("reflector", [0.0, 0.0, 0.0]), dtype=float)
        distance = np.linalg.norm(np.nan_to_num(tracker) - station, axis=1)
        tracker_sigma = float(spec.get("sigma", 15e-6)) + float(spec.get("sigma_per_m", 6e-6)) * distance
        tracker_sigma = np.maximum(tracker_sigma, FLOOR_SIGMA)
    return Recorded(e_steps, E, max(sigma, FLOOR_SIGMA), tracker, tracker_sigma, reflector,
                    aligned("load_cells", "load_cells"), aligned("accel", "imu"), str(robot.get("name", "")), m, dt,
                    str(robot.get("cable_set", "default")), str(sim.get("cable_model", "ideal")))


@dataclass(frozen=True)
class CalibrationReport:
    geometry: GeometryCalibration
    mass: MassCalibration | None
    robot: Robot  # the calibrated robot
    text: str  # the calibrated robot file
    samples: int
    tracker: bool
    tracker_readings: int = 0
    warnings: tuple[str, ...] = ()


def calibrate(recording: str | Path, nominal: str, *, platform_points: bool = False, tracker: bool = True,
              set_mass: bool = False, max_samples: int = 12_000) -> CalibrationReport:
    """Calibrate NOMINAL (a shipped name or a robot file) from ``recording``; InputError (one line) for a recording
    without encoder readings, of another robot, or that the model does not cover."""
    from cdpr.config.loading import read_yaml, resolve
    from cdpr.config.robot import load_robot

    robot = load_robot(nominal, check_home=False)
    rec = read_readings(recording)
    if not tracker:  # self-calibration from the encoders alone
        rec = dataclasses.replace(rec, tracker=None, tracker_sigma=None, reflector=None)
    if rec.robot_name and rec.robot_name != robot.name:
        raise InputError(f"{recording}: a recording of robot {rec.robot_name!r}, not of {robot.name!r} (--robot)")
    if rec.cables != robot.m:
        raise InputError(f"{recording}: a recording of {rec.cables} cables; {nominal} has {robot.m}")
    if rec.cable_set != robot.cable_set:
        raise InputError(f"{recording}: a recording of cable set {rec.cable_set!r}; {nominal}'s cables are "
                         f"{robot.cable_set!r} (calibrate a robot file whose cables are that set)")
    warnings: list[str] = []
    if rec.cable_model not in ("ideal", "ups"):
        warnings.append(f"the recording's cables are {rec.cable_model}: the rigid-cable model takes their stretch "
                        "(and sag) into the offsets and exit points")
    rows = np.arange(len(rec.steps))
    if len(rows) > max_samples:  # evenly spread over the session
        rows = rows[np.linspace(0, len(rows) - 1, max_samples).round().astype(int)]
    reflector = None if rec.reflector is None else rec.reflector - np.asarray(robot.com_offset)
    samples = Samples(rec.encoders[rows], rec.encoder_sigma,
                      None if rec.tracker is None else rec.tracker[rows],
                      None if rec.tracker_sigma is None else rec.tracker_sigma[rows],
                      np.zeros(3) if reflector is None else reflector)
    geometry = calibrate_geometry(robot, samples, platform_points=platform_points)
    if geometry.iterations >= MAX_ITERATIONS:
        warnings.append(f"Gauss-Newton stopped at its {MAX_ITERATIONS} iterations before its steps were below "
                        "1e-10 m: the figures are the last iterate's")
    if geometry.chi2_dof > 2.0:
        warnings.append(f"the reduced chi2 is {geometry.chi2_dof:.3g}: the readings are noisier than the scenario "
                        "says (or the model misses something); the uncertainties are scaled by its square root")
    mass = None
    if rec.load_cells is not None and rec.accel is not None:
        rates = cable_rates(rec.steps, rec.encoders - geometry.encoder_offsets, dt=rec.dt)
        try:
            mass = calibrate_mass(robot.replace(platform_points=geometry.platform_points), geometry.frame_points,
                                  geometry.positions, geometry.rotations, rec.load_cells[rows], rec.accel[rows],
                                  None if np.isnan(rates[rows]).all() else rates[rows])
        except InputError as exc:
            warnings.append(f"mass not identified: {exc}")
    damping = None if mass is None else _identified(mass, "damping.cable")
    if damping is not None and (damping <= 0.0 or rec.cable_model not in ("ideal", "ups")):
        warnings.append(f"cable damping {damping:.4g} N·s/m not written ("
                        + ("not positive" if damping <= 0.0 else f"{rec.cable_model} cables do not apply it") + ")")
        damping = None
    calibrated = robot.replace(frame_points=geometry.frame_points, encoder_offsets=geometry.encoder_offsets,
                               platform_points=geometry.platform_points)
    if set_mass and mass is not None and mass.parameters[0].identifiable:
        calibrated = calibrated.with_mass(mass.mass)
    if damping is not None:
        calibrated = calibrated.replace(cable_damping=damping)
    data = read_yaml(resolve(nominal, "robots", "robot"))
    text = robot_file(data, robot, geometry, mass, Path(recording).name,
                      calibrated.inertia if set_mass and mass is not None else None, damping)
    readings = 0 if samples.tracker is None else int(np.isfinite(samples.tracker).all(axis=1).sum())
    return CalibrationReport(geometry, mass, calibrated, text, len(rows), rec.tracker is not None, readings,
                             tuple(warnings))


def robot_file(data: dict[str, Any], robot: Robot, geometry: GeometryCalibration, mass: MassCalibration | None,
               origin: str, inertia: Array | None = None, damping: float | None = None) -> str:
    """The nominal robot file's data with the identified values in place (its cables: ``frame``,
    ``encoder_offset``, ``platform`` when identified; ``damping.cable`` given ``damping``; ``platform.mass`` and
    the solid shape's ``inertia`` given ``inertia``: the mass identified is the session's platform's, payload
    included, which scenarios often set themselves), as YAML text."""
    from cdpr.tools.caspr import robot_yaml

    cables = data.get("cables")
    if not isinstance(cables, list) or len(cables) != robot.m:
        raise InputError(f"robot file: expected its {robot.m} cables under 'cables'")
    com = np.asarray(robot.com_offset)
    identified = {p.name for p in geometry.parameters if p.identifiable}
    platform = any(p.name.endswith(".platform.x") for p in geometry.parameters)  # --platform-points
    for i, cable in enumerate(cables):
        cable["frame"] = [round(float(x), 6) for x in geometry.frame_points[i]]
        cable["encoder_offset"] = round(float(geometry.encoder_offsets[i]), 7)
        if platform:
            cable["platform"] = [round(float(x), 6) for x in geometry.platform_points[i] + com]
    set_mass = False
    if inertia is not None and mass is not None and mass.parameters[0].identifiable:
        set_mass = True
        data.setdefault("platform", {})["mass"] = round(mass.mass, 4)
        data["platform"]["inertia"] = [round(float(x), 6) for x in np.diag(inertia)]
    if damping is not None:
        data.setdefault("damping", {})["cable"] = round(damping, 4)
    left = [p.name for p in geometry.parameters if p.name not in identified]
    note = (f" Calibrated by `cdpr calibrate` from {origin}: {len(identified)} of {len(geometry.parameters)} "
            "geometric parameters identified" + (f" (not identifiable from that recording: {_ranges(left)}; "
                                                 "kept at the least change from the nominal file)" if left else "")
            + ("" if mass is None else f"; the session's platform mass {mass.mass:.5g} kg"
               + (" (written here)" if set_mass else ""))
            + ("" if damping is None else "; cable damping"))
    data["source"] = f"{data.get('source', '')}{note}".strip()
    return robot_yaml(data, origin, f"Calibrated from {origin} by `cdpr calibrate`: what it identified is in "
                                    "`source`.")


def _identified(mass: MassCalibration, name: str) -> float | None:
    return next((p.value for p in mass.parameters if p.name == name and p.identifiable), None)


def cable_rates(steps: Array, lengths: Array, dt: float) -> Array:
    """Each cable's length rate (N, m), m/s: central differences over the neighbouring readings (NaN at the ends
    and where the neighbours are more than 20 steps apart: a gap)."""
    rates = np.full(lengths.shape, np.nan)
    if len(steps) >= 3:
        gap = steps[2:] - steps[:-2]
        ok = gap <= 40
        rates[1:-1][ok] = (lengths[2:][ok] - lengths[:-2][ok]) / (gap[ok, None] * dt)
    return rates


def _ranges(names: list[str]) -> str:
    """``cables.0.frame.x … cables.7.frame.z`` for a long list, else the names."""
    return ", ".join(names) if len(names) <= 4 else f"{names[0]} … {names[-1]} ({len(names)} parameters)"


def table(report: CalibrationReport) -> str:
    """The identified parameters, the residuals before and after, the identification's condition, as text."""
    g = report.geometry
    what = (f"encoders, {report.tracker_readings} with a laser tracker reading" if report.tracker
            else "encoders only: self-calibration")
    lines = [f"{report.samples} samples ({what}), {g.iterations} Gauss-Newton iterations",
             f"identification: rank {g.rank} of {g.unknowns} parameters, condition number {g.condition:.3g}, "
             f"reduced chi2 {g.chi2_dof:.3g}"]
    if g.rank < g.unknowns:
        why = {"frame": "a rigid motion of the whole frame changes no cable length (a laser tracker fixes it)",
               "platform": "a rigid motion of the platform frame's points changes no cable length (give the "
                           "platform points, or fewer of them)",
               "frame and platform": "rigid motions of the frame and of the platform frame's points change no "
                                     "cable length"}.get(g.gauge, "the recorded poses do not excite them")
        lines.append(f"not identifiable ({g.unknowns - g.rank} directions: {why}): "
                     + _ranges([p.name for p in g.parameters if not p.identifiable]))
    eb, tb = g.before.rms()
    ea, ta = g.after.rms()
    lines.append(f"encoder residual RMS: {1e3 * eb:.4f} mm (nominal robot) -> {1e3 * ea:.4f} mm (calibrated)")
    if tb is not None and ta is not None:
        lines.append(f"laser tracker residual RMS: {1e3 * tb:.4f} mm -> {1e3 * ta:.4f} mm")
    lines += [f"warning: {w}" for w in report.warnings]
    lines += ["", "| parameter | nominal (--robot file) | identified | change | standard uncertainty | identifiable |",
              "|---|---:|---:|---:|---:|---|"]
    params: list[Parameter] = list(g.parameters) + (list(report.mass.parameters) if report.mass else [])
    for p in params:
        scale, unit = (1e3, "mm") if p.unit == "m" else (1.0, p.unit)
        change = scale * (p.value - p.nominal)
        lines.append(f"| {p.name} | {scale * p.nominal:.3f} | {scale * p.value:.3f} | {change:+.3f} {unit} | "
                     f"{f'{scale * p.sigma:.3f} {unit}' if p.identifiable else '-'} | "
                     f"{'yes' if p.identifiable else '**no**'} |")
    if report.mass is not None:
        lines.append(f"\nforce balance residual RMS {report.mass.residual_rms:.3g} N over {report.mass.samples} "
                     "samples (load cells and IMU)")
    return "\n".join(lines)


def plot(report: CalibrationReport, path: str | Path) -> None:
    """The encoder residuals of every sample, before (the nominal robot) and after, one line per cable."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    g = report.geometry
    fig, axes = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    for ax, fit, label in ((axes[0], g.before, "nominal robot"), (axes[1], g.after, "calibrated")):
        ax.plot(1e3 * fit.encoders, lw=0.6)
        ax.set_ylabel("encoder residual, mm")
        ax.set_title(f"{label}: RMS {1e3 * fit.rms()[0]:.4f} mm")
        ax.grid(alpha=0.3)
    axes[1].set_xlabel("sample")
    fig.tight_layout()
    try:
        fig.savefig(path, dpi=110)
    except OSError as exc:
        raise InputError(f"--plot: cannot write {path}: {exc.strerror or exc}") from None
    finally:
        plt.close(fig)


def summary(report: CalibrationReport) -> dict[str, Any]:
    """The report as JSON-friendly data (``--json``)."""
    g = report.geometry
    params = list(g.parameters) + (list(report.mass.parameters) if report.mass else [])
    return {"samples": report.samples, "tracker": report.tracker, "iterations": g.iterations, "rank": g.rank,
            "unknowns": g.unknowns, "condition": g.condition, "chi2_dof": g.chi2_dof,
            "gauge": g.gauge, "tracker_readings": report.tracker_readings, "warnings": list(report.warnings),
            "encoder_rms_before": g.before.rms()[0], "encoder_rms_after": g.after.rms()[0],
            "tracker_rms_before": g.before.rms()[1], "tracker_rms_after": g.after.rms()[1],
            "parameters": [{"name": p.name, "nominal": p.nominal, "value": p.value,
                            "sigma": p.sigma if p.identifiable else None,
                            "identifiable": p.identifiable, "unit": p.unit} for p in params]}
