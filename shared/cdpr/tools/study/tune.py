"""``cdpr tune``: search a scenario's numbers (gains, limits, ...) for the best metric under constraints.

Ray Tune runs the trials (one session each, on this machine or a cluster), Optuna's TPE sampler
proposes them (``OptunaSearch``, seeded, warm-started at the base scenario's own values), and the ASHA
scheduler stops bad trials early: a trial runs its session for the first fraction of the duration
(``tune.fidelities``, e.g. 30 %), reports, and goes on to the whole duration only if it is among the
better ones at that fraction. A trial that breaks a constraint on a quantity that can only grow with
time (infeasible steps, tensions out of limits, the largest error) stops there. The objective Tune
minimises is the metric for a feasible trial, and 1e6 plus the size of the violation otherwise, so
the sampler learns where the feasible region ends.

The output folder gets ``trials.csv``/``trials.parquet`` (one row per trial), plots, the baseline (the
base scenario as it is) and ``best.yaml``: the best feasible trial as a ready-to-run scenario.
"""

from __future__ import annotations

import copy
import json
import math
import os
import tempfile
import time
from pathlib import Path
from typing import Any

import yaml

from cdpr.config.loading import read_yaml
from cdpr.config.study import ParameterSpec, StudySpec, load_study
from cdpr.config.variation import Base, build_point, check_point, load_base, matches, write_point_files
from cdpr.errors import InputError
from cdpr.tools.study.engine import Progress, connect_ray, need_ray, resolved_study
from cdpr.tools.study.runner import resolve_mode, run_point
from cdpr.tools.study.table import metrics_of, write_table

PENALTY = 1e6  # objective of an infeasible trial (plus the violation's size)
FAILED = 1e9  # objective of a trial whose session failed
# quantities that can only grow (or, for min-bounded ones, only shrink) as a session goes on: a bound broken
# after a fraction of the duration stays broken
MONOTONE = {"infeasible_commands", "clamped_commands", "tension_max", "tension_min", "tensions_within_limits",
            "max_position_error", "max_orientation_error", "max_tension_change", "tension_range"}


def search_space(spec: StudySpec) -> dict[str, Any]:
    from ray import tune

    space: dict[str, Any] = {}
    for p in spec.parameters:
        if p.discrete is not None:
            space[p.column] = tune.choice(p.discrete)
        elif p.uniform is not None:
            lo, hi = p.uniform
            space[p.column] = tune.qrandint(int(lo), int(hi)) if p.integer else tune.uniform(lo, hi)
        elif p.loguniform is not None:
            lo, hi = p.loguniform
            space[p.column] = tune.lograndint(int(lo), int(hi)) if p.integer else tune.loguniform(lo, hi)
        elif p.normal is not None:
            mean, sigma = p.normal
            space[p.column] = tune.qrandn(mean, sigma, 1) if p.integer else tune.randn(mean, sigma)
    return space


def baseline_values(spec: StudySpec, base: Base) -> dict[str, Any] | None:
    """The parameters' values in the base scenario (after ``set``): Optuna's first proposal."""
    values: dict[str, Any] = {}
    scenario, robot = copy.deepcopy(base.scenario), copy.deepcopy(base.robot)
    for path, value in spec.set.items():
        target = robot if path.startswith("robot.") else scenario
        for container, key in matches(target, path.removeprefix("robot."), create=True, where="set"):
            container[key] = value
    for p in spec.parameters:
        if p.op != "set":
            values[p.column] = 0.0 if p.op == "add" else 1.0
            continue
        try:
            places = matches(robot if p.on_robot else scenario, p.path.removeprefix("robot."), False, "")
        except InputError:
            return None
        value = places[0][0][places[0][1]]
        if not _in_range(p, value):
            return None
        values[p.column] = value
    return values


def _in_range(p: ParameterSpec, value: Any) -> bool:
    if p.uniform is not None or p.loguniform is not None:
        lo, hi = p.uniform or p.loguniform  # type: ignore[misc]
        return isinstance(value, int | float) and lo <= value <= hi
    if p.discrete is not None:
        return value in p.discrete
    return isinstance(value, int | float)


def judge(spec: StudySpec, metrics: dict[str, Any], ok: bool) -> tuple[float, bool, bool]:
    """(objective, feasible, stop now) of one report."""
    t = spec.tune
    assert t is not None
    sign = 1.0 if t.goal == "min" else -1.0
    value = metrics.get(t.metric)
    if not ok or value is None:
        return sign * FAILED, False, True
    violation, final = 0.0, False
    for c in t.constraints:
        v = metrics.get(c.metric)
        if v is None:
            violation += 1.0
            continue
        excess = max(0.0, v - c.max) if c.max is not None else 0.0
        excess += max(0.0, c.min - v) if c.min is not None else 0.0
        if excess > 0:
            bound = c.max if c.max is not None and v > c.max else c.min
            violation += excess / (abs(bound or 0.0) + 1.0)
            final = final or c.metric in MONOTONE
    if violation > 0:
        return sign * (PENALTY + min(violation, 1e5)), False, final
    return float(value), True, False


def _trainable(spec: StudySpec, base: Base, where: str, mode: str) -> Any:
    from ray import tune

    metrics = sorted({*spec.metrics, spec.tune.metric, *(c.metric for c in spec.tune.constraints)})  # type: ignore[union-attr]
    columns = [p.column for p in spec.parameters]

    def trial(config: dict[str, Any]) -> None:
        chosen = {j: config[c] for j, c in enumerate(columns)}
        for frac in spec.tune.fidelities:  # type: ignore[union-attr]
            point = build_point(spec, base, 0, chosen, None, where, duration_fraction=frac)
            with tempfile.TemporaryDirectory(prefix="cdpr-trial-") as tmp:
                write_point_files(point, Path(tmp))
                try:
                    limits = check_point(point, Path(tmp))
                except InputError as exc:
                    tune.report({"objective": FAILED, "feasible": False, "fidelity": frac, "ok": False,
                                 "error": str(exc)[:300]})
                    return
            result = run_point({"id": f"trial-{tune.get_context().get_trial_id()}", "files": point.files,
                                "mode": mode, "split": False, "record": False, "timeout": spec.timeout})
            ok = result["status"] == "ok"
            values = metrics_of(result.get("summary") or {}, metrics, limits)
            objective, feasible, stop = judge(spec, values, ok)
            tune.report({"objective": objective, "feasible": feasible, "fidelity": frac, "ok": ok,
                         "error": result.get("error") or "", "node": result.get("node", ""),
                         "host": result.get("host", ""), "wall_s": result.get("wall_s"),
                         **{k: (math.nan if v is None else v) for k, v in values.items()}})
            if stop:
                return

    return trial


def run_tune(study_file: str | Path, out: Path | None = None, address: str | None = None,
             trials: int | None = None, mode: str | None = None, progress: bool = True) -> dict[str, Any]:
    need_ray()
    spec, path = load_study(study_file)
    if spec.tune is None:
        raise InputError(f"{path}: tune: missing: what to optimise (metric, goal, trials, constraints)")
    if trials is not None:
        spec = spec.model_copy(update={"tune": spec.tune.model_copy(update={"trials": trials})})
    if mode is not None:
        spec = StudySpec.model_validate({**spec.model_dump(), "mode": mode})
    assert spec.tune is not None
    base = load_base(spec, path)
    chosen_mode = resolve_mode(spec.mode)
    out = (out if out is not None else Path("runs") / "tune" / spec.name).resolve()
    out.mkdir(parents=True, exist_ok=True)
    (out / "study.yaml").write_text(resolved_study(spec, path, chosen_mode), encoding="utf-8")
    # every parameter must be usable: a point with the baseline (or first) values builds and loads
    first = {j: _probe(p) for j, p in enumerate(spec.parameters)}
    probe = build_point(spec, base, 0, first, None, str(path))
    with tempfile.TemporaryDirectory(prefix="cdpr-probe-") as tmp:
        write_point_files(probe, Path(tmp))
        check_point(probe, Path(tmp))

    os.environ.setdefault("RAY_AIR_NEW_OUTPUT", "0")  # no console tables from Tune: the progress bar is ours
    import optuna
    import ray
    from ray import tune
    from ray.tune.schedulers import ASHAScheduler
    from ray.tune.search import ConcurrencyLimiter
    from ray.tune.search.optuna import OptunaSearch

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    cluster = connect_ray(address)
    t = spec.tune
    concurrent = t.concurrent or max(1, int(cluster["cpus"] // spec.cpus_per_point))
    warm = baseline_values(spec, base)
    searcher = ConcurrencyLimiter(OptunaSearch(points_to_evaluate=[warm] if warm else None, seed=spec.seed),
                                  max_concurrent=concurrent)
    scheduler = (ASHAScheduler(time_attr="training_iteration", max_t=len(t.fidelities), grace_period=1,
                               reduction_factor=2) if len(t.fidelities) > 1 else None)
    bar = Progress(t.trials, 0, f"tune {spec.name}", progress, unit="trials")

    class Bar(tune.Callback):
        def on_trial_complete(self, iteration: int, trials: list[Any], trial: Any, **info: Any) -> None:
            bar.update(bool(trial.last_result.get("ok", False)))

        def on_trial_error(self, iteration: int, trials: list[Any], trial: Any, **info: Any) -> None:
            bar.update(False)

    # the baseline (the base scenario's own values) runs beside the search, at the whole duration
    base_point = build_point(spec, base, 0, {}, None, str(path)) if warm is None else \
        build_point(spec, base, 0, {j: warm[p.column] for j, p in enumerate(spec.parameters)}, None, str(path))
    with tempfile.TemporaryDirectory(prefix="cdpr-base-") as tmp:
        write_point_files(base_point, Path(tmp))
        base_limits = check_point(base_point, Path(tmp))
    baseline_ref = ray.remote(run_point).options(num_cpus=spec.cpus_per_point).remote(
        {"id": "baseline", "files": base_point.files, "mode": chosen_mode, "split": False, "record": False,
         "timeout": spec.timeout})
    started = time.monotonic()
    bar.show()
    tuner = tune.Tuner(
        tune.with_resources(_trainable(spec, base, str(path), chosen_mode), {"cpu": spec.cpus_per_point}),
        param_space=search_space(spec),
        tune_config=tune.TuneConfig(metric="objective", mode="min" if t.goal == "min" else "max",
                                    search_alg=searcher, scheduler=scheduler, num_samples=t.trials),
        run_config=tune.RunConfig(name=spec.name, storage_path=str(out / "ray_tune"), verbose=0,
                                  callbacks=[Bar()]),
    )
    grid = tuner.fit()
    wall = time.monotonic() - started
    baseline_result = ray.get(baseline_ref)
    metric_names = sorted({*spec.metrics, t.metric, *(c.metric for c in t.constraints)})
    baseline = metrics_of(baseline_result.get("summary") or {}, metric_names, base_limits)
    rows = []
    for i in range(len(grid)):
        result = grid[i]
        last = result.metrics or {}
        config = result.config or {}
        full = last.get("fidelity") == 1.0
        status = ("failed" if not last.get("ok", False) or result.error else
                  "infeasible" if not last.get("feasible") else "ok" if full else "stopped early")
        row = {"trial": i, **{p.column: config.get(p.column) for p in spec.parameters},
               **{m: _clean(last.get(m)) for m in metric_names}, "fidelity": last.get("fidelity"),
               "objective": last.get("objective"), "feasible": bool(last.get("feasible", False)),
               "status": status, "error": last.get("error") or (str(result.error)[:300] if result.error else None),
               "iterations": last.get("training_iteration"), "wall_s": last.get("wall_s"),
               "node": last.get("node"), "host": last.get("host")}
        rows.append(row)
    columns = ["trial", *[p.column for p in spec.parameters], *metric_names, "fidelity", "objective", "feasible",
               "status", "error", "iterations", "wall_s", "node", "host"]
    write_table(rows, columns, out / "trials")
    finished = [r for r in rows if r["status"] == "ok"]
    sign = 1.0 if t.goal == "min" else -1.0
    best = min(finished, key=lambda r: sign * r[t.metric]) if finished else None
    plots = tune_plots(spec, rows, baseline, out)
    summary: dict[str, Any] = {
        "study": spec.name, "out": str(out), "trials": len(rows), "finished": len(finished),
        "stopped_early": sum(r["status"] == "stopped early" for r in rows),
        "infeasible": sum(r["status"] == "infeasible" for r in rows),
        "failed": sum(r["status"] == "failed" for r in rows), "mode": chosen_mode, "wall_s": round(wall, 1),
        "nodes": cluster["nodes"], "cpus": cluster["cpus"], "metric": t.metric, "goal": t.goal,
        "baseline": {"values": warm, **baseline, "status": baseline_result.get("status")},
        "table": [str(out / "trials.csv"), str(out / "trials.parquet")], "plots": [str(p) for p in plots],
    }
    if best is not None:
        values = {p.column: best[p.column] for p in spec.parameters}
        best_file = write_best(spec, base, path, values, best, baseline, out)
        summary["best"] = {"values": values, **{m: best[m] for m in metric_names}, "trial": best["trial"],
                           "scenario": str(best_file)}
        if baseline.get(t.metric) is not None:
            summary["improvement"] = baseline[t.metric] / best[t.metric] if best[t.metric] else None
    (out / "tune.json").write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    return summary


def _probe(p: ParameterSpec) -> Any:
    if p.values is not None:
        return p.values[0]
    if p.choice is not None:
        return p.choice[0]
    if p.uniform is not None:
        return p.uniform[0]
    if p.loguniform is not None:
        return p.loguniform[0]
    assert p.normal is not None
    return p.normal[0]


def _clean(v: Any) -> Any:
    return None if isinstance(v, float) and math.isnan(v) else v


def write_best(spec: StudySpec, base: Base, study_path: Path, values: dict[str, Any], best: dict[str, Any],
               baseline: dict[str, Any], out: Path) -> Path:
    """The best trial as a scenario file (``best.yaml``, and ``best_robot.yaml`` if the robot is a file)."""
    assert spec.tune is not None
    point = build_point(spec, base, 0, {j: values[p.column] for j, p in enumerate(spec.parameters)}, None,
                        str(study_path))
    doc = yaml.safe_load(point.files["scenario.yaml"])
    name = f"{base.scenario.get('name', spec.name)}_tuned"
    m = spec.tune.metric
    settings = ", ".join(f"{k} = {_short(v)}" for k, v in values.items())
    doc["name"] = name
    doc["description"] = (f"{base.scenario.get('name')} with {settings}, found by cdpr tune ({spec.name}: "
                          f"{len(spec.tune.constraints)} constraints): {m} {best[m]:.6g} "
                          f"(the base scenario's: {_short(baseline.get(m))}).")
    if "robot.yaml" in point.files:
        (out / "best_robot.yaml").write_text(point.files["robot.yaml"], encoding="utf-8")
        doc["robot"] = "best_robot.yaml"
    text = (f"# The best trial of `cdpr tune {study_path.name}` (trial {best['trial']}): a ready-to-run scenario.\n"
            + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=110))
    best_file = out / "best.yaml"
    best_file.write_text(text, encoding="utf-8")
    read_yaml(best_file)
    return best_file


def _short(v: Any) -> str:
    return f"{v:.6g}" if isinstance(v, float) else str(v)


def tune_plots(spec: StudySpec, rows: list[dict[str, Any]], baseline: dict[str, Any], out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    assert spec.tune is not None
    m = spec.tune.metric
    from cdpr.tools.study.plots import _label, _unit

    factor, _ = _unit(m)
    written = []
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    colours = {"ok": "#4c72b0", "stopped early": "#bbbbbb", "infeasible": "#dd8452", "failed": "#c44e52"}
    for status, colour in colours.items():
        pts = [(r["trial"], r[m] * factor) for r in rows if r["status"] == status and r.get(m) is not None]
        if pts:
            xs, ys = zip(*pts, strict=True)
            ax.scatter(xs, ys, s=14, color=colour, label=status)
    pick = min if spec.tune.goal == "min" else max
    best_so_far, best = [], math.inf if spec.tune.goal == "min" else -math.inf
    for r in sorted(rows, key=lambda r: r["trial"]):
        if r["status"] == "ok" and r.get(m) is not None:
            best = pick(best, r[m] * factor)
        best_so_far.append(best)
    if any(math.isfinite(b) for b in best_so_far):
        ax.step(range(len(best_so_far)), best_so_far, where="post", color="black", lw=1, label="best so far")
    if baseline.get(m) is not None:
        ax.axhline(baseline[m] * factor, color="green", ls="--", lw=1, label="base scenario")
    ax.set_yscale("log")
    ax.set_xlabel("trial")
    ax.set_ylabel(_label(m))
    ax.legend(fontsize=8)
    ax.set_title(f"{spec.name}: {len(rows)} trials")
    fig.tight_layout()
    fig.savefig(out / "trials.png", dpi=110)
    plt.close(fig)
    written.append(out / "trials.png")
    numeric = [p.column for p in spec.parameters
               if all(isinstance(r.get(p.column), int | float) for r in rows)]
    if len(numeric) >= 2:
        x, y = numeric[:2]
        fig, ax = plt.subplots(figsize=(6.4, 4.8))
        done = [r for r in rows if r["status"] in ("ok", "stopped early") and r.get(m) is not None]
        bad = [r for r in rows if r["status"] in ("infeasible", "failed")]
        if done:
            sc = ax.scatter([r[x] for r in done], [r[y] for r in done], c=[math.log10(r[m] * factor) for r in done],
                            cmap="viridis_r", s=22)
            fig.colorbar(sc, ax=ax, label=f"log10 {_label(m)}")
        if bad:
            ax.scatter([r[x] for r in bad], [r[y] for r in bad], marker="x", color="#c44e52", label="infeasible/failed")
            ax.legend(fontsize=8)
        log_axes = {p.column for p in spec.parameters if p.loguniform is not None}
        if x in log_axes:
            ax.set_xscale("log")
        if y in log_axes:
            ax.set_yscale("log")
        ax.set_xlabel(x)
        ax.set_ylabel(y)
        ax.set_title(f"{spec.name}: where the trials went")
        fig.tight_layout()
        fig.savefig(out / "space.png", dpi=110)
        plt.close(fig)
        written.append(out / "space.png")
    return written
