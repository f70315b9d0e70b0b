"""Control laws are declared once (cdpr.laws.LAWS): the scenario's ``controller.law`` and its sections, the
controller node and the learning environment's base law follow the table.

The cost of a new law is shown on a copy of the tree: a Cartesian PD with gravity compensation, ``pd``, is its
module and a row of the table; a scenario then names it, with its own section, and a whole session runs it."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from cdpr.config.scenario import ControllerSpec, load_scenario
from cdpr.errors import InputError
from cdpr.laws import LAWS
from cdpr.laws.feedback_linearisation import ControllerCore
from cdpr.laws.ibvs import IbvsCore
from cdpr_controller.node import ControllerNode
from conftest import changed_sources, source_copy

ROOT = Path(__file__).resolve().parents[1]


def test_every_law_of_the_table_is_a_scenario_choice_with_its_section() -> None:
    assert list(LAWS) == ["feedback_linearisation", "ibvs"]
    fields = ControllerSpec.model_fields
    for law in LAWS.values():
        assert law.name in fields["law"].description  # documented (docs/scenarios.md is generated from it)
        assert (law.name in fields) == (law.section is not None)
    assert isinstance(ControllerNode.make_core(load_scenario("caroca_15kg")), ControllerCore)
    assert isinstance(ControllerNode.make_core(load_scenario("caroca_15kg_ibvs")), IbvsCore)


def test_an_unknown_law_is_one_line_naming_the_known_ones(tmp_path: Path) -> None:
    spec = yaml.safe_load((ROOT / "shared/cdpr/scenarios/caroca_15kg.yaml").read_text(encoding="utf-8"))
    spec["controller"]["law"] = "mpc"
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(spec), encoding="utf-8")
    with pytest.raises(InputError, match=r"controller\.law: .*unknown control law 'mpc' \(known: "
                                         r"feedback_linearisation, ibvs\)") as err:
        load_scenario(path)
    assert "\n" not in str(err.value)


PD = '''"""A Cartesian PD law with gravity compensation (tests/test_laws.py's new law)."""

from __future__ import annotations

from typing import Any

import numpy as np
from pydantic import Field

from cdpr.laws.base import Law, LawSpec
from cdpr.mechanics.dynamics import required_wrench
from cdpr.mechanics.kinematics import WrenchMatrix
from cdpr.mechanics.rotation import orientation_error, quat_to_matrix
from cdpr.mechanics.tda import make_tda


class PdSpec(LawSpec):
    kp: float = Field(400.0, gt=0.0, description="1/s²")
    kd: float = Field(40.0, gt=0.0, description="1/s")


class PdCore:
    def __init__(self, scenario: Any) -> None:
        self.robot, self.gains = scenario.robot, scenario.spec.controller.section("pd")
        self.tda = make_tda(scenario.tda_method, **scenario.tda_options)
        self.W = WrenchMatrix(self.robot)

    def command(self, state: Any, setpoint: Any, residual: Any = None) -> Any:
        R, Rd = quat_to_matrix(state.pose[3:]), quat_to_matrix(setpoint.pose[3:])
        twist = np.asarray(state.twist)
        error = np.concatenate([np.subtract(setpoint.pose[:3], state.pose[:3]), orientation_error(Rd, R)])
        wrench = required_wrench(self.robot, R, twist, self.gains.kp * error - self.gains.kd * twist)
        return self.tda.solve(self.W(np.asarray(state.pose[:3]), R), wrench, self.robot.tmin, self.robot.tmax), None

    def reset(self) -> None:
        self.tda.reset()


LAW = Law(name="pd", doc="a Cartesian PD with gravity compensation", build=PdCore, section=PdSpec)
'''


@pytest.mark.slow
def test_a_new_law_is_its_module_and_a_row(tmp_path: Path) -> None:
    tree, env = source_copy(tmp_path)
    laws = tree / "shared/cdpr/laws"
    (laws / "pd.py").write_text(PD, encoding="utf-8")
    table = (laws / "__init__.py").read_text(encoding="utf-8")
    assert table.count("    ibvs.LAW,\n") == 1
    table = table.replace("    ibvs.LAW,\n", "    ibvs.LAW,\n    pd.LAW,\n")
    table = table.replace("import feedback_linearisation, ibvs\n", "import feedback_linearisation, ibvs, pd\n")
    (laws / "__init__.py").write_text(table, encoding="utf-8")
    assert changed_sources(tree) == ["shared/cdpr/laws/__init__.py", "shared/cdpr/laws/pd.py"]  # the row, the module

    spec = yaml.safe_load((ROOT / "shared/cdpr/scenarios/caroca_15kg.yaml").read_text(encoding="utf-8"))
    spec["controller"] = {"law": "pd", "pd": {"kp": 400.0, "kd": 40.0}, "tda": {"method": "qp"}}
    scenario = tmp_path / "pd.yaml"
    scenario.write_text(yaml.safe_dump(spec), encoding="utf-8")
    runs = {}
    for mode in ("--in-process", None):  # the in-process composition and a process per service
        run = subprocess.run([sys.executable, "-m", "cdpr", "run", str(scenario), "--duration", "2.0", "--quiet",
                              *([mode] if mode else [])], cwd=tmp_path, env=env, capture_output=True, text=True,
                             timeout=600, check=False)
        assert run.returncode == 0, run.stderr[-3000:]
        runs[mode] = json.loads(run.stdout.strip().splitlines()[-1])
    for summary in runs.values():
        assert summary["steps"] == summary["total_steps"] == 2000
        # the PD's tracking (it lags the quintic without eq. 6-7's feedforward: ~9 mm), not feedback
        # linearisation's (~3e-5 m): the new law ran
        assert 2e-3 < summary["rms_position_error"] < 2e-2
    assert runs["--in-process"]["state_digest"] == runs[None]["state_digest"]
