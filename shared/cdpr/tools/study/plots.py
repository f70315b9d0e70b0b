"""A study's PNG plots (matplotlib): metric vs parameter, a heatmap for 2-D grids, histograms for Monte Carlo."""

from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from cdpr.config.study import METRICS, StudySpec

SCALE = {"m": (1e3, "mm"), "rad": (1e3, "mrad")}  # shown in readable units


def _unit(metric: str) -> tuple[float, str]:
    unit = METRICS[metric].rsplit(", ", 1)[-1] if ", " in METRICS[metric] else ""
    unit = unit if unit in ("m", "rad", "N", "s") else ""
    factor, shown = SCALE.get(unit, (1.0, unit))
    return factor, shown


def _label(metric: str) -> str:
    _, unit = _unit(metric)
    return f"{metric} ({unit})" if unit else metric


def _number(v: Any) -> float | None:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        return None
    return float(v)


def _ok(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [r for r in rows if r.get("status") == "ok"]


def _figure(n: int) -> tuple[Any, list[Any]]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cols = min(n, 3)
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols, 3.4 * rows), squeeze=False)
    flat = list(axes.ravel())
    for ax in flat[n:]:
        ax.set_visible(False)
    return fig, flat[:n]


def _save(fig: Any, path: Path, title: str) -> Path:
    import matplotlib.pyplot as plt

    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _numeric_metrics(spec: StudySpec, rows: list[dict[str, Any]]) -> list[str]:
    return [m for m in spec.metrics if any(_number(r.get(m)) is not None for r in rows)]


def study_plots(spec: StudySpec, rows: list[dict[str, Any]], out: Path) -> list[Path]:
    """Write the plots that fit the study's design; their paths."""
    ok = _ok(rows)
    metrics = _numeric_metrics(spec, ok)
    if not ok or not metrics:
        return []
    written = []
    grid = [p for p in spec.parameters if p.is_grid]
    random = [p for p in spec.parameters if not p.is_grid]
    if random:
        written.append(_histograms(spec, ok, metrics, out / "histograms.png"))
        for p in random:
            if any(_number(r.get(p.column)) is not None for r in ok):
                written.append(_versus(spec, ok, metrics, p.column, out / f"vs_{_safe(p.column)}.png", scatter=True))
    if len(grid) == 2 and not random:
        for metric in metrics:
            written.append(_heatmap(spec, ok, metric, grid[0].column, grid[1].column,
                                    out / f"heatmap_{_safe(metric)}.png"))
    elif grid and not random:
        for p in grid:
            written.append(_versus(spec, ok, metrics, p.column, out / f"vs_{_safe(p.column)}.png", scatter=False))
    elif grid and random:
        for p in grid:
            written.append(_boxes(spec, ok, metrics, p.column, out / f"by_{_safe(p.column)}.png"))
    return written


def flat_range(values: list[float]) -> tuple[float, float] | None:
    """The axis range to give ``values`` that are one number to 1e-9 of their size (a metric the parameter does
    not change, bar rounding): ±5 % around it, so that 1e-14 of noise is drawn flat, not magnified into a wiggle;
    None when they vary."""
    if not values:
        return None
    lo, hi = min(values), max(values)
    scale = max(abs(lo), abs(hi))
    if hi - lo > 1e-9 * scale:
        return None
    middle = (lo + hi) / 2
    pad = 0.05 * abs(middle) if middle != 0 else 1.0
    return middle - pad, middle + pad


def tick(value: float, _: object = None) -> str:
    """A tick label: four significant digits, no float noise (``0.02363``, not ``0.02363447120255``)."""
    text = f"{value:.4g}"
    return "0" if text in ("-0", "0") else text


def _tidy(ax: Any, axis: str, values: list[float]) -> None:
    from matplotlib.ticker import FuncFormatter

    if (limits := flat_range(values)) is not None:
        (ax.set_ylim if axis == "y" else ax.set_xlim)(*limits)
    (ax.yaxis if axis == "y" else ax.xaxis).set_major_formatter(FuncFormatter(tick))


def _safe(name: str) -> str:
    return "".join(c if c.isalnum() or c in "_-" else "_" for c in name)


def _histograms(spec: StudySpec, rows: list[dict[str, Any]], metrics: list[str], path: Path) -> Path:
    fig, axes = _figure(len(metrics))
    for ax, metric in zip(axes, metrics, strict=True):
        factor, _ = _unit(metric)
        values = np.array([v * factor for r in rows if (v := _number(r.get(metric))) is not None])
        bins: Any = "auto" if flat_range(values.tolist()) is None else 1
        ax.hist(values, bins=bins, color="#4c72b0", edgecolor="white")
        ax.set_xlabel(_label(metric))
        ax.set_ylabel("points")
        _tidy(ax, "x", values.tolist())
    return _save(fig, path, f"{spec.name}: {len(rows)} points")


def _versus(spec: StudySpec, rows: list[dict[str, Any]], metrics: list[str], column: str, path: Path,
            scatter: bool) -> Path:
    fig, axes = _figure(len(metrics))
    for ax, metric in zip(axes, metrics, strict=True):
        factor, _ = _unit(metric)
        pairs = [(x, y * factor) for r in rows
                 if (x := _number(r.get(column))) is not None and (y := _number(r.get(metric))) is not None]
        if not pairs:
            text = [(str(r.get(column)), _number(r.get(metric))) for r in rows]
            labels = [t for t, y in text if y is not None]
            ax.bar(range(len(labels)), [y * factor for _, y in text if y is not None], color="#4c72b0")
            ax.set_xticks(range(len(labels)), labels, rotation=30, ha="right")
        elif scatter:
            ax.scatter([x for x, _ in pairs], [y for _, y in pairs], s=8, alpha=0.6, color="#4c72b0")
        else:
            by_x: dict[float, list[float]] = defaultdict(list)
            for x, y in pairs:
                by_x[x].append(y)
            xs = sorted(by_x)
            ax.plot(xs, [np.mean(by_x[x]) for x in xs], "o-", color="#4c72b0")
        ax.set_xlabel(column)
        ax.set_ylabel(_label(metric))
        if pairs:
            _tidy(ax, "y", [y for _, y in pairs])
    return _save(fig, path, f"{spec.name}: metrics vs {column}")


def _boxes(spec: StudySpec, rows: list[dict[str, Any]], metrics: list[str], column: str, path: Path) -> Path:
    fig, axes = _figure(len(metrics))
    groups = sorted({str(r.get(column)) for r in rows})
    for ax, metric in zip(axes, metrics, strict=True):
        factor, _ = _unit(metric)
        data = [[v * factor for r in rows if str(r.get(column)) == g and (v := _number(r.get(metric))) is not None]
                for g in groups]
        ax.boxplot(data, tick_labels=groups)
        ax.set_xlabel(column)
        ax.set_ylabel(_label(metric))
    return _save(fig, path, f"{spec.name}: metrics by {column}")


def _heatmap(spec: StudySpec, rows: list[dict[str, Any]], metric: str, xcol: str, ycol: str, path: Path) -> Path:
    fig, (ax,) = _figure(1)
    fig.set_size_inches(6.4, 4.8)
    factor, _ = _unit(metric)
    xs = sorted({r.get(xcol) for r in rows}, key=_sort_key)
    ys = sorted({r.get(ycol) for r in rows}, key=_sort_key)
    grid = np.full((len(ys), len(xs)), np.nan)
    for r in rows:
        v = _number(r.get(metric))
        if v is not None:
            grid[ys.index(r.get(ycol)), xs.index(r.get(xcol))] = v * factor
    image = ax.imshow(grid, origin="lower", aspect="auto", cmap="viridis")
    ax.set_xticks(range(len(xs)), [str(x) for x in xs], rotation=30, ha="right")
    ax.set_yticks(range(len(ys)), [str(y) for y in ys])
    ax.set_xlabel(xcol)
    ax.set_ylabel(ycol)
    for (i, j), v in np.ndenumerate(grid):
        if np.isfinite(v):
            ax.text(j, i, f"{v:.3g}", ha="center", va="center", color="white", fontsize=7)
    fig.colorbar(image, ax=ax, label=_label(metric))
    return _save(fig, path, f"{spec.name}: {metric}")


def _sort_key(v: Any) -> tuple[int, Any]:
    return (0, v) if _number(v) is not None else (1, str(v))
