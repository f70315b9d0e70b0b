"""``cdpr robots|ik|fk|tda|workspace|export-sdf``: robot tools (no session, no network)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import click
import numpy as np

from cdpr.errors import InputError
from cdpr.mechanics.forward import MAX_ITERATIONS as FK_MAX_ITERATIONS
from cdpr.mechanics.forward import TOL as FK_TOL
from cdpr.mechanics.robot import Robot
from cdpr.tools.cli.group import cli, emit

# ------------------------------------------------------------------------------------------------
# Robot tools

INFEASIBLE_EXIT = 3  # cdpr tda: no admissible tensions produce the wrench (documented in README)


def analysed_robot(robot: str, cable_set: str | None) -> Robot:
    """ROBOT for a tool that analyses it (ik, tda, workspace): loaded whether or not tensions hold its
    platform at its home pose — a session would refuse it, and a line on stderr says so and why."""
    from cdpr.config.loading import resolve
    from cdpr.config.robot import home_held_problem, load_robot

    r = load_robot(robot, cable_set, check_home=False)
    if (problem := home_held_problem(r, resolve(robot, "robots", "robot"))) is not None:
        click.echo(f"cdpr: warning: {problem} (a session would refuse this robot)", err=True)
    return r


@cli.command()
@click.argument("robot", required=False)
@click.option("--cable-set", "cable_set", default=None, metavar="NAME",
              help="which of the robot file's cable sets (default: its cables)")
@click.option("--find-home", is_flag=True,
              help="the pose nearest the file's home at which tensions within the limits hold the platform at rest "
                   "(its home orientation), as a line to put in the file")
def robots(robot: str | None, cable_set: str | None, find_home: bool) -> None:
    """List the shipped robots, or print the summary of ROBOT (a name or a YAML path). Exit code 3 when
    --find-home finds no such pose."""
    from cdpr.config.robot import load_robot, shipped_robots

    if robot is None:
        if find_home:
            raise InputError("--find-home: give the ROBOT whose home to find")
        out = []
        for name in shipped_robots():
            r = load_robot(name)
            out.append({"name": name, "mode": r.mode, "cables": r.m, "mass": r.mass, "description": r.description})
        emit(out)
    elif find_home:
        from cdpr.mechanics.rotation import matrix_to_rpy
        from cdpr.mechanics.workspace import find_held_pose, wrench_feasible

        r = load_robot(robot, cable_set, check_home=False)
        R = r.home_rotation
        held = bool(wrench_feasible(r, r.home_position[None, :], R)[0])
        found = r.home_position if held else find_held_pose(r, r.home_position, R)
        if found is None:
            emit({"robot": r.name, "home_held": False, "found": None})
            click.echo(f"cdpr robots --find-home: no position in the frame box holds the platform at its home "
                       f"orientation: {why_not_held_text(r)}", err=True)
            sys.exit(INFEASIBLE_EXIT)
        position = [round(float(x), 9) + 0.0 for x in found - R @ r.com_offset]  # the platform frame's, as the file
        rpy = [round(x, 12) + 0.0 for x in matrix_to_rpy(R)]
        emit({"robot": r.name, "home_held": held, "found": {"position": position, "rpy": rpy},
              "moved": float(np.linalg.norm(found - r.home_position))})
        if not held:
            click.echo(f"home: {{position: {position}, rpy: {rpy}}}   # held: put this in the robot file", err=True)
    else:  # the file checked as a session would (exit 2 with the loader's line, --find-home's way forward in it)
        emit(load_robot(robot, cable_set).summary())


@cli.command()
@click.argument("scenario", required=False)
@click.option("--reference", is_flag=True,
              help="every key a scenario file may hold — type, default, unit, an example — as markdown "
                   "(docs/scenarios.md)")
def scenarios(scenario: str | None, reference: bool) -> None:
    """List the shipped scenarios, or print SCENARIO's summary (a name or a YAML path): its robot, steps, start
    pose, controller and cable model."""
    from cdpr.config.scenario import load_scenario, shipped_scenarios

    if reference:
        from cdpr.config.reference import reference_markdown

        click.echo(reference_markdown(), nl=False)
        return
    if scenario is None:
        emit([{"name": n, "description": load_scenario(n, checks=()).description} for n in shipped_scenarios()])
        return
    s = load_scenario(scenario)
    origin = s.initial_position - s.initial_rotation @ s.robot.com_offset
    emit({"name": s.name, "source": s.source, "robot": s.robot.name, "cables": s.robot.m, "mass": s.robot.mass,
          "dt": s.dt, "duration": s.duration, "total_steps": s.total_steps,
          "start": {"position": [round(float(x), 12) + 0.0 for x in origin],
                    "at_home": s.start_note() is None},
          "controller": s.spec.controller.law, "tda": s.tda_method, "cable_model": s.cable_model,
          "cameras": [c.name for c in s.cameras], "sensors": s.spec.sim.sensors is not None})
    if (note := s.start_note()) is not None:
        click.echo(f"cdpr: note: {note}", err=True)


def why_not_held_text(r: Robot) -> str:
    from cdpr.mechanics.workspace import why_not_held

    return why_not_held(r, r.home_position, r.home_rotation)


_ANGLES_HELP = ("the convention of three angles, rad: rpy = roll pitch yaw, R = Rz(yaw)·Ry(pitch)·Rx(roll) (ROS/URDF); "
                "xyz = Euler XYZ, R = Rx(a)·Ry(b)·Rz(c) (CASPR)")
_POSE = ("--pose", "X Y Z [A B C]", "the platform frame's pose: position, m, and three angles, rad, in --angles' "
         "convention (default roll pitch yaw; none: no rotation)  [required]")
_WRENCH = ("--wrench", "FX FY FZ MX MY MZ", "the wrench the cables must exert on the platform: N and N·m, world "
           "frame, moment about the centre of mass")


def _numbers_command(*flags: tuple[str, str, str]) -> type[click.Command]:
    """A command class whose --help also lists ``flags`` (FLAG, METAVAR, HELP): options that take several numbers,
    which click cannot declare, collected from the command's extra arguments by :func:`_split_numbers`."""

    class NumbersCommand(click.Command):
        def format_options(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
            rows = [(f"{flag} {metavar}", text) for flag, metavar, text in flags]
            rows += [r for p in self.get_params(ctx)
                     if isinstance(p, click.Option) and (r := p.get_help_record(ctx)) is not None]
            with formatter.section("Options"):
                formatter.write_dl(rows)

    return NumbersCommand


def _cable_set_option() -> Any:
    return click.option("--cable-set", "cable_set", default=None, metavar="NAME",
                        help="which of the robot file's cable sets (default: its cables)")


def _angle_convention(_ctx: click.Context, _param: click.Parameter, value: str) -> str:
    from cdpr.mechanics.rotation import ANGLE_CONVENTIONS

    if value not in ANGLE_CONVENTIONS:
        raise InputError(f"--angles: unknown convention {value!r} (known: {', '.join(ANGLE_CONVENTIONS)})")
    return value


def _angles_option() -> Any:
    return click.option("--angles", metavar="rpy|xyz", default="rpy", show_default=True, callback=_angle_convention,
                        help=_ANGLES_HELP)


def _pose(values: tuple[float, ...], angles: str = "rpy") -> tuple[np.ndarray, np.ndarray]:
    from cdpr.mechanics.rotation import angles_to_matrix

    if len(values) not in (3, 6):
        raise InputError(f"--pose: expected X Y Z [A B C] (three angles in --angles {angles}), "
                         f"got {len(values)} number(s)")
    if not np.all(np.isfinite(values)):
        raise InputError("--pose: every number must be finite")
    return np.array(values[:3]), angles_to_matrix(angles, values[3:] if len(values) == 6 else (0.0, 0.0, 0.0))


@cli.command(cls=_numbers_command(_POSE), context_settings={"ignore_unknown_options": True, "allow_extra_args": True})
@click.argument("robot")
@_angles_option()
@_cable_set_option()
@click.pass_context
def ik(ctx: click.Context, robot: str, angles: str, cable_set: str | None) -> None:
    """Inverse kinematics of ROBOT at --pose X Y Z [A B C]: cable lengths, directions, wrench matrix (JSON).

    Exit code 3 when the robot cannot take the pose (a cable beyond its max_length, the platform outside the
    frame box or below its floor, a planar robot off its plane: the JSON is still printed, reachable false and
    the problems), 2 for bad input.
    """
    from cdpr.mechanics.kinematics import inverse_kinematics, pose_problems

    groups = _split_numbers(list(ctx.args), ("--pose",))
    if "--pose" not in groups:
        raise InputError("--pose X Y Z [A B C] is required")
    r = analysed_robot(robot, cable_set)
    position, R = _pose(_numbers("--pose", tuple(groups["--pose"])), angles)
    com = r.com_pose(position, R)
    k = inverse_kinematics(r, com, R)
    problems = pose_problems(r, com, R)
    emit({"lengths": k.lengths.tolist(), "directions": k.directions.tolist(),
          "wrench_matrix": k.wrench_matrix.tolist(), "reachable": not problems, "problems": problems})
    if problems:
        click.echo(f"cdpr ik: the robot cannot take this pose: {'; '.join(problems)}", err=True)
        sys.exit(3)


_LENGTHS = ("--lengths", "L1 … Lm", "the cable lengths, m, one per cable in the robot file's order  [required unless "
            "--csv]")
_GUESS = ("--guess", "X Y Z [A B C]", "where the solver starts: the platform frame's pose, as --pose is (default: the "
          "robot's home pose)")
_TENSIONS = ("--tensions", "T1 … Tm", "with --ea: the cables' tensions, N; the lengths are then unstretched ones l0 "
             "and the pose is that of the stretched lengths l0 (1 + T/EA)")


def _fk_lengths(flag: str, raw: list[str], r: Robot, what: str = "lengths") -> np.ndarray:
    values = np.array(_numbers(flag, tuple(raw)))
    if values.size != r.m:
        raise InputError(f"{flag}: expected {r.m} {what} (one per cable of {r.name}), got {values.size}")
    if not np.all(np.isfinite(values)) or (what == "lengths" and np.any(values <= 0.0)):
        raise InputError(f"{flag}: every one must be finite{' and > 0' if what == 'lengths' else ''}")
    return values


def _fk_pose(r: Robot, fk: Any, angles: str) -> dict[str, Any]:
    """A solve's pose as ``cdpr fk`` prints it: the platform frame's (what --pose gives), the COM's, the angles."""
    from cdpr.mechanics.rotation import matrix_to_rotvec, matrix_to_rpy

    R = fk.rotation
    origin = fk.position - R @ r.com_offset
    if angles == "rpy":
        three = list(matrix_to_rpy(R))
    else:  # Euler XYZ: R = Rx(a)·Ry(b)·Rz(c)
        b = float(np.arcsin(np.clip(R[0, 2], -1.0, 1.0)))
        three = [float(np.arctan2(-R[1, 2], R[2, 2])), b, float(np.arctan2(-R[0, 1], R[0, 0]))]
    return {"position": [float(x) + 0.0 for x in origin], angles: [x + 0.0 for x in three],  # (+ 0.0: no -0.0)
            "rotation": (R + 0.0).tolist(), "rotvec": (matrix_to_rotvec(R) + 0.0).tolist(),
            "com": (fk.position + 0.0).tolist()}


def _fk_problem(fk: Any, max_residual: float, max_iterations: int) -> str | None:
    if not fk.converged:
        return (f"the solver did not converge in {max_iterations} iterations (residual {fk.residual:.3g} m; "
                "another --guess may help)")
    if fk.residual > max_residual:
        return f"the lengths are inconsistent: residual {fk.residual:.3g} m > --max-residual {max_residual:g} m"
    return None


@cli.command(cls=_numbers_command(_LENGTHS, _GUESS, _TENSIONS),
             context_settings={"ignore_unknown_options": True, "allow_extra_args": True})
@click.argument("robot")
@click.option("--csv", "csv_file", default=None, metavar="FILE",
              help="the lengths of many poses, a line each (m, separated by commas or spaces; with --ea the m "
                   "tensions after them; blank lines and # comments skipped; - for stdin): a CSV line per pose on "
                   "stdout, each solve started from the last converged pose")
@click.option("--ea", "ea", type=float, default=None, metavar="N",
              help="every cable's axial stiffness EA, N: correct the lengths for elastic stretch (with --tensions)")
@click.option("--max-residual", type=float, default=1e-3, show_default=True,
              help="m: lengths that no pose matches closer than this (the largest |l_i(pose) − L_i|) are "
                   "inconsistent")
@click.option("--tol", type=float, default=FK_TOL, show_default=True, help="the solver's tolerance, m and rad")
@click.option("--max-iterations", type=int, default=FK_MAX_ITERATIONS, show_default=True,
              help="the solver's iterations")
@_angles_option()
@_cable_set_option()
@click.pass_context
def fk(ctx: click.Context, robot: str, csv_file: str | None, ea: float | None, max_residual: float, tol: float,
       max_iterations: int, angles: str, cable_set: str | None) -> None:
    """Forward kinematics of ROBOT: the pose whose cable lengths are --lengths L1 … Lm (JSON), or those of each
    line of --csv FILE (CSV).

    Prints the platform frame's pose (position, m; three angles, rad, in --angles' convention; the rotation),
    the centre of mass's position, the solver's iterations, whether it converged and the residual (the largest
    |l_i(pose) − L_i|, m: the least-squares pose when the lengths are noisy). Exit code 3 when the solver does not
    converge or the residual exceeds --max-residual (the JSON is still printed, consistent false and the problem;
    with --csv, every line is and one line on stderr counts them), 2 for bad input.
    """
    from cdpr.mechanics.forward import ForwardKinematics

    groups = _split_numbers(list(ctx.args), ("--lengths", "--guess", "--tensions"))
    if csv_file is None and "--lengths" not in groups:
        raise InputError("--lengths L1 … Lm (or --csv FILE) is required")
    if csv_file is not None and "--lengths" in groups:
        raise InputError("--csv: give --lengths or --csv, not both")
    if csv_file is not None and "--tensions" in groups:
        raise InputError("--tensions: with --csv, the tensions go on each line after the lengths")
    if csv_file is None and (ea is not None) != ("--tensions" in groups):
        raise InputError("--ea/--tensions: the elastic correction needs both")
    if ea is not None and not (np.isfinite(ea) and ea > 0.0):
        raise InputError(f"--ea: must be > 0 (got {ea:.12g})")
    for flag, value in (("--max-residual", max_residual), ("--tol", tol)):
        if not (np.isfinite(value) and value > 0.0):
            raise InputError(f"{flag}: must be > 0 (got {value:.12g})")
    if max_iterations < 1:
        raise InputError(f"--max-iterations: must be >= 1 (got {max_iterations})")
    r = analysed_robot(robot, cable_set)
    solver = ForwardKinematics(r, tol, max_iterations)
    if "--guess" in groups:
        values = _numbers("--guess", tuple(groups["--guess"]))
        if len(values) not in (3, 6) or not np.all(np.isfinite(values)):
            raise InputError(f"--guess: expected X Y Z [A B C] (finite; three angles in --angles {angles}), got "
                             f"{len(values)} number(s)")
        position, R = _pose(values, angles)
        solver.position, solver.rotation = r.com_pose(position, R), R
    if csv_file is None:
        lengths = _fk_lengths("--lengths", groups["--lengths"], r)
        tensions = None if ea is None else _fk_lengths("--tensions", groups["--tensions"], r, "tensions")
        result = solver.solve(lengths, tensions=tensions, EA=ea)
        problem = _fk_problem(result, max_residual, max_iterations)
        emit({**_fk_pose(r, result, angles), "iterations": result.iterations, "converged": result.converged,
              "residual": result.residual, "residual_norm": result.residual_norm, "consistent": problem is None,
              "problems": [] if problem is None else [problem]})
        if problem is not None:
            click.echo(f"cdpr fk: no pose has these lengths: {problem}", err=True)
            sys.exit(INFEASIBLE_EXIT)
        return
    _fk_csv(r, solver, csv_file, ea, angles, max_residual, max_iterations)


def _fk_csv(r: Robot, solver: Any, csv_file: str, ea: float | None, angles: str, max_residual: float,
            max_iterations: int) -> None:
    """``cdpr fk --csv``: a pose per line of lengths, each solve warm-started from the last converged one."""
    import re

    try:
        text = sys.stdin.read() if csv_file == "-" else Path(csv_file).read_text(encoding="utf-8")
    except OSError as exc:
        raise InputError(f"--csv: cannot read {csv_file}: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise InputError(f"--csv: {csv_file} is not a text file (UTF-8): a line of lengths per pose") from None
    rows: list[tuple[int, np.ndarray]] = []
    per_line = 2 * r.m if ea is not None else r.m
    what = f"{r.m} lengths and {r.m} tensions" if ea is not None else f"{r.m} lengths"
    for number, line in enumerate(text.splitlines(), start=1):
        fields = [f for f in re.split(r"[,\s]+", line.split("#", 1)[0].strip()) if f]
        if not fields:
            continue
        where = f"--csv {csv_file}: line {number}"
        values = np.array(_numbers(where, tuple(fields)))
        if values.size != per_line:
            raise InputError(f"{where}: expected {what} (one per cable of {r.name}), got {values.size} number(s)")
        if not np.all(np.isfinite(values)) or np.any(values[: r.m] <= 0.0):
            raise InputError(f"{where}: every number must be finite and every length > 0")
        rows.append((number, values))
    if not rows:
        raise InputError(f"--csv {csv_file}: no lines of lengths")
    names = {"rpy": ("roll", "pitch", "yaw"), "xyz": ("a", "b", "c")}[angles]
    click.echo(",".join(("line", "x", "y", "z", *names, "iterations", "converged", "residual")))
    bad: list[str] = []
    for number, values in rows:
        if ea is None:
            result = solver.solve(values)
        else:
            result = solver.solve(values[: r.m], tensions=values[r.m:], EA=ea)
        pose = _fk_pose(r, result, angles)
        click.echo(",".join([str(number), *(f"{x:.12g}" for x in pose["position"] + pose[angles]),
                             str(result.iterations), "true" if result.converged else "false",
                             f"{result.residual:.6g}"]))
        if (problem := _fk_problem(result, max_residual, max_iterations)) is not None:
            bad.append(f"line {number}: {problem}")
    if bad:
        click.echo(f"cdpr fk: {len(bad)} of {len(rows)} line(s) have no pose with their lengths ({bad[0]}"
                   f"{'; …' if len(bad) > 1 else ''})", err=True)
        sys.exit(INFEASIBLE_EXIT)


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


@cli.command(cls=_numbers_command(_POSE, _WRENCH),
             context_settings={"ignore_unknown_options": True, "allow_extra_args": True})
@click.argument("robot")
@_angles_option()
@click.option("--static", "static", is_flag=True, help="tensions that hold the platform (plus payload) at rest")
@click.option("--payload", type=float, default=0.0, show_default=True, help="kg rigidly attached at the centre of mass")
@click.option("--method", default="qp", show_default=True, help="qp | closed-form | improved-closed-form | continuity")
@click.option("--tmin", type=float, default=None, help="N (default: the robot's)")
@click.option("--tmax", type=float, default=None, help="N (default: the robot's)")
@_cable_set_option()
@click.pass_context
def tda(ctx: click.Context, robot: str, angles: str, static: bool, payload: float, method: str,
        tmin: float | None, tmax: float | None, cable_set: str | None) -> None:
    """Tension distribution of ROBOT at --pose X Y Z [A B C], for --static or --wrench FX FY FZ MX MY MZ.

    Prints the tensions as JSON. Exit code 0 when they produce the wrench within the limits, 3 when no
    admissible tensions do (the JSON is still printed: feasible false, the nearest admissible tensions and
    their residual), 2 for bad input.
    """
    from cdpr.mechanics.dynamics import gravity_wrench
    from cdpr.mechanics.kinematics import inverse_kinematics
    from cdpr.mechanics.tda import METHODS, make_tda

    groups = _split_numbers(list(ctx.args), ("--pose", "--wrench"))
    if "--pose" not in groups:
        raise InputError("--pose X Y Z [A B C] is required")
    if static == ("--wrench" in groups):
        raise InputError("give exactly one of --static or --wrench FX FY FZ MX MY MZ")
    if method not in METHODS:
        raise InputError(f"--method: unknown method {method!r} (known: {', '.join(sorted(METHODS))})")
    r = _option("--payload", analysed_robot(robot, cable_set).with_payload, payload)
    lo, hi = _limits(r, tmin, tmax)
    position, R = _pose(_numbers("--pose", tuple(groups["--pose"])), angles)
    rows = list(r.controlled_rows)
    W = inverse_kinematics(r, r.com_pose(position, R), R).wrench_matrix[rows]
    if static:
        w = -gravity_wrench(r)
        w = w if r.mode == "point_mass" else w[rows]
    else:
        wrench = np.array(_numbers("--wrench", tuple(groups["--wrench"])))
        if wrench.shape != (6,) or not np.all(np.isfinite(wrench)):
            raise InputError("--wrench: expected 6 finite numbers FX FY FZ MX MY MZ")
        w = wrench[rows]
    result = make_tda(method).solve(W, w, lo, hi)
    emit(
        {
            "tensions": result.tensions.tolist(),
            "feasible": result.feasible,
            "residual": result.residual,
            "method": result.method,
            "status": result.status,
        }
    )
    if not result.feasible:
        sys.exit(INFEASIBLE_EXIT)


def _option(flag: str, build: Any, value: float) -> Robot:
    """``build(value)``, its error (``name: must be …``) said of the command-line option ``flag``."""
    try:
        return build(value)
    except InputError as exc:
        raise InputError(f"{flag}: {str(exc).split(': ', 1)[-1]}") from None


def _limits(r: Any, tmin: float | None, tmax: float | None) -> tuple[np.ndarray, np.ndarray]:
    """Each cable's (tmin, tmax): the robot's, where --tmin / --tmax (for every cable) do not replace them."""
    lo = r.tmin if tmin is None else np.full(r.m, tmin)
    hi = r.tmax if tmax is None else np.full(r.m, tmax)
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))) or np.any(lo < 0) or np.any(lo > hi):
        given = (f"{tmin}" if tmin is not None else "the robot's") + " and " + (
            f"{tmax}" if tmax is not None else "the robot's")
        raise InputError(f"--tmin/--tmax: need 0 <= tmin <= tmax for every cable, got {given}")
    return lo, hi


def _number_or_list(values: np.ndarray) -> float | list[float]:
    """One number when every cable has it, else one per cable (for JSON)."""
    out = values.tolist()
    return out[0] if min(out) == max(out) else out


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
              help="fixed platform orientation: three angles, rad, in --angles' convention")
@_angles_option()
@click.option("--tmin", type=float, default=None, help="N (default: the robot's)")
@click.option("--tmax", type=float, default=None, help="N (default: the robot's)")
@click.option("--rrd", type=click.Path(), default=None, help="write the points to this .rrd file")
@click.option("--spawn", is_flag=True, help="show the points in a new Rerun viewer")
@click.option("--interference", is_flag=True,
              help="also the interference-free workspace: no two cables within --margin, no cable into the platform")
@click.option("--margin", type=float, default=0.0, show_default=True, help="with --interference: m")
@_cable_set_option()
def workspace(robot: str, payload: float, mass: float | None, step: float,
              orientation: tuple[float, float, float], angles: str, tmin: float | None, tmax: float | None,
              rrd: str | None, spawn: bool, interference: bool, margin: float, cable_set: str | None) -> None:
    """Static wrench-feasible workspace of ROBOT on a grid over its frame box (JSON; points to Rerun); with
    --interference, the part of it free of cable interference too (docs/workspace.md)."""
    import time

    from cdpr.mechanics.rotation import angles_to_matrix
    from cdpr.mechanics.workspace import compute_workspace
    from cdpr.recording.workspace import record_workspace

    r = analysed_robot(robot, cable_set)
    r = _option("--payload", (r if mass is None else _option("--mass", r.with_mass, mass)).with_payload, payload)
    lo, hi = _limits(r, tmin, tmax)
    if not (np.isfinite(step) and step > 0):
        raise InputError(f"--step: must be > 0 (got {step:.12g})")
    if not np.all(np.isfinite(orientation)):
        raise InputError("--orientation: roll, pitch and yaw must be finite")
    R = angles_to_matrix(angles, orientation)
    start = time.perf_counter()
    if margin and not interference:
        raise InputError("--margin: the interference-free workspace's (give --interference)")
    ws = compute_workspace(r, step, R, 0.0, lo, hi)
    free = None
    if interference:
        import dataclasses

        from cdpr.mechanics.interference import interference_free

        if not (np.isfinite(margin) and margin >= 0.0):
            raise InputError(f"--margin: must be >= 0 (got {margin:.12g})")
        free = interference_free(r, ws.points, R, margin)[0]
        wrench_ok = np.asarray(ws.feasible, dtype=bool)
        ws = dataclasses.replace(ws, feasible=wrench_ok & free)  # what the picture shows: both
    seconds = time.perf_counter() - start
    box = ws.bounding_box()
    out: dict[str, Any] = {
        "robot": r.name, "mass": r.mass, "payload": payload, "tmin": _number_or_list(lo),
        "tmax": _number_or_list(hi),
        f"orientation_{angles}": list(orientation), "step": step, "spacing": ws.spacing.tolist(),
        "grid": list(ws.shape),
        "points": int(ws.points.shape[0]), "feasible": int(ws.feasible.sum()), "fraction": ws.fraction,
        "bounding_box": None if box is None else {"min": box[0].tolist(), "max": box[1].tolist()},
        "seconds": seconds, "us_per_point": 1e6 * seconds / max(1, ws.points.shape[0]), "rrd": rrd,
    }
    if free is not None:  # feasible above is then wrench-feasible and interference-free
        out.update({"margin": margin, "wrench_feasible": int(wrench_ok.sum()), "interference_free": int(free.sum()),
                    "interfering_of_wrench_feasible": int((wrench_ok & ~free).sum())})
    if rrd is not None or spawn:
        info = {"workspace": dict(out), "robot": r.summary()}
        out["problems"] = record_workspace(r, ws, R, rrd=rrd, spawn=spawn, info=info)
    emit(out)


@cli.command("export-sdf")
@click.argument("robot")
@click.option("-o", "--output", default=None,
              help="SDF file to write (default: ROBOT's name + .sdf; - for stdout)")
@click.option("--tree", is_flag=True,
              help="leave out the ball joints that close the loops (for tree-only parsers)")
@_cable_set_option()
def export_sdf(robot: str, output: str | None, tree: bool, cable_set: str | None) -> None:
    """Write ROBOT as an SDF 1.6 world: frame, platform, a U-P-S leg per cable (the seed paper's model)."""
    import xml.etree.ElementTree as ET

    from cdpr.config.robot import load_robot
    from cdpr.tools.sdf import sdf_string

    r = load_robot(robot, cable_set)
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
    emit({"robot": r.name, "file": path, "links": len(model.findall("link")), "joints": len(joints),
           "ball_joints": sum(j.get("type") == "ball" for j in joints)})


# ------------------------------------------------------------------------------------------------
# Robots from other tools (docs/robots.md)


@cli.group("import")
def import_robot() -> None:
    """Write a robot file from another tool's model (CASPR)."""


@import_robot.command("caspr")
@click.argument("files", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("--model", "model", default=None, metavar="NAME",
              help="of a folder holding several models (NAME_bodies.xml, NAME_cables.xml), import NAME only "
                   "(default: every one, a robot file each)")
@click.option("--cable-set", "cable_set", default=None, metavar="ID",
              help="the set that becomes the file's cables (default: the model's default_cable_set); the others "
                   "are kept as cable_sets")
@click.option("--name", default=None, help="the robot's name (default: the model's link name, as a slug)")
@click.option("--home", type=float, nargs=3, default=None, metavar="X Y Z",
              help="the platform frame's home position (CASPR's joint frame), m (default: CASPR's q_initial; its "
                   "orientation is kept)")
@click.option("-o", "--output", default=None,
              help="robot file to write, or a folder for them (default: NAME.yaml; - for stdout)")
def import_caspr(files: tuple[Path, ...], model: str | None, cable_set: str | None, name: str | None,
                 home: tuple[float, float, float] | None, output: str | None) -> None:
    """Import a single-rigid-body CASPR model: FILES are its BODIES.xml and CABLES.xml (either order), or its
    model folder (a folder of several models: a robot file each, or --model NAME).

    Writes the robot file (the platform frame: CASPR's joint frame, platform.com the COM in it; mass, inertia,
    per-cable force limits, rotating pulleys as exit pulleys, every cable set) and names in it what CASPR does
    not give and the import chose (shape, frame box, max_length, max_speed). The file is loaded as every robot
    is before it is written: a model whose home pose its cables cannot hold is refused with the reason.
    """
    from cdpr.tools.caspr import import_caspr as run_import

    reports, text = run_import(list(files), model, cable_set, name, home, output)
    if text is not None:
        click.echo(text, nl=False)
    elif len(reports) == 1:
        emit(reports[0])
    else:
        emit({"models": [r["model"] for r in reports], "robots": reports})


@cli.command()
@click.argument("recording", type=click.Path())
@click.option("--robot", "nominal", required=True, metavar="NOMINAL",
              help="the robot file the session's controller believed (a shipped name or a YAML path)")
@click.option("-o", "--out", default=None, type=click.Path(dir_okay=False),
              help="the calibrated robot file (default: NAME_calibrated.yaml)")
@click.option("--platform-points", is_flag=True, help="identify the platform points b_i too")
@click.option("--set-mass", is_flag=True, help="write the identified mass into the robot file's platform.mass (the "
              "session's platform, payload included; scenarios often set theirs)")
@click.option("--without-tracker", is_flag=True,
              help="ignore the laser tracker's readings: self-calibration from the encoders alone")
@click.option("--plot", default=None, type=click.Path(dir_okay=False),
              help="a PNG of the encoder residuals before and after")
@click.option("--json", "as_json", is_flag=True, help="print the report as JSON instead of a table")
def calibrate(recording: str, nominal: str, out: str | None, platform_points: bool, set_mass: bool,
              without_tracker: bool, plot: str | None, as_json: bool) -> None:
    """Calibrate NOMINAL from RECORDING (a .rrd of a session with winch encoders): the frame's exit points and the
    encoders' zero errors (with a laser tracker's readings, or self-calibration from the encoders alone), the
    platform's mass from the load cells and the IMU. Prints each parameter with its standard uncertainty, the
    residuals before and after, which parameters the data cannot identify; writes a robot file. Exit code 2 for
    a recording without encoder readings or of another robot (docs/calibration.md)."""
    from cdpr.config.loading import resolve
    from cdpr.config.robot import home_held_problem, load_robot
    from cdpr.tools import calibrate as cal

    report = cal.calibrate(recording, nominal, platform_points=platform_points, tracker=not without_tracker,
                           set_mass=set_mass)
    target = Path(out or f"{report.robot.name}_calibrated.yaml")
    staged = target.with_name(f".{target.name}.tmp")
    try:
        staged.write_text(report.text, encoding="utf-8")
        written = load_robot(staged, check_home=False)  # loads and validates like any other, before it replaces
        staged.replace(target)
    except OSError as exc:
        raise InputError(f"-o: cannot write {target}: {exc.strerror or exc}") from None
    finally:
        staged.unlink(missing_ok=True)
    if home_held_problem(load_robot(nominal, check_home=False), resolve(nominal, "robots", "robot")) is None and (
            problem := home_held_problem(written, target)) is not None:
        click.echo(f"cdpr: warning: {problem}", err=True)
    if plot is not None:
        cal.plot(report, plot)
    if as_json:
        emit({**cal.summary(report), "file": str(target)})
    else:
        click.echo(cal.table(report))
        click.echo(f"\nwrote {target}")


@cli.command()
@click.argument("scenario")
@click.option("--margin", type=float, default=0.0, show_default=True,
              help="the least clearance, m: a cable this near another, the platform, an obstacle or the floor violates")
@click.option("--every", type=click.IntRange(min=1), default=10, show_default=True,
              help="check every N steps (the steps before a violation one by one)")
@click.option("--json", "as_json", is_flag=True, help="print the report as JSON instead of a table")
def check(scenario: str, margin: float, every: int, as_json: bool) -> None:
    """Check SCENARIO's trajectory before running it: the wrench-feasible workspace, the cables' length limits,
    cable-cable and cable-platform interference, the scene's obstacles and floor (docs/scenarios.md). Prints the
    least clearance of each kind and the first violation (time, step, what, how near) in one line. Exit code 0
    when clean, 3 when violated, 2 for bad input."""
    from cdpr.config.scenario import load_scenario
    from cdpr.tools import check as chk

    if not (np.isfinite(margin) and margin >= 0.0):
        raise InputError(f"--margin: must be >= 0 (got {margin:.12g})")
    report = chk.check_scenario(load_scenario(scenario, checks=()), margin, every)
    if as_json:
        emit(chk.summary(report))
    else:
        click.echo(chk.table(report))
    if not report.ok:
        assert report.violation is not None
        step, kind, line = report.violation
        click.echo(f"cdpr: {report.scenario}: {kind} at t = {step * report.dt:.3f} s (step {step}): {line}", err=True)
        sys.exit(INFEASIBLE_EXIT)
