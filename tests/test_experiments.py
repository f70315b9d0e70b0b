"""The paper's three experiments through the real loop, held to the accuracy and tension-bound targets."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from cdpr.config.scenario import load_scenario
from cdpr.tools.analysis import tension_change_bound
from cdpr.tools.experiments import meets_targets
from conftest import cdpr, last_json_line

pytestmark = pytest.mark.slow


@pytest.mark.parametrize("scenario",
                         ["caroca_1kg_continuity", "caroca_15kg_continuity", "caroca_15kg_scurve_continuity"])
def test_paper_experiment_meets_the_targets(scenario: str, session_id: str) -> None:
    proc = cdpr("run", scenario, "--session", session_id, "--quiet", timeout=600, check=True)
    s = last_json_line(proc.stdout)
    sc = load_scenario(scenario)
    assert s["exit_ok"] is True
    assert s["steps"] == sc.total_steps
    ok = meets_targets(s, sc.robot.tmin, sc.robot.tmax)
    assert all(ok.values()), (ok, s)
    assert s["rms_position_error"] <= 1e-3
    assert s["final_position_error"] <= 1e-4
    assert s["rms_orientation_error"] <= 1e-3
    assert s["max_tension_change"] <= tension_change_bound(sc)


def test_the_bound_catches_a_jittery_distribution() -> None:
    """The same bound is exceeded by the QP taken at OSQP's default tolerances (so it can fail)."""
    proc = cdpr("run", "caroca_15kg_osqp_defaults", "--duration", "2", "--quiet", timeout=300, check=True)
    s = last_json_line(proc.stdout)
    assert s["max_tension_change"] > tension_change_bound(load_scenario("caroca_15kg_osqp_defaults", {"duration": 2}))


def test_experiments_command_writes_the_page(tmp_path: Path) -> None:
    docs, runs = tmp_path / "docs", tmp_path / "runs"
    proc = cdpr("experiments", "--docs", str(docs), "--runs", str(runs), "--duration", "0.3",
                "--only", "caroca_15kg", "--only", "caroca_15kg_ups", timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = last_json_line(proc.stdout)
    assert out["runs"] == 2
    assert out["targets_missed"] == []
    page = (docs / "results.md").read_text()
    assert "| `caroca_15kg` |" in page
    assert "| `caroca_15kg_ups` |" in page
    assert "Largest platform position difference" in page
    for name in ("caroca_15kg", "caroca_15kg_ups"):
        assert (docs / "results" / name / "tracking.png").stat().st_size > 10_000
        assert f"results/{name}/tracking.png" in page
    table = json.loads((docs / "results" / "results.json").read_text())
    assert set(table) == {"caroca_15kg", "caroca_15kg_ups"}
