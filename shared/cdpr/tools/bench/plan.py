"""What a run measures (:class:`BenchPlan`: full and quick) and the progress log."""

from __future__ import annotations

import sys
from dataclasses import dataclass

BENCH_VERSION = 13  # 2: loop variants (recording, in-process), deliveries, start-up; 3: the recorder writing
# an .rrd and an .mcap (loops.multi_process_recording_both, loops.recording_both_cost, its target); 4: the
# monolithic loop measured before each run of a variant (M A M B M C M D), no longer first and apart; 5: the
# MuJoCo peer (mujoco: its loop beside the monolithic one, the engines' agreement; its target); 6: realtime paced by
# the sim (lateness: each step's start after its deadline), 2 kHz (realtime_2khz), --cpu-latency runs, the
# monolithic loop messaging as protocol 2 does (windows, blocks); 7: a ROS 2 controller's session beside the cdpr
# controller's (ros2); 8: what cameras cost (cameras); 9: the Gymnasium environment's speed (gym); 10: the cameras'
# costs from rounds of adjacent runs (the median of each round's ratio), realtime in rounds too; the ros2 node in
# the sim's process (sim+ros2); 11: the MuJoCo peer takes its setpoints in the monolithic loop's blocks (the
# trajectory's block sample, as the node publishes them); 12: the cameras part's realtime in 5 rounds (its
# rounds' drops spread over ±0.3 points: the median of 3 moved by as much as the target);
# 13: forward kinematics (part fk, #46)


@dataclass(frozen=True)
class BenchPlan:
    """How much of each part to run."""

    mono_steps: int  # steps of the monolithic loop (capped at the scenario's)
    mono_repeats: int  # monolithic runs before each run of a variant of the distributed loop
    loop_duration: float | None  # sim seconds of the distributed run (None: the whole scenario)
    loop_repeats: int  # runs of each variant
    rtt_count: int  # timed round trips
    realtime_duration: float  # sim seconds in realtime mode (1 kHz)
    realtime_2khz_duration: float  # sim seconds of the 2 kHz realtime runs
    tda_sizes: tuple[int, ...]
    tda_calls: int  # solves per method and size
    session_counts: tuple[int, ...]
    session_duration: float
    cable_counts: tuple[int, ...]
    cable_duration: float
    startup_repeats: int = 3  # 50-step sessions timed as whole commands, per mode
    ros2_duration: float = 11.0  # sim seconds of each ROS 2- and cdpr-controlled session (ros2 part)
    ros2_repeats: int = 3  # runs of each, alternating
    camera_duration: float = 4.0  # sim seconds of each fast-mode session of the cameras part
    camera_repeats: int = 8  # rounds of (no camera, features, images)
    camera_realtime_duration: float = 15.0  # sim seconds of each realtime session of the cameras part
    camera_realtime_repeats: int = 5  # rounds of (no camera, images) in realtime
    gym_duration: float | None = None  # sim seconds of each episode of the gym part (None: the scenario's)
    gym_rounds: int = 3  # rounds of (monolithic, env) per action space
    gym_session_duration: float = 4.0  # sim seconds of the session-mode episode
    gym_vector_steps: int = 1000  # env steps of each vectorised run (2 envs)


FULL = BenchPlan(
    mono_steps=11000, mono_repeats=1, loop_duration=None, loop_repeats=3, rtt_count=20000,
    realtime_duration=60.0, realtime_2khz_duration=10.0, tda_sizes=(4, 8, 12, 16), tda_calls=3000,
    session_counts=(1, 2, 4, 8), session_duration=6.0, cable_counts=(4, 8, 12, 16), cable_duration=6.0,
)
# A quick look at every part: a few hundred steps per session (each process's CPU per step read over the loop
# even when it prints no progress line: SessionRun), one run of each.
QUICK = BenchPlan(
    mono_steps=300, mono_repeats=1, loop_duration=0.3, loop_repeats=1, rtt_count=1000,
    realtime_duration=0.3, realtime_2khz_duration=0.2, tda_sizes=(4, 8, 16), tda_calls=50,
    session_counts=(1, 2), session_duration=0.3, cable_counts=(4, 16), cable_duration=0.3,
    startup_repeats=1, ros2_duration=0.3, ros2_repeats=1, camera_duration=0.3, camera_repeats=1,
    camera_realtime_duration=0.3, camera_realtime_repeats=1,
    gym_duration=0.3, gym_rounds=1, gym_session_duration=0.3, gym_vector_steps=50,
)


def _log(message: str) -> None:
    sys.stderr.write(f"[bench] {message}\n")
    sys.stderr.flush()
