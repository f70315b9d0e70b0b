"""``cdpr replay|show|report|experiments|bench``: recordings, results and benchmarks."""

from __future__ import annotations

import sys
from typing import Any

import click

from cdpr.errors import InputError
from cdpr.tools.cli.group import cli, emit

# ------------------------------------------------------------------------------------------------
# Recordings (Rerun): replay, show, report


@cli.command()
@click.argument("file", type=click.Path())
@click.option("--web", is_flag=True, help="serve the web viewer instead of opening the native one")
@click.option("--port", type=click.IntRange(0, 65535), default=0, show_default=True,
              help="web viewer HTTP port with --web (0: a free one)")
@click.option("--bind", default="127.0.0.1", show_default=True,
              help="address the web viewer listens on with --web (0.0.0.0 to reach it from another machine)")
def replay(file: str, web: bool, port: int, bind: str) -> None:
    """Open the recording FILE.rrd in the Rerun viewer (with --web: serve it and print the URL)."""
    import signal
    import subprocess
    from pathlib import Path

    from cdpr.recording import viewer_command, web_viewer_url
    from cdpr.tools.launch import free_port

    if not Path(file).is_file():
        raise InputError(f"{file}: no such file")
    web_port, grpc_port = (port or free_port(), free_port()) if web else (0, 0)
    proc = subprocess.Popen(viewer_command(file, web=web, web_port=web_port, grpc_port=grpc_port, bind=bind))

    def forward(signum: int, _frame: Any) -> None:  # the viewer stops with us
        proc.send_signal(signum)

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, forward)
    if web:
        emit({"url": web_viewer_url(web_port, grpc_port), "file": file})
        sys.stdout.flush()
        click.echo("serving the web viewer; Ctrl-C to stop", err=True)
    code = proc.wait()
    sys.exit(code if code >= 0 else 128 - code)


@cli.command()
@click.argument("robot")
@click.option("--rrd", type=click.Path(), default=None, help="write to this .rrd file (else: spawn a viewer)")
@click.option("--connect-viewer", default=None, help="stream to the Rerun viewer at this gRPC URL")
def show(robot: str, rrd: str | None, connect_viewer: str | None) -> None:
    """Draw ROBOT (a name or a YAML path) at its home pose: frame, numbered anchors, platform, cables."""
    from cdpr.config.robot import load_robot
    from cdpr.recording import show_robot

    emit(show_robot(load_robot(robot), rrd=rrd, viewer=connect_viewer))


@cli.command()
@click.argument("file", type=click.Path())
@click.option("-o", "--out", "out_dir", type=click.Path(), default=None,
              help="output directory (default: FILE's name + _report, beside it)")
def report(file: str, out_dir: str | None) -> None:
    """Plot the recording FILE.rrd in the paper's four-panel layout and write summary.json."""
    from cdpr.tools.report import write_report

    emit(write_report(file, out_dir))


@cli.command()
@click.option("--minutes", type=click.FloatRange(min=0.01), default=10.0, show_default=True)
@click.option("--scenario", default="caroca_15kg", show_default=True)
@click.option("--duration", type=click.FloatRange(min=0.1), default=3.0, show_default=True,
              help="seconds of sim time per round")
@click.option("--seed", type=int, default=0, show_default=True)
def soak(minutes: float, scenario: str, duration: float, seed: int) -> None:
    """Loop sessions with random controller kills and payload noise; report lost or doubled steps."""
    from cdpr.config.scenario import load_scenario
    from cdpr.tools.soak import run_soak

    load_scenario(scenario)  # fail early, with one line, on a bad scenario
    sys.exit(run_soak(scenario, minutes, duration, seed))


# ------------------------------------------------------------------------------------------------
# Performance


@cli.command()
@click.option("--quick", is_flag=True, help="every part, shorter (under two minutes)")
@click.option("--out", type=click.Path(dir_okay=False), default="bench.json", show_default=True,
              help="where the JSON results go")
@click.option("--scenario", default="caroca_15kg", show_default=True, help="scenario of the loop figures")
def bench(quick: bool, out: str, scenario: str) -> None:
    """Measure the loop: monolithic ceiling, distributed loop, Zenoh round trip, realtime ticks, TDA
    solve times, scaling with sessions and cables. Prints a table; writes every figure to --out."""
    from pathlib import Path

    from cdpr.config.scenario import load_scenario
    from cdpr.tools.bench import FULL, QUICK, run_bench, table

    load_scenario(scenario)  # fail early, with one line, on a bad scenario
    click.echo(table(run_bench(QUICK if quick else FULL, scenario, Path(out))))
