"""``cdpr run|up|sim|trajectory|controller|clock|recorder|router|acl|ping|delay-proxy|soak``: sessions and their
nodes."""

from __future__ import annotations

import os
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any, NoReturn

import click
import numpy as np

from cdpr.errors import InputError
from cdpr.protocol.wiring import WIRING
from cdpr.runtime.options import REALTIME_OPTIONS, RECORDER_OPTIONS, SESSION_OPTIONS
from cdpr.tools.cli.group import cli, click_options, emit

# ------------------------------------------------------------------------------------------------
# Running sessions


def _scenario_options(f: Callable[..., Any]) -> Callable[..., Any]:
    return click.argument("scenario")(click_options(SESSION_OPTIONS)(f))


def _rt_option(f: Callable[..., Any]) -> Callable[..., Any]:
    return click_options(REALTIME_OPTIONS)(f)


def _load(scenario: str, duration: float | None) -> Any:
    from cdpr.config.scenario import load_scenario

    if duration is not None and not (np.isfinite(duration) and duration > 0):
        raise InputError(f"--duration: must be a positive number of seconds, got {duration}")
    return load_scenario(scenario, {"duration": duration})


def _node_command(name: str, help_text: str) -> None:
    """``cdpr NAME ARGS``: the same as ``python -m cdpr_NAME ARGS`` (options in :mod:`cdpr.runtime.main`)."""

    @cli.command(name, help=help_text, add_help_option=False,
                 context_settings={"ignore_unknown_options": True, "allow_extra_args": True})
    @click.argument("args", nargs=-1, type=click.UNPROCESSED)
    def command(args: tuple[str, ...]) -> None:
        from cdpr.runtime.main import node_main

        node_main(name, args)


_node_command("sim", "Run the sim service (DART physics) for SCENARIO (--help for its options).")
_node_command("trajectory", "Run the trajectory service for SCENARIO (--help for its options).")
_node_command("controller",
              "Run the controller service (feedback linearisation + tension distribution) for SCENARIO.")
_node_command("clock", "Run the lock-step clock for SCENARIO (--help for its options).")
_node_command("recorder", "Run the recorder: subscribes to the whole session and logs it to Rerun, MCAP, Foxglove.")
_node_command("ros2", "Run the ros2 node: the session on ROS 2's wire (rmw_zenoh), a ROS 2 controller in the loop "
              "(docs/ros2.md).")


def _run_options(f: Callable[..., Any]) -> Callable[..., Any]:
    f = click.option("--summary", type=click.Path(), default=None, help="also write the JSON summary here")(f)
    f = click_options(RECORDER_OPTIONS)(f)
    f = click.option("--max-lateness", type=float, default=None, metavar="S",
                     help="realtime: end the session (aborted) once a step is S seconds behind the wall clock")(f)
    f = click.option("--sync", type=click.Choice(["lock", "free"]), default="lock", show_default=True,
                     help="realtime: lock-step (each step waits for its command) or free-running (the sim keeps "
                          "the wall clock, a late command acts late: docs/realtime.md)")(f)
    f = click.option("--mode", type=click.Choice(["fast", "realtime"]), default="fast", show_default=True)(f)
    f = _rt_option(f)
    return _scenario_options(f)


@cli.command()
@_run_options
@click.option("--quiet", is_flag=True, help="no progress line")
@click.option("--in-process", is_flag=True,
              help="every node in this process on one private Zenoh session (composition): same nodes, "
                   "same messages, no process start-up")
@click.option("--policy", default=None, metavar="POLICY",
              help="a trained policy is the controller: a Stable-Baselines3 model (*.zip) or module:function, "
                   "acting through cdpr/Track-v0 in session mode (docs/learning.md)")
@click.option("--policy-action", type=click.Choice(["residual", "wrench", "tensions"]), default=None,
              help="--policy: its action space (default: the model's .env.json, else residual)")
@click.option("--control-every", type=click.IntRange(1), default=None,
              help="--policy: sim steps per policy step (default: the model's .env.json, else 10)")
@click.option("--algo", type=click.Choice(["sac", "ppo", "td3", "a2c", "ddpg"]), default="sac", show_default=True,
              help="--policy: a model file's algorithm")
@click.option("--policy-model", default=None, metavar="SCENARIO",
              help="--policy: the scenario its environment takes as the controller's model (default: SCENARIO; "
                   "another mass, say, is a model error only the plant has)")
def run(**kw: Any) -> None:
    """Run SCENARIO end to end: every service as a child process on a private loopback network.

    Prints a JSON summary as the last line of stdout.
    """
    from cdpr.tools.launch import RunOptions, run_session

    policy, action, every, algo, model = (kw.pop(k) for k in ("policy", "policy_action", "control_every", "algo",
                                                                  "policy_model"))
    scenario = _load(kw.pop("scenario"), kw.pop("duration"))
    _check_sync(kw)
    if policy is not None:
        if kw["in_process"]:
            raise click.UsageError("--policy: the policy joins the session as its own process (no --in-process)")
        _leave(_run_policy(scenario, RunOptions(**kw), policy, action, every, algo, model), at_once=True)
    _leave(run_session(scenario, RunOptions(**kw)), at_once=not kw["in_process"])


def _run_policy(scenario: Any, opts: Any, policy: str, action: str | None, every: int | None, algo: str,
                model: str | None) -> int:
    """The session with ``policy`` as its controller: a child process (``python -m cdpr.gym.policy``) joins the
    launcher's router as any remote controller would."""
    import dataclasses
    import subprocess

    from cdpr.gym.policy import env_options, load_policy
    from cdpr.tools.launch import free_port, run_session

    load_policy(policy, algo)  # a bad policy is an error here (exit code 2), not a session waiting for it
    env_options(policy)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    given = [*(["--action", action] if action else []), *(["--control-every", str(every)] if every else [])]
    if model is not None:
        _load(model, scenario.duration)  # a bad model scenario: exit code 2 here
    child = subprocess.Popen([sys.executable, "-m", "cdpr.gym.policy", policy, "--scenario", model or scenario.source,
                              "--duration", repr(scenario.duration), *given, "--algo", algo, "--connect", endpoint,
                              "--session", opts.session_id], stdout=subprocess.DEVNULL)
    try:
        code = run_session(scenario, dataclasses.replace(opts, without=("controller",), listen=(endpoint,),
                                                         join_timeout=opts.join_timeout or 120.0))
        child_code = child.wait(timeout=60.0)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    return code if child_code == 0 or code >= 128 else max(code, 1)


def _check_sync(kw: dict[str, Any]) -> None:
    if kw["sync"] == "free" and kw["mode"] != "realtime":
        raise click.UsageError("--sync free: free-running needs --mode realtime (fast mode is lock-step)")
    if kw["max_lateness"] is not None and not kw["max_lateness"] > 0:
        raise click.UsageError(f"--max-lateness: must be a number of seconds > 0, got {kw['max_lateness']}")
    if kw["max_lateness"] is not None and kw["mode"] != "realtime":
        raise click.UsageError("--max-lateness: only realtime sessions keep the wall clock (--mode realtime)")


def _leave(code: int, at_once: bool) -> NoReturn:
    """Exit with ``code``; ``at_once``: without the interpreter's teardown (~0.1 s of freeing modules), for
    a launcher whose children have all exited (nobody left for its router to serve) and that holds no file
    sink of its own (not --in-process)."""
    if at_once:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    sys.exit(code)


@cli.command()
@_run_options
@click.option("--without", "without", multiple=True, type=click.Choice(["controller", "trajectory", "sim"]),
              help="a participant that will join from elsewhere")
@click.option("--listen", "listen", multiple=True,
              help="endpoint where remote participants connect (default tcp/127.0.0.1:7447)")
@click.option("--join-timeout", type=float, default=None,
              help="give up if a participant has not joined after this many seconds")
@click.option("--rejoin-timeout", type=float, default=None,
              help="end the session (aborted) if a participant that left has not come back after this many "
                   "seconds (the clock's --rejoin-timeout: default 60, 0 for ever)")
@click.option("--ros2", is_flag=True,
              help="also run the ros2 node (in the sim's process: sim+ros2): the session's topics on ROS 2 "
                   "(rmw_zenoh); with --without controller a ROS 2 node is the controller (docs/ros2.md)")
@click.option("--ros-namespace", default=None,
              help="--ros2: the namespace of the topics (default: /cdpr for the session default, /cdpr/<session> for "
                   "another)")
@click.option("--episodes", type=click.IntRange(0), default=1, show_default=True, metavar="N",
              help="run the session N times back to back under the same id (0: until interrupted), for a "
                   "participant that joins one after the other: a learning environment in session mode "
                   "(docs/learning.md). Recordings and summaries get _e0001, _e0002 ... before their extension")
@click.option("--quiet", is_flag=True, help="no progress line")
def up(**kw: Any) -> None:
    """Run the services of SCENARIO except --without ones, and wait for those to join over Zenoh."""
    from cdpr.runtime.transport import log
    from cdpr.tools.launch import RunOptions, run_session

    scenario = _load(kw.pop("scenario"), kw.pop("duration"))
    _check_sync(kw)
    episodes = kw.pop("episodes")
    if episodes == 1:
        # the normal exit: the router may still be forwarding the end to remote participants
        sys.exit(run_session(scenario, RunOptions(**kw)))
    worst, n = 0, 0
    while episodes == 0 or n < episodes:
        n += 1
        paths = {k: _episode_path(kw[k], n) for k in ("rrd", "mcap", "summary") if kw.get(k)}
        log("cdpr", f"episode {n}{'' if episodes == 0 else f' of {episodes}'}")
        code = run_session(scenario, RunOptions(**{**kw, **paths}))
        if code >= 128:  # interrupted: no next episode
            sys.exit(code)
        worst = max(worst, code)
    sys.exit(worst)


def _episode_path(path: str, episode: int) -> str:
    """``runs/x.rrd`` → ``runs/x_e0003.rrd``: episode 3's file."""
    p = Path(path)
    return str(p.with_name(f"{p.stem}_e{episode:04d}{p.suffix}"))


@cli.command()
@click.option("--session", "session_id", default="default", show_default=True, help="session id")
@click.option("--connect", multiple=True, help="the session's router (default tcp/127.0.0.1:7447)")
@click.option("--zenoh-config", type=click.Path(), default=None,
              help="Zenoh JSON5 config file (or $ZENOH_CONFIG): TLS, user/password")
@click.option("--node", default="sim", show_default=True, type=click.Choice(list(WIRING)),
              help="any node of the wiring table: each answers ping/<node>")
@click.option("--count", type=click.IntRange(1, 100_000), default=200, show_default=True)
@click.option("--wait", type=click.FloatRange(0.0), default=10.0, show_default=True,
              help="seconds to wait for NODE to be there (its liveliness token) before the first ping")
def ping(session_id: str, connect: tuple[str, ...], zenoh_config: str | None, node: str, count: int,
         wait: float) -> None:
    """Measure the round trip from here to a running session's NODE (where a controller would run), and
    say whether it fits the session's dt. Prints one line, then a JSON summary."""
    from cdpr.protocol import Keys
    from cdpr.runtime.transport import log, open_session
    from cdpr.runtime.transport import zenoh_config as make_config
    from cdpr.tools.ping import ping as measure

    conf = make_config("client", connect=connect or ("tcp/127.0.0.1:7447",), config_file=zenoh_config)
    with open_session(conf, "ping") as session:
        result = measure(session, Keys(session_id), node, count, wait=wait)
    log("ping", result.verdict())
    emit(result.summary())
    if not result.answered:
        sys.exit(1)


@cli.command("delay-proxy")
@click.option("--listen", "listen", required=True, help="HOST:PORT to accept connections on")
@click.option("--to", "to", required=True, help="HOST:PORT to forward them to (a Zenoh router)")
@click.option("--delay-ms", type=click.FloatRange(0.0), default=1.0, show_default=True,
              help="added to each direction")
def delay_proxy(listen: str, to: str, delay_ms: float) -> None:
    """Forward TCP connections with a delay each way: a slow link on one machine (no netem needed). Point a
    client-mode participant at it (--connect tcp/LISTEN) to see how a session copes (docs/realtime.md)."""
    from cdpr.runtime.transport import StopFlag, log
    from cdpr.tools.netdelay import DelayProxy, parse_address

    try:
        here, there = parse_address(listen), parse_address(to)
    except ValueError as exc:
        raise InputError(f"--listen/--to: {exc}") from None
    stop = StopFlag().install()
    wake = threading.Event()
    stop.on_set(wake.set)
    try:
        proxy = DelayProxy(here, there, delay_ms * 1e-3)
    except OSError as exc:
        raise InputError(f"--listen {listen}: {exc.strerror}") from None
    with proxy:
        log("delay-proxy", f"forwarding {listen} -> {to}, {delay_ms:g} ms each way")
        while not stop:
            wake.wait(0.5)


# ------------------------------------------------------------------------------------------------
# Standalone Zenoh router (docker compose, remote participants)


@cli.command()
@click.option("--listen", multiple=True,
              help="endpoint to listen on (default tcp/0.0.0.0:7447 unless in the config)")
@click.option("--connect", multiple=True,
              help="another router to join, e.g. a session's (router-to-router link)")
@click.option("--zenoh-config", type=click.Path(), default=None,
              help="Zenoh JSON5 config file (or $ZENOH_CONFIG): TLS, user/password, access control")
@click.option("--log-denials", is_flag=True,
              help="log each message its access rules drop (which identity, what, on which key) on stderr")
def router(listen: tuple[str, ...], connect: tuple[str, ...], zenoh_config: str | None, log_denials: bool) -> None:
    """Run a standalone Zenoh router that sessions' services connect to, until SIGINT/SIGTERM. Zenoh's own log
    follows $RUST_LOG."""
    import os
    import time

    import zenoh

    from cdpr.runtime.transport import DENIALS_LOG, StopFlag, log, open_session
    from cdpr.runtime.transport import zenoh_config as make_config

    if log_denials:
        zenoh.init_log_from_env_or(DENIALS_LOG)
    else:
        zenoh.try_init_log_from_env()

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
@click.option("--sessions", default="", metavar="S1,S2",
              help="sessions that get identities of their own: controller.S and ros2-controller.S may command "
                   "session S only")
@click.option("-o", "--output", type=click.Path(dir_okay=False), default=None,
              help="write the config here (default: stdout)")
@click.option("--identities", "list_identities", is_flag=True,
              help="print the identities' user names instead, one per line (make certs makes one file each)")
def acl(sessions: str, output: str | None, list_identities: bool) -> None:
    """The secure profile's router config: TLS, passwords, and the access-control list derived from the topic
    tables (docs/security.md; docker/zenoh/router-secure.json5 is its output without --sessions)."""
    from pathlib import Path

    from cdpr.tools import acl as access

    names = [s for s in sessions.split(",") if s]
    if list_identities:
        click.echo("\n".join(access.identities(names)))
        return
    where = "secrets/router-secure.json5" if names else "zenoh/router-secure.json5"
    text = access.render(names, where=str(output or where) if names else where)
    if output is None:
        click.echo(text, nl=False)
    else:
        Path(output).write_text(text, encoding="utf-8")


@cli.command()
@click.option("--docs", type=click.Path(), default="docs", show_default=True,
              help="where results.md and its figures go")
@click.option("--runs", type=click.Path(), default="runs/experiments", show_default=True,
              help="where the recordings go")
@click.option("--duration", type=float, default=None, help="cut every scenario to this many seconds (quick check)")
@click.option("--only", multiple=True, help="run only these scenarios")
def experiments(docs: str, runs: str, duration: float | None, only: tuple[str, ...]) -> None:
    """Re-run the paper's experiments through the distributed loop and regenerate docs/results.md."""
    from pathlib import Path

    from cdpr.tools.experiments import run_experiments

    sys.exit(run_experiments(Path(docs), Path(runs), duration, only))
