"""``cdpr check SCENARIO``: before a session, what its trajectory meets — the wrench-feasible workspace, the
cables' length limits, cable–cable and cable–platform interference, the scene's obstacles and floor.

The trajectory is sampled every ``every`` steps of the scenario's dt (and the workspace at
:data:`cdpr.mechanics.workspace.SAMPLE_PERIOD`); where a sample violates, the steps since the sample before are
checked one by one, so that the first violation is given to the step. A clearance that dips below the margin and
comes back between two samples is missed (crossings are not: the sides of each pair are compared from sample to
sample); ``every`` 1 checks every step. A violation: a clearance at or below the
margin, a cable that runs into the platform (its clearance is an angle: :mod:`cdpr.mechanics.interference`), a
cable longer than its ``max_length``, a platform corner at or below the floor, no tensions within the
limits for the pose's static or feed-forward wrench.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cdpr.mechanics.interference import Nearest, clearances, pair_sides, spans
from cdpr.mechanics.kinematics import inverse_kinematics
from cdpr.mechanics.rotation import Array

KINDS = ("cable-cable", "cable-platform", "cable-obstacle", "cable-floor", "platform-floor", "length")


@dataclass
class Least:
    """The least clearance of one kind over the trajectory (m; for ``length``, the least slack to max_length)."""

    value: float = math.inf
    step: int = -1
    what: str = ""


@dataclass
class CheckReport:
    scenario: str
    margin: float
    steps: int
    checked: int  # poses checked
    least: dict[str, Least] = field(default_factory=dict)
    violation: tuple[int, str, str] | None = None  # (step, kind, the line)
    dt: float = 0.0

    @property
    def ok(self) -> bool:
        return self.violation is None


def _corners(robot: Any, position: Array, R: Array) -> Array | None:
    if robot.shape.type != "box":
        return None
    half = 0.5 * np.asarray(robot.shape.size, dtype=float)
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
    local = signs * half - np.asarray(robot.com_offset, dtype=float)
    return np.asarray(position) + local @ R.T


Sides = tuple[Array, Array, Array, Array, Array]  # (i, j, side, interior, normal) of the cable pairs (pair_sides)


def _pose_checks(scenario: Any, step: int, margin: float, before: tuple[int, Sides] | None
                 ) -> tuple[list[tuple[str, float, str, bool]], Sides]:
    """Each kind's (kind, clearance, between what, violated) at ``step``, and the cable pairs' sides; ``before``: the
    step checked before it and its pairs' sides (a pair that crossed since is a violation)."""
    robot = scenario.robot
    sample = scenario.trajectory.sample(step * scenario.dt)
    p, R = sample.position, sample.rotation
    floor = scenario.spec.scene.floor
    free_spans = spans(robot, p, R)
    c = clearances(robot, p, R, scenario.obstacles, floor, free_spans)
    out: list[tuple[str, float, str, bool]] = []
    sides = pair_sides(*free_spans)
    i, j, side, interior, normal = sides
    if before is not None and np.array_equal(before[1][0], i) and np.array_equal(before[1][1], j):
        _, _, side0, interior0, normal0 = before[1]
        turned = np.einsum("ni,ni->n", normal0, normal) > 0.0  # not a flip through parallel
        crossed = np.flatnonzero((side0 * side < 0.0) & turned & (interior.astype(bool) | interior0.astype(bool)))
        if len(crossed):
            k = int(crossed[0])
            out.append(("cable-cable", 0.0, f"cables {i[k]} and {j[k]} crossed since step {before[0]}", True))

    def add(kind: str, near: Nearest, what: str) -> None:
        if math.isfinite(near.distance):
            out.append((kind, near.distance, what, near.distance <= margin))

    add("cable-cable", c.cable_cable, f"cables {c.cable_cable.i} and {c.cable_cable.j}")
    if math.isfinite(c.cable_platform.distance):  # an angle: violated when the cable runs into the platform
        out.append(("cable-platform", c.cable_platform.distance, f"cable {c.cable_platform.i} and the platform",
                    c.cable_platform.distance <= 0.0))
    add("cable-obstacle", c.cable_obstacle, f"cable {c.cable_obstacle.i} and obstacle {c.cable_obstacle.other}")
    add("cable-floor", c.floor, f"cable {c.floor.i} and the floor")
    corners = _corners(robot, p, R)
    if floor is not None and corners is not None:
        low = float(corners[:, 2].min()) - floor
        out.append(("platform-floor", low, "the platform and the floor", low <= margin))
    lengths = inverse_kinematics(robot, p, R).lengths
    slack = np.asarray(robot.max_length) - lengths
    worst = int(np.argmin(slack))
    out.append(("length", float(slack[worst]), f"cable {worst} (its max_length {robot.max_length[worst]:g} m)",
                bool(slack[worst] < 0.0)))
    return out, sides


def check_scenario(scenario: Any, margin: float = 0.0, every: int = 10) -> CheckReport:
    """The report of :mod:`this module <cdpr.tools.check>` for a loaded scenario (its checks not run at load)."""
    from cdpr.mechanics.workspace import first_violation

    total = scenario.total_steps
    report = CheckReport(scenario.name, margin, total, 0, {k: Least() for k in KINDS}, dt=scenario.dt)
    first: tuple[int, str, str] | None = None

    def visit(step: int, before: tuple[int, Sides] | None) -> tuple[bool, tuple[int, Sides]]:
        nonlocal first
        report.checked += 1
        violated = False
        checks, sides = _pose_checks(scenario, step, margin, before)
        for kind, value, what, bad in checks:
            least = report.least[kind]
            if value < least.value:
                report.least[kind] = Least(value, step, what)
            if bad and (first is None or step < first[0]):
                first = (step, kind, _line(kind, value, what, margin))
            violated |= bad
        return violated, (step, sides)

    grid = list(range(0, total + 1, max(1, every)))
    if grid[-1] != total:
        grid.append(total)
    previous: tuple[int, Sides] | None = None
    refined = False
    for step in grid:
        bad, here = visit(step, previous)
        if bad and not refined and previous is not None:
            refined = True
            if first is not None and first[0] == step:  # found again, step by step (a crossing: since the step before)
                first = None
            chain = previous
            for inner in range(previous[0] + 1, step + 1):  # the first step it happens at
                inner_bad, chain = visit(inner, chain)
                if inner_bad:
                    break
        previous = here
    v = first_violation(scenario.robot, scenario.trajectory, scenario.variant)
    if v is not None:
        step = round(v.t / scenario.dt)
        what = "hold the platform there" if v.kind == "static" else "produce the desired acceleration's wrench"
        line = (f"no tensions in {scenario.robot.tension_limits_text()} {what} (position "
                f"[{', '.join(f'{x:.3f}' for x in v.position)}]): it leaves the wrench-feasible workspace")
        if first is None or step < first[0]:
            first = (step, "workspace", line)
    report.violation = first
    return report


def _line(kind: str, value: float, what: str, margin: float) -> str:
    if kind == "cable-platform":
        return f"{what}: the cable runs into the platform ({math.degrees(value):.2f} deg into it)"
    if kind == "length":
        return f"{what} is {-value * 1e3:.1f} mm too long"
    if kind.endswith("-floor") and value <= 0.0:
        return f"{what.removesuffix(' and the floor')} reaches {-value * 1e3:.1f} mm below the floor"
    if "crossed" in what:
        return what + " (they passed through each other)"
    return f"{what} are {value * 1e3:.2f} mm apart (margin {margin * 1e3:g} mm)"


def table(report: CheckReport) -> str:
    lines = [f"{report.scenario}: {report.checked} poses of {report.steps + 1} steps checked (margin "
             f"{report.margin * 1e3:g} mm)", "", "| check | least clearance | at | between |", "|---|---:|---:|---|"]
    for kind, least in report.least.items():
        if least.step < 0:
            continue
        value = (f"{math.degrees(least.value):.2f} deg" if kind == "cable-platform"
                 else f"{least.value * 1e3:.2f} mm" + (" slack" if kind == "length" else ""))
        lines.append(f"| {kind} | {value} | t = {least.step * report.dt:.3f} s (step {least.step}) | {least.what} |")
    if report.violation is None:
        lines.append("\nno violation")
    else:
        step, kind, line = report.violation
        lines.append(f"\nfirst violation ({kind}) at t = {step * report.dt:.3f} s (step {step}): {line}")
    return "\n".join(lines)


def summary(report: CheckReport) -> dict[str, Any]:
    v = report.violation
    return {"scenario": report.scenario, "margin": report.margin, "steps": report.steps, "checked": report.checked,
            "ok": report.ok,
            "least": {k: {"clearance": x.value, "step": x.step, "t": x.step * report.dt, "between": x.what}
                      for k, x in report.least.items() if x.step >= 0},
            "violation": None if v is None else {"step": v[0], "t": v[0] * report.dt, "kind": v[1], "line": v[2]}}
