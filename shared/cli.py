"""The ``cdpr`` command. Results go to stdout as JSON (so other tools can read them), logs to stderr.

An invalid file or argument prints one line ``cdpr: error: …`` on stderr and exits with code 2.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from typing import Any, NoReturn

import click
import numpy as np

from cdpr.errors import InputError


def _fail(message: str) -> NoReturn:
    click.echo(f"cdpr: error: {message}", err=True)
    sys.exit(2)


def _emit(obj: Any) -> None:
    click.echo(json.dumps(obj))


class _Group(click.Group):
    """Turns InputError anywhere below into one line and exit code 2."""

    def invoke(self, ctx: click.Context) -> Any:
        try:
            return super().invoke(ctx)
        except InputError as exc:
            _fail(str(exc))


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="cdpr")
def cli() -> None:
    """cdpr: a networked simulator for cable-driven parallel robots.

    Physics on DART, services talking over Zenoh, everything logged to Rerun.
    """


# ------------------------------------------------------------------------------------------------
# Robot tools


@cli.command()
@click.argument("robot", required=False)
def robots(robot: str | None) -> None:
    """List the shipped robots, or print the summary of ROBOT (a name or a YAML path)."""
    from cdpr.robot import load_robot, shipped_robots

    if robot is None:
        out = []
        for name in shipped_robots():
            r = load_robot(name)
            out.append({"name": name, "mode": r.mode, "cables": r.m, "mass": r.mass, "description": r.description})
        _emit(out)
    else:
        _emit(load_robot(robot).summary())


def _pose(values: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    from cdpr.rotation import rpy_to_matrix

    if len(values) not in (3, 6):
        raise InputError(f"--pose: expected X Y Z [ROLL PITCH YAW], got {len(values)} number(s)")
    if not np.all(np.isfinite(values)):
        raise InputError("--pose: every number must be finite")
    rpy = values[3:] if len(values) == 6 else (0.0, 0.0, 0.0)
    return np.array(values[:3]), rpy_to_matrix(*rpy)


@cli.command(context_settings={"ignore_unknown_options": True, "allow_extra_args": True})
@click.argument("robot")
@click.pass_context
def ik(ctx: click.Context, robot: str) -> None:
    """Inverse kinematics of ROBOT at --pose X Y Z [ROLL PITCH YAW]."""
    from cdpr.kinematics import inverse_kinematics
    from cdpr.robot import load_robot

    groups = _split_numbers(list(ctx.args), ("--pose",))
    if "--pose" not in groups:
        raise InputError("--pose X Y Z [ROLL PITCH YAW] is required")
    r = load_robot(robot)
    position, R = _pose(_numbers("--pose", tuple(groups["--pose"])))
    k = inverse_kinematics(r, position, R)
    _emit({"lengths": k.lengths.tolist(), "directions": k.directions.tolist(), "wrench_matrix": k.wrench_matrix.tolist()})


def _numbers(flag: str, raw: tuple[Any, ...]) -> tuple[float, ...]:
    out = []
    for x in raw:
        try:
            out.append(float(x))
        except ValueError:
            raise InputError(f"{flag}: {x!r} is not a number") from None
    return tuple(out)


def _split_numbers(args: list[str], flags: tuple[str, ...]) -> dict[str, list[str]]:
    """Numbers after --pose / --wrench (which take several values) are collected here."""
    groups: dict[str, list[str]] = {}
    current: str | None = None
    for a in args:
        if a in flags:
            current = a
            groups[a] = []
        elif current is not None:
            groups[current].append(a)
        else:
            raise InputError(f"unexpected argument {a!r}")
    return groups


@cli.command(context_settings={"ignore_unknown_options": True, "allow_extra_args": True})
@click.argument("robot")
@click.option("--static", "static", is_flag=True, help="tensions that hold the platform (plus payload) at rest")
@click.option("--payload", type=float, default=0.0, show_default=True, help="kg rigidly attached at the centre of mass")
@click.option("--method", default="qp", show_default=True, help="qp | closed-form | improved-closed-form | continuity")
@click.option("--tmin", type=float, default=None, help="N (default: the robot's)")
@click.option("--tmax", type=float, default=None, help="N (default: the robot's)")
@click.pass_context
def tda(ctx: click.Context, robot: str, static: bool, payload: float, method: str, tmin: float | None, tmax: float | None) -> None:
    """Tension distribution of ROBOT at --pose X Y Z [R P Y], for --static or --wrench FX FY FZ MX MY MZ."""
    from cdpr.dynamics import gravity_wrench
    from cdpr.kinematics import inverse_kinematics
    from cdpr.robot import load_robot
    from cdpr.tda import METHODS, make_tda

    groups = _split_numbers(list(ctx.args), ("--pose", "--wrench"))
    if "--pose" not in groups:
        raise InputError("--pose X Y Z [ROLL PITCH YAW] is required")
    if static == ("--wrench" in groups):
        raise InputError("give exactly one of --static or --wrench FX FY FZ MX MY MZ")
    if method not in METHODS:
        raise InputError(f"--method: unknown method {method!r} (known: {', '.join(sorted(METHODS))})")
    r = load_robot(robot).with_payload(payload)
    lo = r.tmin if tmin is None else tmin
    hi = r.tmax if tmax is None else tmax
    if not (np.isfinite(lo) and np.isfinite(hi)) or lo < 0 or lo > hi:
        raise InputError(f"--tmin/--tmax: need 0 <= tmin <= tmax, got {lo} and {hi}")
    position, R = _pose(_numbers("--pose", tuple(groups["--pose"])))
    rows = list(r.controlled_rows)
    W = inverse_kinematics(r, position, R).wrench_matrix[rows]
    if static:
        w = -gravity_wrench(r)
        w = w if r.mode == "point_mass" else w[rows]
    else:
        wrench = np.array(_numbers("--wrench", tuple(groups["--wrench"])))
        if wrench.shape != (6,) or not np.all(np.isfinite(wrench)):
            raise InputError("--wrench: expected 6 finite numbers FX FY FZ MX MY MZ")
        w = wrench[rows]
    result = make_tda(method).solve(W, w, lo, hi)
    _emit(
        {
            "tensions": result.tensions.tolist(),
            "feasible": result.feasible,
            "residual": result.residual,
            "method": result.method,
            "status": result.status,
        }
    )


# ------------------------------------------------------------------------------------------------
# Running sessions


def _scenario_options(f: Callable[..., Any]) -> Callable[..., Any]:
    f = click.option("--duration", type=float, default=None, help="override the scenario's duration (s)")(f)
    f = click.option("--session", "session_id", default="default", show_default=True, help="session id")(f)
    return click.argument("scenario")(f)


def _zenoh_options(f: Callable[..., Any]) -> Callable[..., Any]:
    f = click.option("--connect-timeout", type=click.FloatRange(min=0.1), default=30.0, show_default=True,
                     help="seconds a client keeps trying to reach --connect endpoints")(f)
    f = click.option("--zenoh-config", type=click.Path(), default=None, help="Zenoh JSON5 config file (or $ZENOH_CONFIG)")(f)
    f = click.option("--listen", multiple=True, help="Zenoh endpoint to listen on, e.g. tcp/0.0.0.0:7447")(f)
    f = click.option("--connect", multiple=True, help="Zenoh endpoint to connect to, e.g. tcp/192.168.1.10:7447")(f)
    return click.option("--zenoh-mode", type=click.Choice(["peer", "client"]), default="peer", show_default=True)(f)


def _rt_option(f: Callable[..., Any]) -> Callable[..., Any]:
    return click.option("--rt-priority", type=int, default=None, metavar="1-99",
                        help="run under SCHED_FIFO at this priority (realtime mode on a busy machine; "
                             "needs CAP_SYS_NICE)")(f)


def _load(scenario: str, duration: float | None) -> Any:
    from cdpr.scenario import load_scenario

    if duration is not None and not (np.isfinite(duration) and duration > 0):
        raise InputError(f"--duration: must be a positive number of seconds, got {duration}")
    return load_scenario(scenario, {"duration": duration})


def _serve(name: str, scenario: str, session_id: str, duration: float | None, zenoh_mode: str,
           connect: tuple[str, ...], listen: tuple[str, ...], zenoh_config: str | None, connect_timeout: float,
           rt_priority: int | None = None, **extra: Any) -> None:
    from cdpr.protocol import Keys
    from cdpr.service import serve, set_realtime_priority
    from cdpr.transport import zenoh_config as make_config

    sc = _load(scenario, duration)
    if rt_priority is not None:
        set_realtime_priority(rt_priority)  # before Zenoh's threads exist: they inherit it
    try:
        keys = Keys(session_id)
    except ValueError as exc:
        raise InputError(f"--session: {exc}") from None
    conf = make_config(zenoh_mode, connect, listen, zenoh_config, connect_timeout)
    if name == "sim":
        from cdpr_sim.node import SimNode

        node: Any = SimNode(sc, keys)
    elif name == "trajectory":
        from cdpr_trajectory.node import TrajectoryNode

        node = TrajectoryNode(sc, keys)
    elif name == "controller":
        from cdpr_controller.node import ControllerNode

        node = ControllerNode(sc, keys)
    elif name == "clock":
        from cdpr_clock.node import ClockNode

        node = ClockNode(sc, keys, expected=extra["expect"], realtime=extra["mode"] == "realtime",
                         lookahead=extra["lookahead"], resend_after=extra["resend_after"])
    elif name == "recorder":
        from cdpr_recorder.node import RecorderNode

        node = RecorderNode(sc, keys, rrd=extra["rrd"], spawn=extra["spawn"], viewer=extra["connect_viewer"])
    else:  # pragma: no cover - the commands below are the only callers
        raise AssertionError(name)
    sys.exit(serve(node, conf))


@cli.command()
@_scenario_options
@_zenoh_options
@_rt_option
def sim(**kw: Any) -> None:
    """Run the sim service (DART physics) for SCENARIO."""
    _serve("sim", **kw)


@cli.command()
@_scenario_options
@_zenoh_options
@_rt_option
def trajectory(**kw: Any) -> None:
    """Run the trajectory service for SCENARIO."""
    _serve("trajectory", **kw)


@cli.command()
@_scenario_options
@_zenoh_options
@_rt_option
def controller(**kw: Any) -> None:
    """Run the controller service (feedback linearisation + tension distribution) for SCENARIO."""
    _serve("controller", **kw)


@cli.command()
@_scenario_options
@_zenoh_options
@_rt_option
@click.option("--mode", type=click.Choice(["fast", "realtime"]), default="fast", show_default=True)
@click.option("--expect", default="sim,trajectory,controller", show_default=True,
              help="comma-separated participants to wait for")
@click.option("--lookahead", type=click.IntRange(0, 8), default=1, show_default=True,
              help="ticks issued ahead of the sim (0: strict one-step handshake)")
@click.option("--resend-after", type=click.FloatRange(min=0.01), default=1.0, show_default=True,
              help="seconds without progress before the pending ticks are repeated")
def clock(expect: str, **kw: Any) -> None:
    """Run the lock-step clock for SCENARIO."""
    from cdpr.protocol import SERVICES

    names = tuple(s.strip() for s in expect.split(",") if s.strip())
    unknown = [n for n in names if n not in SERVICES or n == "clock"]
    if unknown:
        raise InputError(f"--expect: unknown participant(s) {', '.join(unknown)}")
    _serve("clock", expect=names, **kw)


@cli.command()
@_scenario_options
@_zenoh_options
@click.option("--rrd", type=click.Path(), default=None, help="write the recording to this .rrd file")
@click.option("--spawn", is_flag=True, help="also stream to a new Rerun viewer")
@click.option("--connect-viewer", default=None, help="also stream to the Rerun viewer at this gRPC URL")
def recorder(**kw: Any) -> None:
    """Run the recorder: subscribes to the whole session and logs it to Rerun."""
    _serve("recorder", **kw)


def _run_options(f: Callable[..., Any]) -> Callable[..., Any]:
    f = click.option("--summary", type=click.Path(), default=None, help="also write the JSON summary here")(f)
    f = click.option("--connect-viewer", default=None, help="stream the recording to this Rerun viewer URL")(f)
    f = click.option("--spawn", is_flag=True, help="stream the recording to a new Rerun viewer")(f)
    f = click.option("--rrd", type=click.Path(), default=None, help="write the recording to this .rrd file")(f)
    f = click.option("--mode", type=click.Choice(["fast", "realtime"]), default="fast", show_default=True)(f)
    f = _rt_option(f)
    return _scenario_options(f)


@cli.command()
@_run_options
@click.option("--quiet", is_flag=True, help="no progress line")
def run(**kw: Any) -> None:
    """Run SCENARIO end to end: every service as a child process on a private loopback network.

    Prints a JSON summary as the last line of stdout.
    """
    from cdpr.launch import run_session

    sys.exit(run_session(_load(kw.pop("scenario"), kw.pop("duration")), **kw))


@cli.command()
@_run_options
@click.option("--without", "without", multiple=True, type=click.Choice(["controller", "trajectory", "sim"]),
              help="a participant that will join from elsewhere")
@click.option("--listen", "listen", multiple=True, help="endpoint where remote participants connect (default tcp/127.0.0.1:7447)")
@click.option("--join-timeout", type=float, default=None, help="give up if a participant has not joined after this many seconds")
@click.option("--quiet", is_flag=True, help="no progress line")
def up(**kw: Any) -> None:
    """Run the services of SCENARIO except --without ones, and wait for those to join over Zenoh."""
    from cdpr.launch import run_session

    sys.exit(run_session(_load(kw.pop("scenario"), kw.pop("duration")), **kw))


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

    from cdpr.launch import free_port
    from cdpr.recording import viewer_command, web_viewer_url

    if not Path(file).is_file():
        raise InputError(f"{file}: no such file")
    web_port, grpc_port = (port or free_port(), free_port()) if web else (0, 0)
    proc = subprocess.Popen(viewer_command(file, web=web, web_port=web_port, grpc_port=grpc_port, bind=bind))

    def forward(signum: int, _frame: Any) -> None:  # the viewer stops with us
        proc.send_signal(signum)

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, forward)
    if web:
        _emit({"url": web_viewer_url(web_port, grpc_port), "file": file})
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
    from cdpr.recording import show_robot
    from cdpr.robot import load_robot

    _emit(show_robot(load_robot(robot), rrd=rrd, viewer=connect_viewer))


@cli.command()
@click.argument("file", type=click.Path())
@click.option("-o", "--out", "out_dir", type=click.Path(), default=None,
              help="output directory (default: FILE's name + _report, beside it)")
def report(file: str, out_dir: str | None) -> None:
    """Plot the recording FILE.rrd in the paper's four-panel layout and write summary.json."""
    from cdpr.report import write_report

    _emit(write_report(file, out_dir))


@cli.command()
@click.option("--minutes", type=click.FloatRange(min=0.01), default=10.0, show_default=True)
@click.option("--scenario", default="caroca_15kg", show_default=True)
@click.option("--duration", type=click.FloatRange(min=0.1), default=3.0, show_default=True, help="seconds of sim time per round")
@click.option("--seed", type=int, default=0, show_default=True)
def soak(minutes: float, scenario: str, duration: float, seed: int) -> None:
    """Loop sessions with random controller kills and payload noise; report lost or doubled steps."""
    from cdpr.scenario import load_scenario
    from cdpr.soak import run_soak

    load_scenario(scenario)  # fail early, with one line, on a bad scenario
    sys.exit(run_soak(scenario, minutes, duration, seed))


# ------------------------------------------------------------------------------------------------
# Standalone Zenoh router (docker compose, remote participants)


@cli.command()
@click.option("--listen", multiple=True,
              help="endpoint to listen on (default tcp/0.0.0.0:7447 unless in the config)")
@click.option("--connect", multiple=True,
              help="another router to join, e.g. a session's (router-to-router link)")
@click.option("--zenoh-config", type=click.Path(), default=None,
              help="Zenoh JSON5 config file (or $ZENOH_CONFIG): TLS, user/password, access control")
def router(listen: tuple[str, ...], connect: tuple[str, ...], zenoh_config: str | None) -> None:
    """Run a standalone Zenoh router that sessions' services connect to, until SIGINT/SIGTERM."""
    import os
    import time

    from cdpr.transport import StopFlag, log, open_session
    from cdpr.transport import zenoh_config as make_config

    config_file = zenoh_config or os.environ.get("ZENOH_CONFIG")
    if not listen and not config_file:
        listen = ("tcp/0.0.0.0:7447",)
    conf = make_config("router", connect=connect, listen=listen, config_file=config_file)
    stop = StopFlag().install()
    with open_session(conf, "router") as session:
        where = ", ".join(listen) if listen else f"the endpoints of {config_file}"
        log("router", f"Zenoh router {session.zid()} listening on {where}")
        while not stop:
            time.sleep(0.1)
    log("router", "stopped")


@cli.command()
@click.option("--docs", type=click.Path(), default="docs", show_default=True, help="where results.md and its figures go")
@click.option("--runs", type=click.Path(), default="runs/experiments", show_default=True, help="where the recordings go")
@click.option("--duration", type=float, default=None, help="cut every scenario to this many seconds (quick check)")
@click.option("--only", multiple=True, help="run only these scenarios")
def experiments(docs: str, runs: str, duration: float | None, only: tuple[str, ...]) -> None:
    """Re-run the paper's experiments through the distributed loop and regenerate docs/results.md."""
    from pathlib import Path

    from cdpr.experiments import run_experiments

    sys.exit(run_experiments(Path(docs), Path(runs), duration, only))


# ------------------------------------------------------------------------------------------------
# Workspace and SDF export (docs/workspace.md)


@cli.command()
@click.argument("robot")
@click.option("--payload", type=float, default=0.0, show_default=True,
              help="kg rigidly attached at the centre of mass")
@click.option("--mass", type=float, default=None,
              help="whole platform mass, kg (solid-shape inertia), as a scenario's platform.mass")
@click.option("--step", type=float, default=0.1, show_default=True, help="grid spacing, m (at most)")
@click.option("--orientation", type=float, nargs=3, default=(0.0, 0.0, 0.0), show_default=True,
              help="fixed platform orientation: roll pitch yaw, rad")
@click.option("--tmin", type=float, default=None, help="N (default: the robot's)")
@click.option("--tmax", type=float, default=None, help="N (default: the robot's)")
@click.option("--rrd", type=click.Path(), default=None, help="write the points to this .rrd file")
@click.option("--spawn", is_flag=True, help="show the points in a new Rerun viewer")
def workspace(robot: str, payload: float, mass: float | None, step: float,
              orientation: tuple[float, float, float], tmin: float | None, tmax: float | None,
              rrd: str | None, spawn: bool) -> None:
    """Static wrench-feasible workspace of ROBOT on a grid over its frame box (JSON; points to Rerun)."""
    import time

    from cdpr.robot import load_robot
    from cdpr.rotation import rpy_to_matrix
    from cdpr.workspace import compute_workspace, record_workspace

    r = load_robot(robot)
    r = (r if mass is None else r.with_mass(mass)).with_payload(payload)
    lo, hi = (r.tmin if tmin is None else tmin), (r.tmax if tmax is None else tmax)
    if not (np.isfinite(lo) and np.isfinite(hi)) or lo < 0 or lo > hi:
        raise InputError(f"--tmin/--tmax: need 0 <= tmin <= tmax, got {lo} and {hi}")
    if not (np.isfinite(step) and step > 0):
        raise InputError(f"--step: must be a positive length in m, got {step}")
    if not np.all(np.isfinite(orientation)):
        raise InputError("--orientation: roll, pitch and yaw must be finite")
    R = rpy_to_matrix(*orientation)
    start = time.perf_counter()
    ws = compute_workspace(r, step, R, 0.0, lo, hi)
    seconds = time.perf_counter() - start
    box = ws.bounding_box()
    out: dict[str, Any] = {
        "robot": r.name, "mass": r.mass, "payload": payload, "tmin": lo, "tmax": hi,
        "orientation_rpy": list(orientation), "step": step, "spacing": ws.spacing.tolist(),
        "grid": list(ws.shape),
        "points": int(ws.points.shape[0]), "feasible": int(ws.feasible.sum()), "fraction": ws.fraction,
        "bounding_box": None if box is None else {"min": box[0].tolist(), "max": box[1].tolist()},
        "seconds": seconds, "us_per_point": 1e6 * seconds / max(1, ws.points.shape[0]), "rrd": rrd,
    }
    if rrd is not None or spawn:
        info = {"workspace": dict(out), "robot": r.summary()}
        out["problems"] = record_workspace(r, ws, R, rrd=rrd, spawn=spawn, info=info)
    _emit(out)


@cli.command("export-sdf")
@click.argument("robot")
@click.option("-o", "--output", default=None,
              help="SDF file to write (default: ROBOT's name + .sdf; - for stdout)")
@click.option("--tree", is_flag=True,
              help="leave out the ball joints that close the loops (for tree-only parsers)")
def export_sdf(robot: str, output: str | None, tree: bool) -> None:
    """Write ROBOT as an SDF 1.6 world: frame, platform, a U-P-S leg per cable (the seed paper's model)."""
    import xml.etree.ElementTree as ET

    from cdpr.robot import load_robot
    from cdpr.sdf import sdf_string

    r = load_robot(robot)
    text = sdf_string(r, close_loops=not tree)
    if output == "-":
        click.echo(text, nl=False)
        return
    path = output or f"{r.name}.sdf"
    try:
        with open(path, "w") as fh:
            fh.write(text)
    except OSError as exc:
        raise InputError(f"-o: cannot write {path}: {exc.strerror or exc}") from None
    model = ET.fromstring(text).find("world/model")
    assert model is not None
    joints = model.findall("joint")
    _emit({"robot": r.name, "file": path, "links": len(model.findall("link")), "joints": len(joints),
           "ball_joints": sum(j.get("type") == "ball" for j in joints)})


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

    from cdpr.bench import FULL, QUICK, run_bench, table
    from cdpr.scenario import load_scenario

    load_scenario(scenario)  # fail early, with one line, on a bad scenario
    click.echo(table(run_bench(QUICK if quick else FULL, scenario, Path(out))))


def main(argv: list[str] | None = None) -> None:
    try:
        cli.main(args=argv, prog_name="cdpr", standalone_mode=True)
    except InputError as exc:  # raised outside a command's invoke (e.g. in a callback)
        _fail(str(exc))


def service_main(name: str) -> None:
    """Entry of ``python -m cdpr_<name>``: the same as ``cdpr <name>``."""
    main([name, *sys.argv[1:]])
