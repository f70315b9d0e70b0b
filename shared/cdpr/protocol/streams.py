"""The per-step streams of a session, declared once: each column of the sim's state with its width, unit and
meaning, where the recording plots it (Rerun time series) and where the MCAP file carries it (Foxglove JSON
channels).

Everything that handles the state stream is derived from :data:`STATE_COLUMNS`: the ``sim/state`` message and
the states of a ``sim/telemetry`` block (:mod:`cdpr.protocol.messages`), the recorder's rows and Rerun series
(:mod:`cdpr_recorder`), the MCAP schemas and rows (:mod:`cdpr.recording.mcap`), and reading a recording back
(``cdpr report``, ``cdpr convert``). A new state field is one column here, its attribute of
:class:`cdpr.protocol.messages.State` (with a default, so that older senders stay valid), and its producer
in the sim (docs/protocol.md, "Adding a state field").
"""

from __future__ import annotations

from cdpr.columns import ChannelField, Column, Series

# Rerun entity paths of the state's time series (the recording's layout: docs/recording.md)
ACTUAL_POSITION = "actual/position"  # [x, y, z] of the sim state, m
ACTUAL_QUATERNION = "actual/quaternion"  # [qx, qy, qz, qw]
ACTUAL_TWIST = "actual/twist"  # [vx, vy, vz, wx, wy, wz], m/s and rad/s
CABLE_LENGTHS = "actual/cable_lengths"  # m values, m
CLAMPED = "actual/clamped"  # commands clamped by the sim so far
COMMAND_AGE = "latency/command_age"  # steps between the state a command answered and the step it acted on
WATCHDOG = "latency/watchdog"  # 1 on the steps the sim's watchdog policy acted instead of a command
TENSION_SERIES = "tension/cable_{i}"  # one entity per cable (the tension panel's series), N

# Foxglove JSON channels of the state (the MCAP file and the live server: docs/recording.md)
PLATFORM_STATE = "/platform/state"
LENGTHS = "/cables/lengths"
TENSIONS = "/cables/tensions"
COMMAND_TIMING = "/command/timing"  # the command age and the watchdog (Foxglove channel)


STATE_COLUMNS: tuple[Column, ...] = (
    Column("pose", 7, "m, 1", "x, y, z of the centre of mass and the quaternion qx, qy, qz, qw (platform to "
           "world), world frame",
           series=(Series(ACTUAL_POSITION, 0, 3), Series(ACTUAL_QUATERNION, 3, 7)),
           fields=(ChannelField(PLATFORM_STATE, "position", 0, 3), ChannelField(PLATFORM_STATE, "quaternion", 3, 7))),
    Column("twist", 6, "m/s, rad/s", "vx, vy, vz, wx, wy, wz, world frame",
           series=(Series(ACTUAL_TWIST),), fields=(ChannelField(PLATFORM_STATE, "twist"),)),
    Column("cable_lengths", None, "m", "the geometric cable lengths ‖a_i − t − R b_i‖, cable 0 first",
           series=(Series(CABLE_LENGTHS),), fields=(ChannelField(LENGTHS, "lengths"),)),
    Column("tensions", None, "N", "the tensions the sim applied over [t − dt, t] (zeros at step 0), cable 0 first",
           since=1, series=(Series(TENSION_SERIES),), fields=(ChannelField(TENSIONS, "tensions"),)),
    Column("clamped", 1, "", "commands clamped by the sim so far", integer=True, default=0,
           series=(Series(CLAMPED),), fields=(ChannelField(PLATFORM_STATE, "clamped"),)),
    Column("command_age", 1, "steps", "the age of the command that acted over [t − dt, t]: k − 1 − j for the "
           "command answering state j (0 in lock-step without latency; docs/realtime.md)", integer=True,
           default=0, since=1, series=(Series(COMMAND_AGE),), fields=(ChannelField(COMMAND_TIMING, "age"),)),
    Column("watchdog", 1, "", "1 if the sim's watchdog policy acted over [t − dt, t] instead of a command",
           integer=True, default=0, since=1, series=(Series(WATCHDOG),),
           fields=(ChannelField(COMMAND_TIMING, "watchdog"),)),
)
STATE = {c.name: c for c in STATE_COLUMNS}

# The estimate a controller fed from the sensors answers (controller.feedback: sensors): ``Command.estimate``,
# carried on in the sim's telemetry; the recording's and the summary's ``estimate/*``, beside ``actual/*``.
ESTIMATE_POSITION = "estimate/position"  # [x, y, z] the controller estimated, m
ESTIMATE_QUATERNION = "estimate/quaternion"  # [qx, qy, qz, qw]
ESTIMATE_TWIST = "estimate/twist"  # [vx, vy, vz, wx, wy, wz], m/s and rad/s
ESTIMATE_ERROR_POSITION = "estimate/error/position"  # ‖estimated − actual‖ of the centre of mass, m
ESTIMATE_ERROR_ORIENTATION = "estimate/error/orientation"  # the angle between the two orientations, rad
PLATFORM_ESTIMATE = "/platform/estimate"  # Foxglove JSON channel

ESTIMATE_COLUMNS: tuple[Column, ...] = (
    Column("pose", 7, "m, 1", "the controller's estimate of the pose of state k: x, y, z of the centre of mass and "
           "the quaternion qx, qy, qz, qw, world frame",
           series=(Series(ESTIMATE_POSITION, 0, 3), Series(ESTIMATE_QUATERNION, 3, 7)),
           fields=(ChannelField(PLATFORM_ESTIMATE, "position", 0, 3),
                   ChannelField(PLATFORM_ESTIMATE, "quaternion", 3, 7))),
    Column("twist", 6, "m/s, rad/s", "the controller's estimate of the twist of state k: vx, vy, vz, wx, wy, wz, "
           "world frame", series=(Series(ESTIMATE_TWIST),), fields=(ChannelField(PLATFORM_ESTIMATE, "twist"),)),
)
ESTIMATE_WIDTH = sum(c.width or 0 for c in ESTIMATE_COLUMNS)  # numbers of Command.estimate: 13
# what the recording derives from the estimate and the state of the same step
ESTIMATE_ERROR_COLUMNS: tuple[Column, ...] = (
    Column("position_error", 1, "m", "‖estimated − actual‖ of the centre of mass at step k",
           series=(Series(ESTIMATE_ERROR_POSITION),), fields=(ChannelField(PLATFORM_ESTIMATE, "position_error"),)),
    Column("orientation_error", 1, "rad", "the angle of the rotation from the actual to the estimated orientation",
           series=(Series(ESTIMATE_ERROR_ORIENTATION),),
           fields=(ChannelField(PLATFORM_ESTIMATE, "orientation_error"),)),
)
