"""``cdpr study``: every point of a study as one Ray task, one folder of results, resumable.

``ray.init()`` without an address starts Ray on this machine (nothing to set up); ``--address`` or
``RAY_ADDRESS`` runs the same study on a cluster. The driver (this process) writes everything: each
point's YAML files, its ``result.json`` as soon as it finishes (so a re-run skips it), and at the end
the table (``results.csv``, ``results.parquet``), the plots and the resolved study file.
"""

from __future__ import annotations

import json
import logging
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from cdpr.config.study import StudySpec, load_study
from cdpr.config.variation import Base, Point, check_point, load_base, study_points, write_point_files
from cdpr.errors import InputError
from cdpr.tools.study.runner import resolve_mode, run_point
from cdpr.tools.study.table import markdown_summary, metrics_of, row_columns, write_table

RAY_MISSING = "cdpr study and cdpr tune need Ray: pip install 'cdpr[study]' (ray[tune], optuna, pyarrow)"


def need_ray() -> None:
    try:
        import optuna  # noqa: F401
        import pyarrow  # noqa: F401
        import ray  # noqa: F401
    except ImportError:
        raise InputError(RAY_MISSING) from None


CONNECT_ATTEMPTS = 5  # a cluster's Ray Client server now and then fails to start a new driver's server (below)
CONNECT_RETRY_S = 2.0


def connect_ray(address: str | None, verbose: bool = False) -> dict[str, Any]:
    """Join the cluster at ``address`` (or $RAY_ADDRESS), else start Ray on this machine. Its resources. Ray's
    own start-up lines and warnings (e.g. its token authentication's) only with ``verbose`` ($CDPR_RAY_LOG=1):
    a study's output is the study's."""
    import ray

    verbose = verbose or os.environ.get("CDPR_RAY_LOG", "") not in ("", "0")
    level = logging.INFO if verbose else logging.ERROR
    logging.getLogger("ray").setLevel(level)
    if not ray.is_initialized():
        address = address or os.environ.get("RAY_ADDRESS") or None
        if address:
            join_cluster(lambda: ray.init(address=address, log_to_driver=False, logging_level=level), address)
        else:
            ray.init(include_dashboard=False, log_to_driver=False, logging_level=level)
    return {"nodes": len([n for n in ray.nodes() if n.get("Alive")]), "cpus": ray.cluster_resources().get("CPU", 0)}


def join_cluster(init: Callable[[], object], address: str, attempts: int = CONNECT_ATTEMPTS,
                 wait: float = CONNECT_RETRY_S) -> None:
    """``init()`` (``ray.init`` at ``address``), tried again when the cluster refused this driver at the start.

    Ray Client's head runs one server process per driver; Ray 2.60 now and then sees that process end at once
    (``Initialization failure from server``: "SpecificServer startup failed" in the head's
    ``ray_client_server.err``) and the next driver is served. That refusal is tried again ``attempts`` times in
    all, ``wait`` s apart, saying so on stderr; anything else (unreachable, not a Ray Client port, versions)
    and the last refusal are an :class:`InputError` naming the address and Ray's reason."""
    for attempt in range(1, attempts + 1):
        try:
            init()
            return
        except ConnectionAbortedError as exc:  # the head answered and refused: its server for us did not start
            if attempt == attempts:
                raise InputError(f"--address {address}: {ray_reason(exc)} ({attempts} attempts)") from None
            print(f"cdpr: --address {address}: {ray_reason(exc)}; connecting again in {wait:g} s "
                  f"(attempt {attempt + 1} of {attempts})", file=sys.stderr, flush=True)
            time.sleep(wait)
        except (ConnectionError, TimeoutError, ValueError, RuntimeError) as exc:  # unreachable, no Ray Client
            raise InputError(f"--address {address}: {ray_reason(exc)}") from None


def ray_reason(exc: BaseException) -> str:
    """Ray's error in one line: its first line, and the last line of the server's traceback it carries."""
    lines = [line.strip() for line in str(exc).strip().splitlines() if line.strip()]
    if not lines:
        return type(exc).__name__
    first, last = lines[0].rstrip(":"), lines[-1]
    return (first if len(lines) == 1 else f"{first}: {last}").rstrip(".")


class Progress:
    """One progress line on stderr with the ETA (redrawn in place on a terminal, every few s otherwise)."""

    def __init__(self, total: int, done: int, label: str, enabled: bool = True, unit: str = "points") -> None:
        self.total, self.done, self.first, self.failed = total, done, done, 0
        self.label, self.enabled, self.unit = label, enabled, unit
        self.started = time.monotonic()
        self.tty = sys.stderr.isatty()
        self.last = 0.0

    def update(self, ok: bool) -> None:
        self.done += 1
        self.failed += 0 if ok else 1
        self.show()

    def show(self, final: bool = False) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if not (self.tty or final or now - self.last >= 5.0 or self.done == self.total):
            return
        self.last = now
        elapsed = now - self.started
        ran = self.done - self.first
        left = self.total - self.done
        eta = f"ETA {_clock(elapsed / ran * left)}" if ran and left else ("done" if not left else "ETA ?")
        width = 24
        filled = int(width * self.done / self.total) if self.total else width
        bar = "#" * filled + "." * (width - filled)
        text = (f"[{self.label}] [{bar}] {self.done}/{self.total} {self.unit}, {self.failed} failed, "
                f"{_clock(elapsed)} elapsed, {eta}")
        sys.stderr.write(("\r" + text + "\x1b[K") if self.tty else text + "\n")
        if self.tty and (final or not left):
            sys.stderr.write("\n")
        sys.stderr.flush()


def _clock(seconds: float) -> str:
    s = round(seconds)
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


@dataclass
class Prepared:
    spec: StudySpec
    base: Base
    out: Path
    mode: str
    points: list[Point]
    limits: dict[str, tuple[list[float], list[float]]]  # point id -> its (tmin, tmax) per cable
    rows: dict[str, dict[str, Any]]  # point id -> its row, for the points already finished or invalid
    todo: list[Point]
    resumed: int  # points whose result a previous run left


def resolved_study(spec: StudySpec, study_path: Path, mode: str) -> str:
    data = spec.model_dump(mode="json", exclude_none=True)
    for p in data["parameters"]:
        for key in ("name", "integer", "plant_only"):
            if p.get(key) in (None, False):
                p.pop(key, None)
        if p.get("op") == "set":
            p.pop("op")
    scenario = spec.scenario
    if scenario.endswith((".yaml", ".yml")) and not Path(scenario).is_absolute():
        scenario = str((study_path.parent / scenario).resolve())
    data["scenario"] = scenario
    data["mode"] = mode
    head = (f"# {study_path.name}, resolved by cdpr study: every default filled in, the base scenario's path "
            f"absolute, the session mode chosen.\n")
    return head + yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=120)


def prepare(study_file: str | Path, out: Path | None = None, mode: str | None = None,
            record: bool | None = None) -> Prepared:
    spec, path = load_study(study_file)
    if record is not None:
        spec = spec.model_copy(update={"record": record})
    if mode is not None:
        spec = StudySpec.model_validate({**spec.model_dump(), "mode": mode})
    base = load_base(spec, path)
    chosen = resolve_mode(spec.mode)
    points = study_points(spec, base, str(path))
    out = out if out is not None else Path("runs") / "studies" / spec.name
    out.mkdir(parents=True, exist_ok=True)
    (out / "study.yaml").write_text(resolved_study(spec, path, chosen), encoding="utf-8")
    rows: dict[str, dict[str, Any]] = {}
    limits: dict[str, tuple[list[float], list[float]]] = {}
    todo: list[Point] = []
    resumed = 0
    for point in points:
        folder = out / "points" / point.id
        write_point_files(point, folder)
        done = folder / "result.json"
        if done.is_file():
            try:
                previous = json.loads(done.read_text(encoding="utf-8"))
            except ValueError:
                previous = {}
            if previous.get("status") == "ok" and previous.get("digest") == point.digest:
                rows[point.id] = previous["row"]
                resumed += 1
                continue
        try:
            limits[point.id] = check_point(point, folder)
        except InputError as exc:
            rows[point.id] = base_row(spec, point, _point_mode(point, chosen)) | {
                "status": "failed", "error": f"invalid point: {exc}"}
            continue
        todo.append(point)
    return Prepared(spec, base, out, chosen, points, limits, rows, todo, resumed)


def _point_mode(point: Point, mode: str) -> str:
    return "multi-process" if point.split else mode


def base_row(spec: StudySpec, point: Point, mode: str) -> dict[str, Any]:
    return {"point": point.index, "id": point.id, "sample": point.sample, **point.values, "mode": mode}


def result_row(prep: Prepared, point: Point, result: dict[str, Any]) -> dict[str, Any]:
    summary = result.get("summary") or {}
    row = base_row(prep.spec, point, _point_mode(point, prep.mode))
    row.update(metrics_of(summary, prep.spec.metrics, prep.limits.get(point.id)))
    row.update(status=result.get("status", "failed"), error=result.get("error"), wall_s=result.get("wall_s"),
               node=result.get("node"), host=result.get("host"), state_digest=summary.get("state_digest"))
    return row


def run_study(study_file: str | Path, out: Path | None = None, address: str | None = None,
              mode: str | None = None, record: bool | None = None, progress: bool = True) -> dict[str, Any]:
    """Run (or resume) a study; returns its JSON summary. Every point's outcome is a row, never an exception."""
    need_ray()
    prep = prepare(study_file, out, mode, record)
    if not prep.todo:  # everything finished before: the outputs again, no Ray needed
        return write_outputs(prep, 0, 0.0, {})
    import ray

    if progress:
        for line in describe(prep):
            print(f"[{prep.spec.name}] {line}", file=sys.stderr, flush=True)
    cluster = connect_ray(address)
    remote = ray.remote(run_point).options(num_cpus=prep.spec.cpus_per_point, max_retries=1,
                                           scheduling_strategy="SPREAD")
    started = time.monotonic()
    bar = Progress(len(prep.points), len(prep.points) - len(prep.todo), prep.spec.name, progress)
    bar.show()
    pending = {}
    for point in prep.todo:
        task = {"id": point.id, "files": point.files, "mode": _point_mode(point, prep.mode), "split": point.split,
                "record": prep.spec.record, "timeout": prep.spec.timeout}
        pending[remote.remote(task)] = point
    ran = 0
    while pending:
        ready, _ = ray.wait(list(pending), num_returns=1, timeout=1.0)
        for ref in ready:
            point = pending.pop(ref)
            try:
                result = ray.get(ref)
            except Exception as exc:  # the task itself died (a node lost, out of memory): a row, not a crash
                result = {"status": "failed", "error": f"task failed: {str(exc).strip().splitlines()[0][:300]}"}
            finish(prep, point, result)
            ran += 1
            bar.update(prep.rows[point.id]["status"] == "ok")
        if not ready:
            bar.show()
    wall = time.monotonic() - started
    return write_outputs(prep, ran, wall, cluster)


def describe(prep: Prepared) -> list[str]:
    """The study's first lines: what it runs, and what varies for the plant and for the controller — a value the
    controller is given too is one it compensates (a heavier platform it knows: the tracking does not change);
    ``plant_only`` makes it a model error the controller does not know about."""
    spec = prep.spec
    modes = ", ".join(sorted({_point_mode(point, prep.mode) for point in prep.points}))
    lines = [f"{len(prep.points)} points of {spec.scenario}, {modes}"
             + (f" ({len(prep.points) - len(prep.todo)} done before: resumed)" if len(prep.todo) < len(prep.points)
                else "")]
    for p in spec.parameters:
        values = p.discrete
        law = (f"{p.law} {', '.join(map(str, values[:4]))}{' …' if len(values) > 4 else ''}" if values is not None
               else f"{p.law} {getattr(p, p.law)}")
        what = f"{p.column}: {p.op} {law}"
        if p.plant_only:
            lines.append(f"varies {what} for the plant only: the controller keeps the base scenario's (a model error)")
        else:
            lines.append(f"varies {what} for the plant and the controller alike: the controller knows each point's "
                         "value (plant_only: true for a model error it does not know)")
    return lines


def finish(prep: Prepared, point: Point, result: dict[str, Any]) -> None:
    folder = prep.out / "points" / point.id
    row = result_row(prep, point, result)
    rrd_bytes = result.pop("rrd_bytes", None)
    if rrd_bytes:
        (folder / "point.rrd").write_bytes(rrd_bytes)
        row["rrd"] = str(folder / "point.rrd")
    prep.rows[point.id] = row
    record = {"status": row["status"], "digest": point.digest, "row": row, "summary": result.get("summary"),
              "stderr_tail": result.get("stderr_tail")}
    (folder / "result.json").write_text(json.dumps(record, indent=1) + "\n", encoding="utf-8")


def write_outputs(prep: Prepared, ran: int, wall: float, cluster: dict[str, Any]) -> dict[str, Any]:
    from cdpr.tools.study.plots import study_plots

    rows = [prep.rows[p.id] for p in prep.points]
    csv_path, parquet_path = write_table(rows, row_columns(prep.spec), prep.out / "results")
    plots = study_plots(prep.spec, rows, prep.out)
    (prep.out / "summary.md").write_text(markdown_summary(prep.spec, rows), encoding="utf-8")
    ok = sum(r["status"] == "ok" for r in rows)
    steps = sum(_steps(prep.out / "points" / p.id / "result.json") for p in prep.todo)
    return {
        "study": prep.spec.name, "out": str(prep.out), "points": len(rows), "ok": ok, "failed": len(rows) - ok,
        "ran": ran, "resumed": prep.resumed,
        "mode": ", ".join(sorted({_point_mode(p, prep.mode) for p in prep.points})), "wall_s": round(wall, 3),
        "steps_per_s": round(steps / wall, 1) if wall > 0 and steps else None,
        "nodes": cluster.get("nodes"), "cpus": cluster.get("cpus"),
        "table": [str(csv_path), str(parquet_path)], "plots": [str(p) for p in plots],
    }


def _steps(result_json: Path) -> int:
    try:
        return int((json.loads(result_json.read_text(encoding="utf-8")).get("summary") or {}).get("steps") or 0)
    except (OSError, ValueError):
        return 0
