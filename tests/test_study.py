"""Parameter studies on Ray (`cdpr study`, `cdpr tune`, the study throughput bench).

The fast tests check the study files and the points they make (no session); the slow ones run real
sessions: a study on a real two-node Ray cluster started here (``ray.cluster_utils.Cluster``, two nodes
of 1 CPU), its resumption, and a short tuning whose best scenario is run again. The slow ones share that
cluster, started once for the module (each command joins it with ``--address``, as its own Ray job), instead
of starting Ray on this machine each.
"""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from cdpr.errors import InputError
from conftest import CDPR, last_json_line

SMALL = """
name: small
scenario: caroca_15kg
set: {duration: 0.3}
parameters:
  - {name: kp, path: controller.kp, values: [1000.0, 1500.0]}
  - {name: mass, path: platform.mass, values: [12.0, 15.0]}
metrics: [rms_position_error, tension_max, tensions_within_limits, infeasible_commands]
"""

MONTE_CARLO = """
name: mc
scenario: caroca_15kg
set: {duration: 0.3}
samples: 3
seed: 11
parameters:
  - {name: tda, path: controller.tda.method, values: [qp, closed-form]}
  - {name: mass_factor, path: platform.mass, op: scale, uniform: [0.8, 1.2], plant_only: true}
  - {name: anchor_error, path: robot.cables.*.frame, op: add, uniform: [-0.005, 0.005], plant_only: true}
  - {name: encoder_sigma, path: sim.sensors.encoders.sigma, normal: [1.0e-5, 1.0e-6]}
"""


def write(tmp_path: Path, text: str, name: str = "study.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def read_rows(csv_path: Path) -> list[dict[str, str]]:
    with open(csv_path, encoding="utf-8") as f:
        return list(csv.DictReader(f))


# ------------------------------------------------------------------------------------------------
# Study files and points (no session)


@pytest.mark.parametrize(("change", "message"), [
    ("parameters:\n  - {path: platform.mass, uniform: [2.0, 1.0]}\nsamples: 2\n",
     "parameters.0: Value error, uniform: low must be below high"),
    ("parameters:\n  - {path: platform.mass, values: [1.0], uniform: [1.0, 2.0]}\n",
     "parameters.0: Value error, give exactly one of values, uniform, normal, loguniform, choice"),
    ("parameters:\n  - {path: platform.mass, uniform: [1.0, 2.0]}\n", "samples: missing"),
    ("parameters:\n  - {path: platform.mass, values: [1.0]}\nmetrics: [rms_error]\n",
     "metrics.0: unknown metric 'rms_error'"),
    ("parameters:\n  - {path: platform.mass, values: [1.0], colour: red}\n",
     "parameters.0.colour: unknown key (check its spelling)"),
])
def test_a_bad_study_file_is_one_line_naming_the_field(tmp_path: Path, change: str, message: str) -> None:
    from cdpr.config.study import load_study

    path = write(tmp_path, "name: bad\nscenario: caroca_15kg\n" + change)
    with pytest.raises(InputError) as err:
        load_study(path)
    text = str(err.value).replace("Value error, ", "")
    assert text.startswith(f"{path}: "), text
    assert message.replace("Value error, ", "") in text
    assert "\n" not in text


def test_the_cli_says_so_in_one_line_with_exit_code_2(tmp_path: Path) -> None:
    path = write(tmp_path, "name: bad\nscenario: caroca_15kg\nparameters:\n  - {path: controller.kp, values: []}\n")
    proc = subprocess.run([*CDPR, "study", str(path)], capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        f"cdpr: error: {path}: parameters.0.values: List should have at least 1 item after validation, not 0 (got [])"]


def test_a_path_that_is_not_in_the_base_scenario_is_an_error(tmp_path: Path) -> None:
    from cdpr.tools.study.engine import prepare

    path = write(tmp_path, "name: bad\nscenario: caroca_15kg\nparameters:\n"
                 "  - {path: controller.gain, op: scale, values: [2.0]}\n")
    with pytest.raises(InputError, match=r"parameters\.0: controller\.gain is not in the base file"):
        prepare(path, tmp_path / "out", mode="multi-process")


def test_an_invalid_point_is_a_failed_row_not_a_failed_study(tmp_path: Path) -> None:
    from cdpr.tools.study.engine import prepare

    path = write(tmp_path, "name: tda\nscenario: caroca_15kg\nparameters:\n"
                 "  - {path: controller.tda.method, values: [qp, closed_form, continuity]}\n")
    prep = prepare(path, tmp_path / "out", mode="multi-process")
    assert [p.values["controller.tda.method"] for p in prep.todo] == ["qp", "continuity"]
    (bad,) = prep.rows.values()
    assert (bad["point"], bad["status"]) == (1, "failed")
    assert "controller.tda.method: unknown TDA method 'closed_form'" in bad["error"]
    assert (tmp_path / "out" / "study.yaml").is_file()
    assert len(list((tmp_path / "out" / "points").glob("*/scenario.yaml"))) == 3


def test_without_ray_the_study_commands_say_how_to_get_it(tmp_path: Path) -> None:
    path = write(tmp_path, SMALL)
    code = ("import sys; sys.modules['ray'] = None\n"  # `import ray` raises ImportError, as when it is absent
            "from cdpr.tools.cli import main\n"
            f"main(['study', {str(path)!r}])\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        "cdpr: error: cdpr study and cdpr tune need Ray: pip install 'cdpr[study]' (ray[tune], optuna, pyarrow)"]


# what Ray 2.60's client raises when the head's server for this driver ended at once (its proxier's traceback)
REFUSED = ("Initialization failure from server:\nTraceback (most recent call last):\n"
           '  File "/opt/cdpr/lib/python3.11/site-packages/ray/util/client/server/proxier.py", line 772, in Datapath\n'
           "    raise RuntimeError(\n"
           "RuntimeError: Starting Ray client server failed. See ray_client_server_23000.err for detailed logs.\n")


def test_a_driver_the_cluster_refused_at_the_start_connects_again(capsys: pytest.CaptureFixture[str]) -> None:
    from cdpr.tools.study.engine import join_cluster

    calls: list[int] = []

    def refused_once() -> None:  # stands in for ray.init: the head refuses the first driver, serves the next
        calls.append(1)
        if len(calls) == 1:
            raise ConnectionAbortedError(REFUSED)

    join_cluster(refused_once, "ray://head:10001", wait=0.0)
    assert len(calls) == 2
    assert capsys.readouterr().err.splitlines() == [
        "cdpr: --address ray://head:10001: Initialization failure from server: RuntimeError: Starting Ray client "
        "server failed. See ray_client_server_23000.err for detailed logs; connecting again in 0 s (attempt 2 of 5)"]

    def refused() -> None:
        calls.append(1)
        raise ConnectionAbortedError(REFUSED)

    calls.clear()
    with pytest.raises(InputError) as err:
        join_cluster(refused, "ray://head:10001", wait=0.0)
    assert len(calls) == 5  # then it says why, in one line
    assert str(err.value) == ("--address ray://head:10001: Initialization failure from server: RuntimeError: "
                              "Starting Ray client server failed. See ray_client_server_23000.err for detailed logs "
                              "(5 attempts)")

    def unreachable() -> None:  # not a refusal: said at once
        calls.append(1)
        raise ConnectionError("ray client connection timeout")

    calls.clear()
    with pytest.raises(InputError, match=r"^--address ray://head:10001: ray client connection timeout$"):
        join_cluster(unreachable, "ray://head:10001", wait=0.0)
    assert len(calls) == 1


def test_points_grids_times_draws_reproducible_and_plant_only(tmp_path: Path) -> None:
    from cdpr.config.scenario import load_scenario
    from cdpr.config.study import load_study
    from cdpr.config.variation import check_point, load_base, study_points, write_point_files

    spec, path = load_study(write(tmp_path, MONTE_CARLO))
    base = load_base(spec, path)
    points = study_points(spec, base, str(path))
    assert len(points) == 2 * 3  # the grid's 2 values times 3 samples
    again = study_points(spec, base, str(path))
    assert [p.files for p in points] == [p.files for p in again]  # same seed, same points
    other = study_points(spec.model_copy(update={"seed": 12}), base, str(path))
    assert [p.files for p in points] != [p.files for p in other]
    # common random numbers: sample s draws the same for every grid value
    assert points[0].values["mass_factor"] == points[3].values["mass_factor"]
    assert (points[0].values["tda"], points[3].values["tda"]) == ("qp", "closed-form")
    nominal = load_scenario("caroca_15kg")
    for point in points:
        folder = tmp_path / point.id
        write_point_files(point, folder)
        check_point(point, folder)
        plant, controller = load_scenario(folder / "scenario.yaml"), load_scenario(folder / "controller.yaml")
        assert point.split
        assert 0.8 * 15.0 <= plant.robot.mass <= 1.2 * 15.0
        assert plant.robot.mass == pytest.approx(15.0 * point.values["mass_factor"])
        assert controller.robot.mass == 15.0  # the controller keeps the nominal model
        da = plant.robot.frame_points - nominal.robot.frame_points
        assert 0 < abs(da).max() <= 0.005
        assert len({round(x, 12) for x in da.ravel()}) == da.size  # one draw each
        assert (controller.robot.frame_points == nominal.robot.frame_points).all()
        assert point.values["anchor_error"] == pytest.approx(float((da**2).mean() ** 0.5))
        # a parameter the controller knows reaches both
        assert plant.tda_method == controller.tda_method == point.values["tda"]
        sigma = plant.spec.sim.sensors.encoders.sigma
        assert sigma == controller.spec.sim.sensors.encoders.sigma == point.values["encoder_sigma"]


def test_a_study_says_first_what_varies_for_the_plant_and_for_the_controller(tmp_path: Path) -> None:
    """A first mass sweep shows nothing when the controller knows each mass: the study's first lines say, for each
    parameter, whether the controller is given it too, and how to make it a model error."""
    from cdpr.tools.study.engine import describe, prepare

    lines = describe(prepare(write(tmp_path, MONTE_CARLO), tmp_path / "out"))
    assert lines[0] == "6 points of caroca_15kg, multi-process"
    assert ("varies mass_factor: scale uniform [0.8, 1.2] for the plant only: the controller keeps the base "
            "scenario's (a model error)") in lines
    assert ("varies tda: set values qp, closed-form for the plant and the controller alike: the controller knows each "
            "point's value (plant_only: true for a model error it does not know)") in lines


def test_a_metric_the_parameter_does_not_change_is_drawn_flat_with_short_ticks() -> None:
    """1e-14 of rounding on one number is not magnified into a wiggle with 14-digit tick labels."""
    from cdpr.tools.study.plots import flat_range, tick

    same = [0.02363447120255, 0.02363447120255 + 1e-14, 0.02363447120255 - 2e-14]
    low, high = flat_range(same)  # type: ignore[misc]
    assert low == pytest.approx(0.95 * 0.02363447120255)
    assert high == pytest.approx(1.05 * 0.02363447120255)
    assert flat_range([0.0236, 0.0237]) is None  # a real change is drawn as it is
    assert flat_range([0.0, 0.0]) == (-1.0, 1.0)
    assert [tick(x) for x in (0.02363447120255, 2.2640000000000002, -0.0, 1500.0, 1.5e-7)] == [
        "0.02363", "2.264", "0", "1500", "1.5e-07"]


# ------------------------------------------------------------------------------------------------
# Real studies


@pytest.fixture(scope="module")
def cluster() -> Iterator[Any]:
    """A two-node Ray cluster on this machine (two nodes of 1 CPU), shared by the module's real studies."""
    from ray.cluster_utils import Cluster

    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
    try:
        cluster.add_node(num_cpus=1)
        cluster.wait_for_nodes()
        yield cluster
    finally:
        cluster.shutdown()


@pytest.mark.slow
def test_a_study_on_a_two_node_ray_cluster_runs_on_both_and_resumes(tmp_path: Path, cluster: Any) -> None:
    study = write(tmp_path, SMALL)
    out = tmp_path / "out"
    node_ids = {n.node_id for n in cluster.list_all_nodes()}
    assert len(node_ids) == 2

    said: list[str] = []

    def study_run() -> dict:
        proc = subprocess.run([*CDPR, "study", str(study), "--out", str(out), "--address", cluster.address],
                              capture_output=True, text=True, timeout=600, check=False)
        assert proc.returncode == 0, proc.stderr[-3000:]
        said[:] = proc.stderr.splitlines()
        return last_json_line(proc.stdout)

    first = study_run()
    # the study's own lines first, Ray's start-up and warnings (its token authentication's) kept out
    assert said[0].startswith("[small] 4 points of caroca_15kg, ")  # and the mode the points run in
    assert said[1:3] == ["[small] varies kp: set values 1000.0, 1500.0 for the plant and the controller alike: the "
                        "controller knows each point's value (plant_only: true for a model error it does not know)",
                        "[small] varies mass: set values 12.0, 15.0 for the plant and the controller alike: the "
                        "controller knows each point's value (plant_only: true for a model error it does not know)"]
    assert all(line.startswith("[small] ") for line in said), said
    assert (first["nodes"], first["points"], first["ran"], first["ok"]) == (2, 4, 4, 4), first
    rows = read_rows(out / "results.csv")
    assert [int(r["point"]) for r in rows] == [0, 1, 2, 3]
    assert {(float(r["kp"]), float(r["mass"])) for r in rows} == {(1000.0, 12.0), (1000.0, 15.0),
                                                                   (1500.0, 12.0), (1500.0, 15.0)}
    assert all(r["status"] == "ok" and r["error"] == "" for r in rows)
    assert {r["node"] for r in rows} == node_ids  # points ran on both nodes
    assert all(float(r["rms_position_error"]) > 0 and r["tensions_within_limits"] == "1" for r in rows)
    import pyarrow.parquet as pq

    table = pq.read_table(out / "results.parquet")
    assert table.num_rows == 4
    assert table.column("rms_position_error").to_pylist() == [float(r["rms_position_error"]) for r in rows]
    assert yaml.safe_load((out / "study.yaml").read_text())["mode"] in ("in-process", "multi-process")
    assert (out / "heatmap_rms_position_error.png").stat().st_size > 10_000
    results = sorted(out.glob("points/*/result.json"))
    assert len(results) == 4
    stamps = [p.stat().st_mtime_ns for p in results]

    second = study_run()  # resumes: nothing runs again
    assert (second["ran"], second["resumed"], second["ok"]) == (0, 4, 4), second
    assert [p.stat().st_mtime_ns for p in results] == stamps
    assert read_rows(out / "results.csv") == rows

    results[2].unlink()  # one point lost: only it runs again, to the same result (deterministic)
    third = study_run()
    assert (third["ran"], third["resumed"]) == (1, 3), third
    again = read_rows(out / "results.csv")
    keep = ("kp", "mass", "rms_position_error", "tension_max", "infeasible_commands", "state_digest")
    assert [{k: r[k] for k in keep} for r in again] == [{k: r[k] for k in keep} for r in rows]


@pytest.mark.slow
def test_plant_only_errors_run_the_controller_on_the_nominal_model(tmp_path: Path, cluster: Any) -> None:
    text = MONTE_CARLO.replace("samples: 3", "samples: 1").replace("values: [qp, closed-form]", "values: [qp]")
    out = tmp_path / "out"
    proc = subprocess.run([*CDPR, "study", write(tmp_path, text), "--out", str(out), "--quiet",
                           "--address", cluster.address],
                          capture_output=True, text=True, timeout=600, check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = last_json_line(proc.stdout)
    assert (summary["ok"], summary["mode"]) == (1, "multi-process"), summary
    (row,) = read_rows(out / "results.csv")
    assert (row["mode"], row["status"]) == ("multi-process", "ok")
    # the model error shows: the nominal session tracks to a few µm in 0.3 s, this one is off by more
    assert float(row["rms_position_error"]) > 2e-5, row
    assert (out / "histograms.png").is_file()


@pytest.mark.slow
def test_tune_finds_a_best_scenario_that_loads_and_runs(tmp_path: Path, session_id: str, cluster: Any) -> None:
    study = write(tmp_path, """
name: tune_test
scenario: caroca_15kg
set: {duration: 0.4}
seed: 1
parameters:
  - {name: kp, path: controller.kp, loguniform: [500.0, 5000.0]}
  - {name: kd, path: controller.kd, loguniform: [500.0, 2000.0]}
metrics: [rms_position_error, max_position_error]
tune: {metric: rms_position_error, trials: 3, fidelities: [0.5, 1.0]}
""")
    out = tmp_path / "tune"
    proc = subprocess.run([*CDPR, "tune", str(study), "--out", str(out), "--quiet", "--address", cluster.address],
                          capture_output=True, text=True, timeout=900, check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = last_json_line(proc.stdout)
    assert summary["trials"] == 3, summary
    rows = read_rows(out / "trials.csv")
    assert len(rows) == 3
    assert (rows[0]["kp"], rows[0]["kd"]) == ("1500.0", "1500.0")  # Optuna starts at the scenario's gains
    best = summary["best"]
    assert best["rms_position_error"] == min(float(r["rms_position_error"]) for r in rows if r["status"] == "ok")
    assert best["rms_position_error"] <= summary["baseline"]["rms_position_error"]
    from cdpr.config.scenario import load_scenario

    scenario = load_scenario(best["scenario"])
    assert scenario.gains.kp[0] == pytest.approx(best["values"]["kp"])
    assert scenario.gains.kd[0] == pytest.approx(best["values"]["kd"])
    run = subprocess.run([*CDPR, "run", best["scenario"], "--quiet", "--session", session_id],
                         capture_output=True, text=True, timeout=300, check=False)
    assert run.returncode == 0, run.stderr[-3000:]
    again = last_json_line(run.stdout)
    assert again["rms_position_error"] == pytest.approx(best["rms_position_error"], rel=1e-12)  # deterministic


@pytest.mark.slow
def test_study_throughput_measures_both_ways(cluster: Any) -> None:
    import ray

    from cdpr.tools.study import study_throughput

    try:
        result = study_throughput(points=2, duration=0.3, address=cluster.address)
    finally:
        ray.shutdown()
    assert set(result) >= {"alone_steps_per_s", "study_steps_per_s", "ratio", "mode"}
    assert (result["failed"], result["steps_per_point"]) == (0, 300)
    assert result["alone_steps_per_s"] > 0
    assert result["study_steps_per_s"] > 0
    assert result["ratio"] == pytest.approx(result["study_steps_per_s"] / result["alone_steps_per_s"], rel=0.01)
    print(json.dumps(result))
