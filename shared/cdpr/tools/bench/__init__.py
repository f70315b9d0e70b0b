"""`cdpr bench`: where the lock-step loop's time goes, every figure measured side by side in one run.

One invocation measures, one after the other on the same machine (so that their ratios hold even
when the machine is shared and its absolute speed drifts):

1. ``monolithic``: the services' per-step work in one process, without messaging — DART step
   (:class:`cdpr_sim.core.PlatformSim`), controller core (feedback linearisation + tension
   distribution), trajectory setpoint and the encoding/decoding of the four messages of a step: the
   ceiling of the distributed loop;
2. ``distributed``: ``cdpr run SCENARIO`` (fast mode) as a subprocess: steps/s, RTF, its ratio to (1),
   and the CPU each process spends per step; with the same session recorded to an ``.rrd``, to an
   ``.rrd`` and an ``.mcap``, and composed in one process (``--in-process``). (1) and (2) are
   interleaved (M A M B M C M D, three times), each ratio the median of (2)'s runs over all of (1)'s;
3. ``zenoh_rtt``: a raw Zenoh round trip with the project's settings — two processes on loopback,
   each answering in its :class:`cdpr.runtime.transport.Inbox` callback, ``PUBLISH_OPTS``; as clients of a
   router (how remote participants talk) and as peers linked directly (how ``cdpr run``'s services
   talk): the floor of one hop;
4. ``realtime``: ``cdpr run SCENARIO --mode realtime --duration D`` (1 kHz) and the same at 2 kHz
   (``caroca_15kg_2khz``): the share of steps the sim started within dt of their deadline and the lateness
   percentiles, with the defaults, ``--cpu-latency 0`` and ``--rt-priority``, a sleeping probe beside each;
5. ``tda``: the tension distribution's solve time per method for 4, 8, 12 and 16 cables, along a
   smooth path (as in the loop: warm), on random well-conditioned robots built here;
6. ``scaling``: steps/s and CPU per step with 1, 2, 4, 8 concurrent sessions, and with 4 → 16 cables
   (generated robot and scenario files in a temporary directory);
7–10. the MuJoCo peer, a ROS 2 controller, cameras, the Gymnasium environment (their modules' docstrings);
11. ``fk``: forward kinematics by the Mahnke & Caverly (2025) protocol on cogiro and caroca (:mod:`.fk`).

Medians over repeats; ``--quick`` runs every part once, a few hundred steps a session (a quick look, about a
minute). Results are printed as a table and written as JSON. The Linux ``/proc`` file system gives the
per-process CPU figures (elsewhere they are left out).
"""


from __future__ import annotations

import json
import os
import platform
import time
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any

from cdpr.config.scenario import load_scenario
from cdpr.tools.bench.loops import (
    bench_cables,
    bench_loop_variants,
    bench_realtime,
    bench_sessions,
    bench_startup,
    count_deliveries,
    monolithic_steps,
    rt_priority_allowed,
)
from cdpr.tools.bench.plan import BENCH_VERSION, FULL, QUICK, BenchPlan, _log
from cdpr.tools.bench.robots import bench_tda, robot_spec, scenario_yaml, tda_path

REALTIME_2KHZ = "caroca_15kg_2khz"  # the paper's 15 kg session at dt = 0.5 ms: the 2 kHz realtime runs

__all__ = ["BENCH_VERSION", "FULL", "QUICK", "BenchPlan", "monolithic_steps", "robot_spec", "rt_priority_allowed",
           "run_bench", "scenario_yaml", "table", "tda_path"]

# --------------------------------------------------------------------------------------------------
# The whole run


def machine() -> dict[str, Any]:
    model = ""
    try:
        with open("/proc/cpuinfo") as f:
            model = next((ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name")), "")
    except OSError:
        pass
    import zenoh

    return {
        "nproc": os.cpu_count(),
        "cpu_model": model or platform.processor(),
        "loadavg": list(os.getloadavg()),
        "python": platform.python_version(),
        "zenoh": getattr(zenoh, "__version__", None) or _dist_version("eclipse-zenoh"),
        "platform": platform.platform(),
    }


def _dist_version(name: str) -> str | None:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(name)
    except PackageNotFoundError:
        return None


def targets(result: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The project's performance targets, each with the measured figure and whether it is met."""
    dist, rt, loops = result["distributed"], result["realtime"], result["loops"]
    rec, start = loops["multi_process_recording"], result["startup"]

    def target(value: float, met: bool, **extra: Any) -> dict[str, Any]:
        return {"value": value, "met": bool(met), **extra}

    out = {
        "distributed_steps_per_s>=2000": target(dist["steps_per_s"], dist["steps_per_s"] >= 2000),
        "distributed/monolithic>=0.6": target(ratio := dist["ratio_to_monolithic"], ratio >= 0.6),
        "realtime_on_time>=0.999": target(rt["on_time_fraction"], rt["on_time_fraction"] >= 0.999,
                                          over_s=rt["duration_s"], machine=rt["probe_on_time_fraction"]),
        "recording/monolithic>=0.5": target(r := rec["ratio_to_monolithic"], r >= 0.5),
        "recording_cost<=0.15": target(c := loops["recording_cost"], c <= 0.15),
        "recording_both_cost<=0.15": target(c := loops["recording_both_cost"], c <= 0.15),
        "in_process/monolithic>=0.8": target(i := loops["in_process"]["ratio_to_monolithic"], i >= 0.8),
        "deliveries_per_step<=3": target(d := result["deliveries"]["deliveries_per_step"], d <= 3.0),
        "startup_50_steps_multi_process_s<=1.5": target(s := start["multi_process_s"], s <= 1.5),
        "startup_50_steps_in_process_s<=1.0": target(s := start["in_process_s"], s <= 1.0),
    }
    if (fifo := rt.get("rt_priority")) is not None:
        out["realtime_on_time_rt_priority>=0.999"] = target(
            fifo["on_time_fraction"], fifo["on_time_fraction"] >= 0.999, over_s=fifo["duration_s"],
            machine=fifo["probe_on_time_fraction"])
    # #33: 1 kHz with the defaults within 0.1 points of the sleeping probe; 2 kHz >= 99 % (or within 0.2
    # points of the probe when the machine gives a sleeping thread less), >= 99.9 % with --rt-priority
    probe = rt["probe_on_time_fraction"]
    if probe is not None:
        out["realtime_1khz>=probe-0.001"] = target(rt["on_time_fraction"] - probe,
                                                   rt["on_time_fraction"] >= probe - 0.001, machine=probe)
    if (fast := result.get("realtime_2khz")) is not None:
        for name, run in (("", fast), ("_cpu_latency_0", fast.get("cpu_latency"))):
            if run is not None:
                probe_2k = run["probe_on_time_fraction"]
                bar = 0.99 if probe_2k is None else min(0.99, probe_2k - 0.002)
                out[f"realtime_2khz{name}>=0.99"] = target(run["on_time_fraction"], run["on_time_fraction"] >= bar,
                                                           bar=bar, machine=run["probe_on_time_fraction"])
        if (fifo := fast.get("rt_priority")) is not None:
            out["realtime_2khz_rt_priority>=0.999"] = target(fifo["on_time_fraction"],
                                                             fifo["on_time_fraction"] >= 0.999,
                                                             machine=fifo["probe_on_time_fraction"])
    tda8 = next((s for s in result["tda"]["sizes"] if s["cables"] == 8), None)
    if tda8 is not None:
        qp, diff = tda8["methods"]["qp"]["median_us"], tda8["qp_max_difference_N"]
        out["qp_8_cables_median_us<=50"] = target(qp, qp <= 50.0)
        out["qp_same_optimum<=1e-6"] = target(diff, diff <= 1e-6)
    if (mj := result.get("mujoco", {})).get("available"):
        out["monolithic/mujoco_peer>=1.0"] = target(x := mj["monolithic_to_peer"], x >= 1.0)
    if (ros := result.get("ros2", {})).get("available"):
        out["ros2_controller/cdpr_controller>=0.5"] = target(x := ros["ratio"], x >= 0.5)
    if (cams := result.get("cameras", {})).get("available"):  # #26
        out["camera_features_60hz_cost<=0.05"] = target(x := cams["features_60hz_cost"], x <= 0.05)
        out["camera_images_30hz_cost<=0.25"] = target(x := cams["images_30hz_cost"], x <= 0.25)
        out["camera_images_realtime_drop_points<=0.2"] = target(x := cams["realtime_on_time_drop_points"], x <= 0.2)
    if (g := result.get("gym", {})).get("available"):  # #27
        out["gym_local/monolithic>=2"] = target(x := g["local_to_monolithic"], x >= 2.0)
    if "fk" in result:  # #46
        from cdpr.tools.bench.fk import fk_targets

        out.update(fk_targets(result["fk"]))
    return out


def run_bench(plan: BenchPlan, scenario: str = "caroca_15kg", out: Path | None = Path("bench.json"),
              log: Callable[[str], None] = _log) -> dict[str, Any]:
    """Run every part of ``plan``; returns the results (and writes them to ``out`` as JSON)."""
    started = time.monotonic()
    sc = load_scenario(scenario)
    result: dict[str, Any] = {
        "version": BENCH_VERSION,
        "quick": plan == QUICK,
        "scenario": sc.name,
        "plan": asdict(plan),
        "machine": machine(),
        "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    load: dict[str, float] = {}  # the 1-minute load average as each part starts: the machine may be shared
    result["machine"]["loadavg_by_part"] = load

    def part(name: str, message: str) -> None:
        load[name] = os.getloadavg()[0]
        log(f"{len(load)}/11 {message}")

    part("loops", f"distributed loop: multi-process, recording (.rrd; .rrd and .mcap), in-process (x "
                  f"{plan.loop_repeats}), each after the monolithic loop ({plan.mono_steps} steps)")
    result["monolithic"], loops = bench_loop_variants(sc, plan.loop_duration, plan.loop_repeats, plan.mono_steps,
                                                      plan.mono_repeats)
    bare = loops["multi_process"]["steps_per_s"]
    loops["recording_cost"] = 1.0 - loops["multi_process_recording"]["steps_per_s"] / bare
    loops["recording_both_cost"] = 1.0 - loops["multi_process_recording_both"]["steps_per_s"] / bare
    result["loops"] = loops
    result["distributed"] = loops["multi_process"]
    result["deliveries"] = count_deliveries(sc, plan.mono_steps)
    part("startup", f"start-up: 50-step sessions (x {plan.startup_repeats})")
    result["startup"] = bench_startup(scenario, plan.startup_repeats)
    part("zenoh_rtt", f"Zenoh round trip ({plan.rtt_count})")
    from cdpr.tools.bench.zenoh_rtt import bench_zenoh_rtt  # here: its processes run it as __main__

    result["zenoh_rtt"] = bench_zenoh_rtt(plan.rtt_count)
    part("realtime", f"realtime mode, 1 kHz ({plan.realtime_duration:g} s) and 2 kHz "
                     f"({plan.realtime_2khz_duration:g} s): defaults, --cpu-latency 0, --rt-priority")
    result["realtime"] = bench_realtime(scenario, plan.realtime_duration)
    result["realtime_2khz"] = bench_realtime(REALTIME_2KHZ, plan.realtime_2khz_duration)
    part("tda", f"tension distribution ({', '.join(map(str, plan.tda_sizes))} cables)")
    result["tda"] = bench_tda(plan.tda_sizes, plan.tda_calls)
    part("scaling", f"scaling ({', '.join(map(str, plan.session_counts))} sessions; "
                    f"{', '.join(map(str, plan.cable_counts))} cables)")
    result["scaling"] = {
        "sessions": bench_sessions(scenario, plan.session_counts, plan.session_duration),
        "cables": bench_cables(plan.cable_counts, plan.cable_duration),
    }
    part("mujoco", f"the MuJoCo peer: the same controller and trajectory on MuJoCo (x {plan.loop_repeats}), "
                   "and the two engines' agreement")
    from cdpr.tools.bench.mujoco_peer import bench_mujoco

    result["mujoco"] = bench_mujoco(sc, plan.mono_steps, max(plan.loop_repeats, 1))
    part("ros2", f"a ROS 2 controller (zenoh-ros2-sdk) and the cdpr controller, each joining the session from "
                 f"its own process ({plan.ros2_duration:g} s, x {plan.ros2_repeats}, alternating)")
    from cdpr.tools.bench.ros2 import bench_ros2

    result["ros2"] = bench_ros2(scenario, plan.ros2_duration, plan.ros2_repeats)
    part("cameras", f"cameras: none, features at 60 Hz, images at 30 Hz ({plan.camera_duration:g} s fast, x "
                    f"{plan.camera_repeats}; {plan.camera_realtime_duration:g} s realtime, x "
                    f"{plan.camera_realtime_repeats})")
    from cdpr.tools.bench.cameras import bench_cameras

    result["cameras"] = bench_cameras(plan.camera_duration, plan.camera_repeats, plan.camera_realtime_duration,
                                      plan.camera_realtime_repeats)
    part("gym", f"the Gymnasium environment: local mode per action space beside the monolithic loop (x "
                f"{plan.gym_rounds}), session mode, two envs vectorised")
    from cdpr.tools.bench.gym import bench_gym

    result["gym"] = bench_gym(scenario, plan.gym_duration, plan.gym_rounds, plan.gym_session_duration,
                              plan.gym_vector_steps)
    from cdpr.tools.bench.fk import POSES, QUICK_POSES, ROBOTS, bench_fk  # here: python -m runs the module alone

    part("fk", f"forward kinematics, the Mahnke & Caverly protocol on {' and '.join(ROBOTS)} "
               f"({QUICK_POSES if plan == QUICK else POSES} poses each: cold, warm, noisy)")
    result["fk"] = bench_fk(quick=plan == QUICK)
    result["machine"]["loadavg_end"] = list(os.getloadavg())
    result["elapsed_s"] = time.monotonic() - started
    result["targets"] = targets(result)
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    return result


def _percents(values: list[float]) -> str:
    return " ".join(f"{100 * x:.1f}" for x in values) + " %"


def _fmt(x: Any, digits: int = 0) -> str:
    if x is None:
        return "-"
    if isinstance(x, float):
        return f"{x:,.{digits}f}"
    return str(x)


def _realtime_rows(rt: dict[str, Any], title: str) -> list[tuple[str, str]]:
    """A realtime part's rows: the run with the defaults, with --cpu-latency 0, with --rt-priority."""
    ms = f"{1e3 * rt['dt']:g} ms"
    rows: list[tuple[str, str]] = []
    fifo = rt.get("rt_priority")
    awake = " --cpu-latency 0" if fifo is not None and fifo.get("cpu_latency_us") == 0 else ""
    for label, run in ((f"{title}, {rt['duration_s']:g} s: steps within {ms}", rt),
                       (f"  with --cpu-latency 0: steps within {ms}", rt.get("cpu_latency")),
                       (f"  with --rt-priority{awake}: within {ms}", fifo)):
        if run is None:
            rows.append((label, "not permitted here"))
            continue
        rows += [(label, f"{100 * run['on_time_fraction']:.3f} %"),
                 ("    lateness p50 / p99 / p99.9 / max, ms",
                  " / ".join(f"{run[f'lateness_{p}_ms']:.3f}" for p in ("p50", "p99", "p999", "max"))),
                 *_realtime_profile(run)]
    return rows


def _realtime_profile(rt: dict[str, Any]) -> list[tuple[str, str]]:
    """A realtime run's profile rows: each process's CPU and wait for a CPU per step, the machine."""
    cpu, wait = rt.get("cpu_us_per_step_by_process") or {}, rt.get("wait_us_per_step_by_process") or {}
    rows = [(f"    {k}: CPU / waiting for a CPU, us per step", f"{_fmt(cpu[k])} / {_fmt(wait.get(k))}")
            for k in sorted(cpu, key=lambda k: -cpu[k])]
    if cpu:
        rows.append(("    all: CPU / waiting for a CPU, us per step",
                     f"{_fmt(sum(cpu.values()))} / {_fmt(sum(wait.values()) if wait else None)}"))
    if rt.get("machine_idle_fraction") is not None:
        rows.append(("    machine idle / stolen by the host", f"{100 * rt['machine_idle_fraction']:.1f} % / "
                     f"{100 * rt['machine_steal_fraction']:.2f} %"))
    if rt.get("probe_on_time_fraction") is not None:
        rows.append((f"    a sleeping probe beside it: wakes within {1e3 * rt.get('dt', 1e-3):g} ms",
                     f"{100 * rt['probe_on_time_fraction']:.3f} % (max {rt['probe_max_ms']:.1f} ms)"))
    return rows


def table(r: dict[str, Any]) -> str:
    """The results as a plain-text table (what `cdpr bench` prints)."""
    mono, dist, rtt, rt, mach = r["monolithic"], r["distributed"], r["zenoh_rtt"], r["realtime"], r["machine"]
    loops = r["loops"]
    rows: list[tuple[str, str]] = [
        ("1 monolithic loop, steps/s", _fmt(mono["steps_per_s"])),
        *((f"    {k}, us/step", _fmt(v, 1)) for k, v in mono["us_per_step"].items()),
        ("2 distributed loop (fast, multi-process), steps/s", _fmt(dist["steps_per_s"])),
        ("    RTF", _fmt(dist["rtf"], 2)),
        ("    ratio to the monolithic loop", _fmt(dist["ratio_to_monolithic"], 2)),
        ("    CPU of all processes, us/step", _fmt(dist["cpu_us_per_step"])),
        *((f"      {k}", _fmt(v)) for k, v in dist["cpu_us_per_step_by_process"].items()),
        ("  with the recorder writing an .rrd, steps/s", _fmt(loops["multi_process_recording"]["steps_per_s"])),
        ("    ratio to the monolithic loop", _fmt(loops["multi_process_recording"]["ratio_to_monolithic"], 2)),
        ("    cost of recording (throughput lost)", f"{100 * loops['recording_cost']:.1f} %"),
        ("  with .rrd and .mcap, steps/s", _fmt(loops["multi_process_recording_both"]["steps_per_s"])),
        ("    ratio to the monolithic loop", _fmt(loops["multi_process_recording_both"]["ratio_to_monolithic"], 2)),
        ("    cost of both sinks (throughput lost)", f"{100 * loops['recording_both_cost']:.1f} %"),
        ("  in-process composition (--in-process), steps/s", _fmt(loops["in_process"]["steps_per_s"])),
        ("    ratio to the monolithic loop", _fmt(loops["in_process"]["ratio_to_monolithic"], 2)),
        ("  messages delivered per step (fast mode)", _fmt(r["deliveries"]["deliveries_per_step"], 2)),
        *((f"    {k}", _fmt(v["deliveries_per_step"], 3)) for k, v in r["deliveries"]["topics"].items()),
        ("  50-step session, whole command: multi-process, s", _fmt(r["startup"]["multi_process_s"], 2)),
        ("    in-process, s", _fmt(r["startup"]["in_process_s"], 2)),
        ("3 Zenoh round trip, clients through the router, median us", _fmt(rtt["median_us"], 1)),
        ("    p99 us", _fmt(rtt["p99_us"], 1)),
        ("    one message (half), us", _fmt(rtt["one_way_us"], 1)),
        ("  peers linked directly (as in cdpr run), median us", _fmt(rtt["peers"]["median_us"], 1)),
        ("    p99 us", _fmt(rtt["peers"]["p99_us"], 1)),
        ("    one message (half), us", _fmt(rtt["peers"]["one_way_us"], 1)),
        # a step's state → command → state: what dt must hold (1 kHz: < 1 ms, 2 kHz: < 0.5 ms)
        ("4 one step of the fast loop above, ms", _fmt(1e3 / dist["steps_per_s"], 2)),
        *_realtime_rows(rt, "  realtime 1 kHz"),
        *(_realtime_rows(r["realtime_2khz"], "  realtime 2 kHz") if "realtime_2khz" in r else ()),
    ]
    lines = [
        f"cdpr bench{' --quick' if r['quick'] else ''}: {r['scenario']}, "
        f"{mach['nproc']} x {mach['cpu_model']}, "
        f"load {mach['loadavg'][0]:.2f} -> {mach['loadavg_end'][0]:.2f}, {r['elapsed_s']:.0f} s",
        "load as each part started: " + ", ".join(f"{k} {v:.1f}" for k, v in mach["loadavg_by_part"].items()),
        "",
        *(f"{name:52s} {value:>22s}" for name, value in rows),
        "",
        "5 tension distribution, median us per solve (p90)",
    ]
    sizes = r["tda"]["sizes"]
    lines.append(f"    {'method':24s}" + "".join(f"{str(s['cables']) + ' cables':>16s}" for s in sizes))
    for name in sizes[0]["methods"] if sizes else ():
        stats = [s["methods"][name] for s in sizes]
        cells = (f"{_fmt(t['median_us'], 1)} ({_fmt(t['p90_us'])})" for t in stats)
        lines.append(f"    {name:24s}" + "".join(f"{c:>16s}" for c in cells))
    lines.append(f"    {'qp vs qp_solver, max |df|':24s}"
                 + "".join(f"{s['qp_max_difference_N']:>14.1e} N" for s in sizes))
    lines += ["", "6 scaling",
              f"    {'sessions':10s}{'steps/s each':>16s}{'aggregate':>12s}{'CPU us/step':>14s}"]
    for s in r["scaling"]["sessions"]:
        lines.append(f"    {s['sessions']:<10d}{_fmt(s['median_steps_per_s']):>16s}"
                     f"{_fmt(s['aggregate_steps_per_s']):>12s}{_fmt(s['cpu_us_per_step']):>14s}")
    lines.append(f"    {'cables':10s}{'steps/s':>16s}{'':>12s}{'CPU us/step':>14s}")
    for c in r["scaling"]["cables"]:
        lines.append(f"    {c['cables']:<10d}{_fmt(c['steps_per_s']):>16s}{'':>12s}"
                     f"{_fmt(c['cpu_us_per_step']):>14s}")
    lines += ["", "7 the MuJoCo peer: the same controller and trajectory cores, MuJoCo physics (RK4)"]
    mj = r.get("mujoco") or {"available": False, "reason": "not run"}
    if mj["available"]:
        agree = mj["agreement"]
        lines += [f"    {name:48s} {value:>22s}" for name, value in (
            (f"MuJoCo {mj['mujoco']} peer loop, steps/s", _fmt(mj["steps_per_s"])),
            ("monolithic loop in the same minutes, steps/s", _fmt(mj["monolithic_steps_per_s"])),
            ("monolithic / peer", _fmt(mj["monolithic_to_peer"], 2)),
            (f"the engines' difference ({agree['steps']} steps): position",
             f"{1e6 * agree['max_position_difference_m']:.1f} um"),
            ("    orientation", f"{agree['max_orientation_difference_rad']:.2e} rad"),
        )]
    else:
        lines.append(f"    {mj['reason']}")
    lines += ["", "8 a ROS 2 controller (zenoh-ros2-sdk, rmw_zenoh's wire) vs the cdpr controller, same session"]
    ros = r.get("ros2") or {"available": False, "reason": "not run"}
    if ros["available"]:
        lines += [f"    {name:48s} {value:>22s}" for name, value in (
            ("cdpr controller (its own process), steps/s", _fmt(ros["cdpr"]["steps_per_s"])),
            ("ROS 2 controller through the ros2 node, steps/s", _fmt(ros["ros2"]["steps_per_s"])),
            ("    ratio", _fmt(ros["ratio"], 2)),
            ("    ROS 2 side's CPU (ros2 node + controller), us/step", _fmt(ros["ros2"]["ros2_side_cpu_us_per_step"])),
            ("      ros2 node (sim+ros2 less the cdpr runs' sim)", _fmt(ros["ros2"]["ros2_node_cpu_us_per_step"])),
            *((f"      {k}", _fmt(v)) for k, v in ros["ros2"]["cpu_us_per_step_by_process"].items()),
            ("    RMS position error, ROS 2 / cdpr, mm", f"{1e3 * ros['ros2']['rms_position_error']:.3f} / "
                                                       f"{1e3 * ros['cdpr']['rms_position_error']:.3f}"),
        )]
    else:
        lines.append(f"    {ros['reason']}")
    lines += ["", "9 cameras (one looking down at four markers): what they cost the loop"]
    cams = r.get("cameras") or {"available": False, "reason": "not run"}
    if cams["available"]:
        rates, rt = cams["steps_per_s"], cams["realtime"]
        lines += [f"    {name:48s} {value:>22s}" for name, value in (
            ("fast mode, no camera, steps/s", _fmt(rates["none"])),
            ("  a 60 Hz camera, features only, steps/s", _fmt(rates["features_60hz"])),
            ("    throughput lost (median of the rounds)", f"{100 * cams['features_60hz_cost']:.1f} %"),
            ("      each round", _percents(cams["runs_costs"]["features_60hz"])),
            ("  a 30 Hz camera drawing 640 x 480 images, steps/s", _fmt(rates["images_30hz"])),
            ("    throughput lost (median of the rounds)", f"{100 * cams['images_30hz_cost']:.1f} %"),
            ("      each round", _percents(cams["runs_costs"]["images_30hz"])),
            (f"realtime 1 kHz, {cams['realtime_duration_s']:g} s: on time without / with images",
             f"{100 * rt['none']['on_time_fraction']:.2f} / {100 * rt['images_30hz']['on_time_fraction']:.2f} %"),
            ("    a sleeping probe beside each", f"{100 * rt['none']['probe_on_time_fraction']:.2f} / "
                                                f"{100 * rt['images_30hz']['probe_on_time_fraction']:.2f} %"),
            ("    drop in points (median of the rounds) / probe's", f"{cams['realtime_on_time_drop_points']:.2f} / "
                                                                  f"{cams['realtime_probe_drop_points']:.2f}"),
            ("      each round", " ".join(f"{x:.2f}" for x in cams["realtime_runs_drop_points"])),
        )]
    else:
        lines.append(f"    {cams['reason']}")
    lines += ["", "10 the Gymnasium environment (cdpr/Track-v0, 10 sim steps per env step), sim steps/s"]
    g = r.get("gym") or {"available": False, "reason": "not run"}
    if g["available"]:
        local, ses, vec = g["local"], g["session"], g["vector"]
        lines += [f"    {name:48s} {value:>22s}" for name, value in (
            ("monolithic loop in the same minutes", _fmt(g["monolithic_steps_per_s"])),
            *((f"local, {a}: first episode / later ones", f"{_fmt(local[a]['first'])} / {_fmt(local[a]['later'])}")
              for a in local),
            ("    wrench, later episodes / monolithic", _fmt(g["local_to_monolithic"], 2)),
            (f"session mode (cdpr up, {ses['duration_s']:g} s), residual", _fmt(ses["sim_steps_per_s"])),
            ("2 local envs, SyncVectorEnv / AsyncVectorEnv, wrench",
             f"{_fmt(vec['sync_2']['sim_steps_per_s'])} / {_fmt(vec['async_2']['sim_steps_per_s'])}"),
        )]
    else:
        lines.append(f"    {g['reason']}")
    if "fk" in r:
        from cdpr.tools.bench.fk import fk_lines

        lines += ["", *fk_lines(r["fk"])]
    lines += ["", "targets"]
    lines += [target_line(name, t) for name, t in r["targets"].items()]
    return "\n".join(lines)


def target_line(name: str, t: dict[str, Any]) -> str:
    """One row of the targets: name, figure, met or MISSED; a missed realtime target says what the
    machine gave a thread that only sleeps until each millisecond, in the same minutes (``machine``)."""
    line = f"    {name:36s} {_fmt(t['value'], 4):>14s}  {'met' if t['met'] else 'MISSED'}"
    if not t["met"] and t.get("machine") is not None:
        line += f" (a sleeping probe beside it: {100.0 * t['machine']:.3f} % on time)"
    return line
