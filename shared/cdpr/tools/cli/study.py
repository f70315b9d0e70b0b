"""``cdpr study|tune|study-bench``: parameter studies and gain tuning on Ray (the ``study`` extra)."""

from __future__ import annotations

from pathlib import Path

import click

from cdpr.tools.cli.group import cli, emit

_MODES = click.Choice(["auto", "in-process", "multi-process"])


@cli.command()
@click.argument("study_file", metavar="STUDY.yaml", type=click.Path())
@click.option("--out", type=click.Path(), default=None, help="results folder (default runs/studies/NAME)")
@click.option("--address", default=None,
              help="Ray cluster to run on (default $RAY_ADDRESS, else a local Ray on this machine)")
@click.option("--mode", type=_MODES, default=None, help="how each point's session runs (default: the study's)")
@click.option("--record/--no-record", default=None, help="keep each point's .rrd recording (default: the study's)")
@click.option("--quiet", is_flag=True, help="no progress bar")
def study(study_file: str, out: str | None, address: str | None, mode: str | None, record: bool | None,
          quiet: bool) -> None:
    """Run the parameter study STUDY.yaml: every point one session, as one Ray task.

    Writes the table (results.csv, results.parquet), plots and per-point files to one folder; a re-run
    resumes (finished points are not run again). Prints a JSON summary as the last line of stdout.
    """
    from cdpr.tools.study.engine import need_ray, run_study

    need_ray()
    emit(run_study(study_file, Path(out) if out else None, address, mode, record, progress=not quiet))


@cli.command()
@click.argument("study_file", metavar="STUDY.yaml", type=click.Path())
@click.option("--out", type=click.Path(), default=None, help="results folder (default runs/tune/NAME)")
@click.option("--address", default=None,
              help="Ray cluster to run on (default $RAY_ADDRESS, else a local Ray on this machine)")
@click.option("--trials", type=click.IntRange(1), default=None, help="override the study's tune.trials")
@click.option("--mode", type=_MODES, default=None, help="how each trial's session runs (default: the study's)")
@click.option("--quiet", is_flag=True, help="no progress bar")
def tune(study_file: str, out: str | None, address: str | None, trials: int | None, mode: str | None,
         quiet: bool) -> None:
    """Search STUDY.yaml's parameters (Optuna through Ray Tune) for its tune.metric under its constraints.

    Writes trials.csv/.parquet, plots and best.yaml (the best trial as a ready-to-run scenario).
    """
    from cdpr.tools.study.engine import need_ray
    from cdpr.tools.study.tune import run_tune

    need_ray()
    emit(run_tune(study_file, Path(out) if out else None, address, trials, mode, progress=not quiet))


@cli.command("study-bench")
@click.option("--points", type=click.IntRange(1), default=8, show_default=True, help="sessions")
@click.option("--duration", type=click.FloatRange(min=0.001), default=4.0, show_default=True,
              help="simulated seconds per session")
@click.option("--mode", type=_MODES, default="auto", show_default=True)
@click.option("--repeats", type=click.IntRange(1), default=1, show_default=True,
              help="alternate the two phases this many times (medians: fairer on a shared machine)")
def study_bench(points: int, duration: float, mode: str, repeats: int) -> None:
    """Aggregate steps/s of a study against the same sessions run one at a time (JSON on stdout)."""
    from cdpr.tools.study.bench import study_throughput

    emit(study_throughput(points, duration, mode, progress=True, repeats=repeats))
