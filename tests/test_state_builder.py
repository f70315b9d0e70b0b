"""One builder of the ``sim/state`` message for every cable model (``cdpr_sim.core.build``).

``State`` gives its later columns defaults (older senders stay valid on the wire), so a model building the message
by hand could leave a new column at its default unnoticed. Here every cable model the scenarios can choose
(``sim.cable_model``: each row of CABLE_MODELS, in both command modes where it has winches) runs a few steps of
the project's own controller on robots of every kind (spatial, with exit pulleys, planar in x–z and in x–y), and
every column of :data:`cdpr.protocol.streams.STATE_COLUMNS` of each message is checked: its type and width,
finite, and equal to what the model computed (its ``state()``); a column these tests do not know yet must at
least be given by the model (the builder refuses a message without it) and not sit at its default all along.
"""

from __future__ import annotations

import inspect
import math
from typing import Any

import pytest

from cdpr.config.scenario import CABLE_MODELS, WINCH_MODELS, load_scenario
from cdpr.laws.feedback_linearisation import ControllerCore
from cdpr.protocol import State
from cdpr.protocol.streams import STATE_COLUMNS, Column
from cdpr_sim import core
from cdpr_sim.core import MODEL_COLUMNS, STAMPED_COLUMNS, build, state_message
from cdpr_sim.models import SIM_MODELS, make_sim
from cdpr_trajectory.core import setpoint_at

STEPS = 6
# Robots of every kind, each in a shipped scenario: spatial, over exit pulleys, planar in x-z and in x-y.
SCENARIOS = ("caroca_15kg", "caroca_15kg_pulleys", "kntu_planar", "planar_xy_4")
CASES = [(scenario, model, output) for scenario in SCENARIOS for model in CABLE_MODELS
         for output in (("tensions", "lengths") if model in WINCH_MODELS else ("tensions",))]
# The columns checked against the model's own state below; any other column gets the generic checks.
KNOWN = ("pose", "twist", "cable_lengths", "tensions", "clamped", *STAMPED_COLUMNS)


def _run(scenario_name: str, model: str, output: str) -> tuple[Any, list[tuple[State, Any, int]]]:
    """The model's messages of steps 0 … STEPS under the controller, each with the model's state and the
    ``clamped`` it was given (a different number each step)."""
    overrides: dict[str, Any] = {"duration": 0.05, "sim": {"cable_model": model}}
    if output == "lengths":
        overrides["controller"] = {"output": "lengths"}
    scenario = load_scenario(scenario_name, overrides)
    assert scenario.cable_model == model
    assert scenario.output == output
    sim = make_sim(scenario)
    controller = ControllerCore.from_scenario(scenario)
    out = []
    for k in range(STEPS + 1):
        clamped = 3 + 2 * k
        msg = sim.message(clamped)
        out.append((msg, sim.state(), clamped))
        if k < STEPS:
            result, lengths = controller.command(msg, setpoint_at(scenario.trajectory, k, scenario.dt))
            sim.step(result.tensions if lengths is None else lengths)
    return sim, out


def test_every_cable_model_is_covered() -> None:
    assert set(SIM_MODELS) == set(CABLE_MODELS)
    assert {model for _, model, _ in CASES} == set(CABLE_MODELS)
    assert {(model, output) for _, model, output in CASES if output == "lengths"} == {(m, "lengths")
                                                                                     for m in WINCH_MODELS}


@pytest.mark.parametrize(("scenario_name", "model", "output"), CASES)
def test_every_column_of_every_model_is_computed(scenario_name: str, model: str, output: str) -> None:
    sim, run = _run(scenario_name, model, output)
    m, dt = sim.robot.m, sim.dt
    assert {c.name for c in STATE_COLUMNS} == {*MODEL_COLUMNS, *STAMPED_COLUMNS}
    for k, (msg, s, clamped) in enumerate(run):
        assert type(msg) is State
        assert msg.step == k
        assert msg.t == k * dt
        for c in STATE_COLUMNS:
            value = getattr(msg, c.name)
            if c.integer:
                assert type(value) is int, (c.name, value)
                assert value >= 0, (c.name, value)
            elif c.width == 1:  # one number
                assert type(value) is float, (c.name, value)
                assert math.isfinite(value), (c.name, value)
            else:
                assert type(value) is tuple, (c.name, value)
                assert len(value) == c.size(m), (c.name, value)
                assert all(type(x) is float and math.isfinite(x) for x in value), (c.name, value)
        # what the model computed, to the last bit
        assert msg.pose == (*s.position.tolist(), *s.quaternion.tolist())
        assert msg.twist == tuple(s.twist.tolist())
        assert msg.cable_lengths == tuple(s.cable_lengths.tolist())
        assert msg.tensions == tuple(s.tensions.tolist())
        assert msg.clamped == clamped
        for name in STAMPED_COLUMNS:  # the sim node's to stamp (the command that acted): 0 from a model
            assert getattr(msg, name) == 0
        assert msg == state_message(s, clamped)
        assert State.decode(msg.encode(), m) == msg
    # the platform moved and the cables pulled: nothing sits at a placeholder all along
    assert run[-1][0].pose != run[0][0].pose
    assert any(x != 0.0 for x in run[-1][0].twist)
    assert all(t > 0.0 for t in run[-1][0].tensions)
    assert run[-1][0].cable_lengths != run[0][0].cable_lengths
    for c in STATE_COLUMNS:
        if c.name not in KNOWN:  # a column added since: given by every model, and not its default all along
            values = [getattr(msg, c.name) for msg, _, _ in run]
            assert any(v != c.default for v in values), f"{model}: the column {c.name} is its default at every step"


def _sample(c: Column, m: int = 2) -> Any:
    """A value of column ``c`` for a robot of ``m`` cables."""
    return 3 if c.integer else 0.5 if c.width == 1 else tuple(0.25 * (i + 1) for i in range(c.size(m)))


def test_the_builder_takes_every_column_or_none() -> None:
    step, t = 4, 0.004
    values = {c.name: _sample(c) for c in STATE_COLUMNS if c.name in MODEL_COLUMNS}
    assert tuple(values) == MODEL_COLUMNS
    expected = State(step, t, **values, **dict.fromkeys(STAMPED_COLUMNS, 0))
    arguments = [name for name in inspect.signature(build).parameters if name not in ("step", "t", "more")]
    assert arguments == list(MODEL_COLUMNS[:len(arguments)])  # its arguments first, any column added since by name
    assert build(step, t, *(values[name] for name in arguments),
                 **{name: values[name] for name in MODEL_COLUMNS[len(arguments):]}) == expected
    assert build(step, t, **values) == expected
    assert build(step, t, *list(values.values())[:2], **dict(list(values.items())[2:])) == expected
    for name in MODEL_COLUMNS:  # each one required
        with pytest.raises(TypeError, match=f"{name}"):
            build(step, t, **{k: v for k, v in values.items() if k != name})
    with pytest.raises(TypeError, match="multiple values"):
        build(step, t, values["pose"], **values)
    for name in (*STAMPED_COLUMNS, "test_only"):  # the node's to stamp, or no column at all
        with pytest.raises(TypeError, match=f"not a state column a model gives: {name}"):
            build(step, t, **values, **{name: 1})


def test_a_column_the_models_do_not_give_fails_every_model(monkeypatch: pytest.MonkeyPatch) -> None:
    """A state column added to the table that the models do not give yet (as tests/test_streams.py adds one to
    the ideal model's message only): each model's message fails, naming it, instead of carrying its default."""
    monkeypatch.setattr(core, "MODEL_COLUMNS", (*MODEL_COLUMNS, "test_only"))
    monkeypatch.setattr(core, "_PLAIN", False)
    monkeypatch.setattr(core, "State", lambda step, t, **columns: (step, t, columns))  # State has no such field
    given = build(0, 0.0, **{c.name: _sample(c) for c in STATE_COLUMNS if c.name in MODEL_COLUMNS}, test_only=1.5)
    assert given[2]["test_only"] == 1.5
    assert given[2][STAMPED_COLUMNS[0]] == 0
    for model in CABLE_MODELS:
        sim = make_sim(load_scenario("caroca_15kg", {"duration": 0.01, "sim": {"cable_model": model}}))
        with pytest.raises(TypeError, match=r"no value for the state column.* test_only"):
            sim.message(0)
