"""Study files: a base scenario, the parameters to vary and the metrics to keep (YAML + pydantic).

A study file is validated like a scenario: a bad file raises :class:`cdpr.errors.InputError` with one
line ``file: field: message`` naming the field. Example::

    name: caroca_15kg_mass
    scenario: caroca_15kg            # a shipped name, or a path relative to this file
    set: {duration: 4.0}             # dotted paths set on every point
    samples: 200                     # random draws (Monte Carlo); grids multiply them
    seed: 1
    parameters:
      - {path: platform.mass, op: scale, uniform: [0.8, 1.2]}
      - {path: robot.cables.*.frame, op: add, uniform: [-0.005, 0.005], plant_only: true}
      - {path: controller.tda.method, values: [qp, closed_form]}
    metrics: [rms_position_error, infeasible_commands]

``path`` is a dotted path into the scenario file (``controller.kp``, ``limits.tmax``,
``sim.sensors.encoders.sigma``; missing mappings are created) or, with the prefix ``robot.``, into its
robot file (``robot.cables.3.platform``); a number indexes a list and ``*`` takes every element.
"""

from __future__ import annotations

import itertools
import re
from pathlib import Path
from typing import Any, Literal

from pydantic import Field, FiniteFloat, PositiveFloat, PositiveInt, model_validator

from cdpr.config.loading import Strict, parse_model, read_yaml
from cdpr.errors import InputError

# Metrics a point can keep: the numeric keys of a session's summary (cdpr.tools.launch, cdpr.tools.metrics) ...
SUMMARY_METRICS = {
    "rms_position_error": "RMS position error, m",
    "max_position_error": "largest position error, m",
    "final_position_error": "position error at the last step, m",
    "rms_orientation_error": "RMS orientation error, rad",
    "max_orientation_error": "largest orientation error, rad",
    "tension_min": "lowest applied tension, N",
    "tension_max": "highest applied tension, N",
    "max_tension_change": "largest step-to-step tension change (spikes), N",
    "infeasible_commands": "steps whose tension distribution was infeasible",
    "clamped_commands": "commands the sim clamped to the limits",
    "rtf": "real-time factor of the session's loop",
    "rate": "steps per second of the session's loop",
    "steps": "steps run",
    "sim_time": "simulated time, s",
    "wall_time": "wall time of the session's loop, s",
    "resends": "ticks the clock resent",
    "command_age_p50": "median command age, steps (free-running realtime, a command latency)",
    "command_age_p99": "99th percentile of the command age, steps",
    "command_age_max": "largest command age, steps",
    "watchdog_steps": "steps on which the sim's watchdog policy acted",
    "on_time_fraction": "realtime: the share of ticks (free-running: steps) within dt of their deadline",
    # a controller fed from the sensors (controller.feedback: sensors): its estimate of each state against the state
    "rms_estimate_position_error": "RMS position error of the controller's estimate, m",
    "max_estimate_position_error": "largest position error of the controller's estimate, m",
    "rms_estimate_orientation_error": "RMS orientation error of the controller's estimate, rad",
    "max_estimate_orientation_error": "largest orientation error of the controller's estimate, rad",
}
# ... and these, derived from the summary and the point's scenario
DERIVED_METRICS = {
    "tension_range": "tension_max - tension_min, N",
    "tensions_within_limits": "1 if every applied tension was within the point's [tmin, tmax], else 0",
}
METRICS = {**SUMMARY_METRICS, **DERIVED_METRICS}
DEFAULT_METRICS = ["rms_position_error", "max_position_error", "final_position_error", "tension_min",
                   "tension_max", "tensions_within_limits", "infeasible_commands", "max_tension_change", "rtf"]
LAWS = ("values", "uniform", "normal", "loguniform", "choice")
PATH_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(\.([A-Za-z_][A-Za-z0-9_]*|\d+|\*))*$")
NAME_RE = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}$")


def _known_metric(name: str) -> str:
    if name not in METRICS:
        raise ValueError(f"unknown metric {name!r} (known: {', '.join(METRICS)})")
    return name


class ParameterSpec(Strict):
    """One varied quantity: where (``path``), how (``op``) and which values (one law)."""

    path: str = Field(description="dotted path into the scenario, or robot.<path> into its robot file")
    name: str | None = Field(None, description="the table's column (default: the path)")
    op: Literal["set", "add", "scale"] = Field(
        "set", description="set: the value replaces the base one; add: it is added to every number there; "
        "scale: every number there is multiplied by it")
    values: list[Any] | None = Field(None, min_length=1, description="a grid: every value, one point each")
    uniform: list[FiniteFloat] | None = Field(None, min_length=2, max_length=2, description="random: [low, high]")
    normal: list[FiniteFloat] | None = Field(None, min_length=2, max_length=2, description="random: [mean, sigma]")
    loguniform: list[PositiveFloat] | None = Field(None, min_length=2, max_length=2,
                                                   description="random: [low, high], uniform in log")
    choice: list[Any] | None = Field(None, min_length=1, description="random: one of these, equally likely")
    integer: bool = Field(False, description="round every drawn number to an integer")
    plant_only: bool = Field(
        False, description="only the plant (sim) gets the value; the controller keeps the base scenario's "
        "(a model error it does not know about; runs the controller as a separate process)")

    @model_validator(mode="after")
    def _one_law(self) -> ParameterSpec:
        if not PATH_RE.match(self.path):
            raise ValueError(f"path: {self.path!r} is not a dotted path (names, list indices, *)")
        given = [law for law in LAWS if getattr(self, law) is not None]
        if len(given) != 1:
            raise ValueError(f"give exactly one of {', '.join(LAWS)} (got {', '.join(given) or 'none'})")
        if self.uniform is not None and not self.uniform[0] < self.uniform[1]:
            raise ValueError(f"uniform: low must be below high (got {self.uniform})")
        if self.loguniform is not None and not self.loguniform[0] < self.loguniform[1]:
            raise ValueError(f"loguniform: low must be below high (got {self.loguniform})")
        if self.normal is not None and self.normal[1] < 0:
            raise ValueError(f"normal: sigma must be >= 0 (got {self.normal[1]})")
        numbers = self.values if self.values is not None else self.choice
        if self.op != "set" and numbers is not None and not all(
                isinstance(v, int | float) and not isinstance(v, bool) for v in numbers):
            raise ValueError(f"op {self.op}: needs numbers")
        if self.name is not None and not NAME_RE.match(self.name):
            raise ValueError(f"name: {self.name!r} must be 1-64 characters of A-Z a-z 0-9 _ . -")
        return self

    @property
    def column(self) -> str:
        return self.name or self.path

    @property
    def law(self) -> str:
        return next(law for law in LAWS if getattr(self, law) is not None)

    @property
    def is_grid(self) -> bool:
        return self.values is not None

    @property
    def discrete(self) -> list[Any] | None:
        """The values a grid or a choice law takes; None for a continuous law."""
        return self.values if self.values is not None else self.choice

    @property
    def on_robot(self) -> bool:
        return self.path.startswith("robot.")


class ConstraintSpec(Strict):
    metric: str
    max: FiniteFloat | None = None
    min: FiniteFloat | None = None

    @model_validator(mode="after")
    def _bounded(self) -> ConstraintSpec:
        _known_metric(self.metric)
        if self.max is None and self.min is None:
            raise ValueError("give max, min or both")
        return self


class TuneSpec(Strict):
    """``cdpr tune``: Optuna (TPE) through Ray Tune searches the parameters' laws for the best metric."""

    metric: str = "rms_position_error"
    goal: Literal["min", "max"] = "min"
    trials: PositiveInt = 32
    concurrent: PositiveInt | None = Field(None, description="trials at once (default: the cluster's CPUs)")
    constraints: list[ConstraintSpec] = Field(
        default_factory=lambda: [ConstraintSpec(metric="infeasible_commands", max=0),
                                 ConstraintSpec(metric="tensions_within_limits", min=1)],
        description="a trial that breaks one is infeasible: never the best")
    fidelities: list[float] = Field(
        default_factory=lambda: [0.3, 1.0],
        description="fractions of the duration a trial runs, in turn; after each, the ASHA scheduler stops "
        "trials worse than most at the same fraction, and a broken constraint stops the trial")

    @model_validator(mode="after")
    def _check(self) -> TuneSpec:
        _known_metric(self.metric)
        f = self.fidelities
        if not f or any(not 0 < x <= 1 for x in f) or any(b <= a for a, b in itertools.pairwise(f)) \
                or f[-1] != 1.0:
            raise ValueError(f"fidelities: increasing fractions in (0, 1] ending with 1.0 (got {f})")
        return self


class StudySpec(Strict):
    name: str
    description: str = ""
    scenario: str = Field(description="the base scenario: a shipped name or a path (relative to the study file)")
    set: dict[str, Any] = Field(default_factory=dict, description="dotted paths set on every point")
    parameters: list[ParameterSpec] = Field(min_length=1)
    samples: PositiveInt | None = Field(None, description="random draws per grid point (Monte Carlo)")
    seed: int = Field(0, ge=0)
    metrics: list[str] = Field(default_factory=lambda: list(DEFAULT_METRICS))
    mode: Literal["auto", "in-process", "multi-process"] = Field(
        "auto", description="how a point's session runs (auto: in-process where `cdpr run` has it)")
    record: bool = Field(False, description="keep each point's .rrd recording")
    timeout: PositiveFloat = Field(900.0, description="seconds a point may take before it is stopped")
    cpus_per_point: PositiveFloat = Field(1.0, description="Ray CPUs one point reserves")
    tune: TuneSpec | None = None

    @model_validator(mode="after")
    def _check(self) -> StudySpec:
        if not NAME_RE.match(self.name):
            raise ValueError(f"name: {self.name!r} must be 1-64 characters of A-Z a-z 0-9 _ . -")
        for i, m in enumerate(self.metrics):
            try:
                _known_metric(m)
            except ValueError as exc:
                raise ValueError(f"metrics.{i}: {exc}") from None
        columns = [p.column for p in self.parameters]
        for i, c in enumerate(columns):
            if c in columns[:i]:
                raise ValueError(f"parameters.{i}: a second parameter named {c!r} (give it a name)")
            if c in METRICS or c in RESERVED:
                raise ValueError(f"parameters.{i}: name {c!r} is taken by a column of the table")
        for path in self.set:
            if not PATH_RE.match(path):
                raise ValueError(f"set: {path!r} is not a dotted path")
        random = any(not p.is_grid for p in self.parameters)
        if self.tune is None:
            if random and self.samples is None:
                raise ValueError("samples: missing: how many random draws (the parameters have random laws)")
            if not random and self.samples is not None:
                raise ValueError("samples: only for random laws (the sessions are deterministic: a grid point "
                                 "run twice gives the same result)")
        else:
            for i, p in enumerate(self.parameters):
                if p.plant_only:
                    raise ValueError(f"parameters.{i}.plant_only: not for tune (the best point is one scenario)")
        if self.mode == "in-process" and any(p.plant_only for p in self.parameters):
            raise ValueError("mode: in-process runs one scenario for every node; plant_only parameters need "
                             "multi-process (or auto)")
        return self


RESERVED = {"point", "id", "status", "error", "sample", "wall_s", "node", "host", "mode", "state_digest",
            "rrd", "trial", "fidelity", "objective", "feasible"}


def load_study(path: str | Path) -> tuple[StudySpec, Path]:
    """A study file → its validated spec and its path; errors as ``file: field: message``."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such study file")
    spec = parse_model(StudySpec, read_yaml(path), path)
    return spec, path
