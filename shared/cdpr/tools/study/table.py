"""The results table: one row per point (parameters, metrics, status, wall time, node), CSV and Parquet."""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

from cdpr.config.study import SUMMARY_METRICS, StudySpec

TOLERANCE = 1e-9  # N: a tension this close to a limit is within it


def metrics_of(summary: dict[str, Any], names: list[str],
               limits: tuple[list[float], list[float]] | None) -> dict[str, Any]:
    """The study's metrics from a session summary (None where the summary has no value); ``limits`` are the
    point's (tmin, tmax) of each cable."""
    out: dict[str, Any] = {}
    tmin, tmax = summary.get("tension_min"), summary.get("tension_max")
    for name in names:
        if name in SUMMARY_METRICS:
            value = summary.get(name)
            out[name] = value if isinstance(value, int | float) and not isinstance(value, bool) else None
        elif name == "tension_range":
            out[name] = tmax - tmin if tmin is not None and tmax is not None else None
        elif name == "tensions_within_limits":
            out[name] = _within_limits(summary, limits)
    return out


def _within_limits(summary: dict[str, Any], limits: tuple[list[float], list[float]] | None) -> int | None:
    """1 if every cable's tensions stayed within its limits, 0 if not, None if unknown."""
    lows, highs = summary.get("cable_tension_min"), summary.get("cable_tension_max")
    if lows is None or highs is None or limits is None or len(lows) != len(limits[0]):
        return None
    return int(all(lo - TOLERANCE <= t for lo, t in zip(limits[0], lows, strict=True))
               and all(t <= hi + TOLERANCE for hi, t in zip(limits[1], highs, strict=True)))


def row_columns(spec: StudySpec) -> list[str]:
    return ["point", "id", "sample", *[p.column for p in spec.parameters], *spec.metrics, "status", "error",
            "wall_s", "node", "host", "mode", "state_digest", "rrd"]


def _cell(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_table(rows: list[dict[str, Any]], columns: list[str], stem: Path) -> tuple[Path, Path]:
    """``stem``.csv and ``stem``.parquet, rows in point order."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    rows = sorted(rows, key=lambda r: r.get("point", r.get("trial", 0)))
    data: dict[str, list[Any]] = {c: [_cell(r.get(c)) for r in rows] for c in columns}
    arrays = {}
    for name, values in data.items():
        kinds = {type(v) for v in values if v is not None}
        if kinds <= {int, float} and float in kinds:
            values = [None if v is None else float(v) for v in values]
        elif len(kinds) > 1:  # mixed (a parameter of numbers and strings): as text
            values = [None if v is None else str(v) for v in values]
        arrays[name] = pa.array(values) if kinds else pa.array(values, type=pa.null())
    pq.write_table(pa.table(arrays), stem.with_suffix(".parquet"))
    with open(stem.with_suffix(".csv"), "w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f)
        writer.writerow(columns)
        for r in rows:
            writer.writerow(["" if _cell(r.get(c)) is None else _fmt(r.get(c)) for c in columns])
    return stem.with_suffix(".csv"), stem.with_suffix(".parquet")


def _fmt(v: Any) -> Any:
    return repr(v) if isinstance(v, float) else v


def _num(v: Any) -> float | None:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        return None
    return float(v)


def _g(v: float | None) -> str:
    return "–" if v is None else f"{v:.4g}"


def statistics(rows: list[dict[str, Any]], columns: list[str]) -> dict[str, dict[str, float]]:
    """Per column over the finished points: min, 5th percentile, median, mean, 95th percentile, max."""
    import numpy as np

    out: dict[str, dict[str, float]] = {}
    for c in columns:
        values = np.array([v for r in rows if r.get("status") == "ok" and (v := _num(r.get(c))) is not None])
        if values.size:
            p5, p50, p95 = np.percentile(values, [5, 50, 95])
            out[c] = {"min": float(values.min()), "p5": float(p5), "median": float(p50),
                      "mean": float(values.mean()), "p95": float(p95), "max": float(values.max()),
                      "n": int(values.size)}
    return out


def markdown_summary(spec: StudySpec, rows: list[dict[str, Any]], max_rows: int = 40) -> str:
    """The study as Markdown: its statistics (Monte Carlo) or its whole table (a small grid)."""
    ok = [r for r in rows if r.get("status") == "ok"]
    failed = [r for r in rows if r.get("status") != "ok"]
    lines = [f"**{spec.name}**: {len(rows)} points, {len(ok)} finished, {len(failed)} failed.", ""]
    params = [p.column for p in spec.parameters]
    if any(not p.is_grid for p in spec.parameters) or len(rows) > max_rows:
        stats = statistics(rows, [*params, *spec.metrics])
        lines += ["| | min | 5 % | median | mean | 95 % | max |", "|---|---|---|---|---|---|---|"]
        for c, s in stats.items():
            lines.append(f"| {c} | " + " | ".join(_g(s[k]) for k in ("min", "p5", "median", "mean", "p95", "max"))
                         + " |")
    else:
        cols = [*params, *spec.metrics, "status"]
        lines += ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
        for r in sorted(rows, key=lambda r: r["point"]):
            lines.append("| " + " | ".join(_g(v) if _num(v) is not None else str(v) for v in
                                           (r.get(c) for c in cols)) + " |")
    for r in failed[:10]:
        lines.append(f"\n- point {r['point']}: {r.get('error')}")
    return "\n".join(lines) + "\n"
