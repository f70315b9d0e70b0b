"""``cdpr convert FILE.rrd --to rosbag2``: a recording as a ROS 2 bag (MCAP storage, CDR), for ``ros2 bag play``.

The topics and stamps are the ros2 node's (docs/ros2.md), written with its own encoders, so a bag played back
looks like the live session to a ROS 2 node: every recorded state as ``/clock``, ``joint_states``,
``platform/pose``, ``platform/twist`` and ``/tf``; every setpoint as ``setpoint/pose``; every command as
``joint_commands`` (the controller's answer, stamped with the state it answered); the sensors as ``imu`` and
``sensors/joint_states``; ``session_info`` once, latched. A recording keeps the setpoint's pose only, so
``setpoint/twist`` and ``setpoint/accel`` are not in a bag. Each message's bag timestamp is its stamp (sim
time). The bag directory (``metadata.yaml`` and the ``.mcap``) is written by the ``rosbags`` library.
"""

from __future__ import annotations

import shutil
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from cdpr.errors import InputError


def rrd_to_rosbag2(rrd: str | Path, out: str | Path, namespace: str = "/cdpr") -> dict[str, Any]:
    """Write the cdpr recording ``rrd`` as the ROS 2 bag directory ``out``; what was written, JSON-ready."""
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    from cdpr import recording
    from cdpr.mechanics.kinematics import length_rates
    from cdpr.mechanics.rotation import quat_to_matrix
    from cdpr.protocol import PROTOCOL_VERSION
    from cdpr.ros2 import messages as ros
    from cdpr.ros2.cdr import stamp
    from cdpr.ros2.graph import qualify
    from cdpr.ros2.topics import (
        PUBLISHED,
        SENSOR_TOPIC_KIND,
        cable_names,
        info_message,
        sensor_delays,
        sensor_messages,
        setpoint_messages,
        state_messages,
    )
    from cdpr.tools.report import read_recording, sensor_columns, session_of, state_columns

    src, dst = Path(rrd), Path(out)
    if dst.exists():
        if not (dst / "metadata.yaml").is_file():
            raise InputError(f"-o: {dst} exists and is not a ROS 2 bag (no metadata.yaml): not overwritten")
        shutil.rmtree(dst)  # a bag written before: replaced, as a converted .mcap is
    data = read_recording(src)
    session = data.session
    info, robot, dt, m = session_of(data, "a bag")
    output = info.get("controller", {}).get("output", "tensions")
    names = cable_names(m)
    get = data.get
    k = get(recording.ACTUAL_POSITION).step
    try:
        cols = state_columns(data, k, m)
        desired = get(recording.DESIRED_POSITION)
        dq = get(recording.DESIRED_QUATERNION).at(desired.step)
        feasible = get(recording.COMMAND_FEASIBLE)
        commands = get(recording.COMMAND_LENGTHS if output == "lengths" else recording.COMMAND_TENSIONS)
        command_values = commands.at(feasible.step)
        sensor_steps, readings = sensor_columns(data, m)
    except KeyError as exc:
        raise InputError(f"{src}: incomplete recording: no data for step {exc.args[0]}") from None

    # (bag time ns, topic, payload)
    rows: list[tuple[int, str, bytes]] = [(0, "session_info", info_message({"v": PROTOCOL_VERSION, **info}, m))]
    for i, step in enumerate(k.tolist()):
        pose, twist = cols["pose"][i], cols["twist"][i]
        rates = length_rates(robot, pose[:3], quat_to_matrix(pose[3:]), twist)  # as the ros2 node's (cdpr_ros2.core)
        rows += [(_ns(step * dt), name, payload) for name, payload in state_messages(
            step * dt, names, pose.tolist(), twist.tolist(), cols["cable_lengths"][i].tolist(),
            rates.tolist(), cols["tensions"][i].tolist())]
    for step, position, q in zip(desired.step.tolist(), desired.values, dq, strict=True):
        rows += [(_ns(step * dt), name, payload)
                 for name, payload in setpoint_messages(step * dt, (*position, *q), None, None)]
    for step, values in zip(feasible.step.tolist(), command_values.tolist(), strict=True):
        lengths, tensions = (values, []) if output == "lengths" else ([], values)
        rows.append((_ns(step * dt), "joint_commands", ros.joint_state(stamp(step * dt), names, lengths, [], tensions)))
    delays = sensor_delays(info)
    for i, step in enumerate(sensor_steps.tolist()):
        reading = {name: v[i].tolist() for name, v in readings.items() if not np.isnan(v[i, 0])}
        rows += [(_ns(max(0.0, step * dt - delays.get(SENSOR_TOPIC_KIND[name], 0.0))), name, payload)
                 for name, payload in sensor_messages(step * dt, names, reading, delays)]  # at their stamps
    rows.sort(key=lambda r: r[0])  # a bag's messages in time order (stable: a step's topics keep theirs)

    topics = {name: (qualify(namespace, t.name), t.ros_type, t.qos.transient_local) for name, t in PUBLISHED.items()}
    topics["joint_commands"] = (qualify(namespace, "joint_commands"), "sensor_msgs/msg/JointState", False)
    store = get_typestore(Stores.ROS2_JAZZY)
    forever = QosTime(sec=0, nsec=0)
    latched = Qos(QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL, forever, forever,
                  QosLiveliness.AUTOMATIC, forever, False)
    counts: Counter[str] = Counter()
    dst.parent.mkdir(parents=True, exist_ok=True)
    try:
        with Writer(dst, version=9, storage_plugin=StoragePlugin.MCAP) as bag:
            present = {r[1] for r in rows}
            connections = {name: bag.add_connection(topic, ros_type, typestore=store,
                                                    offered_qos_profiles=[latched] if keep else [])
                           for name, (topic, ros_type, keep) in topics.items() if name in present}
            for ns, name, payload in rows:
                bag.write(connections[name], ns, payload)
                counts[topics[name][0]] += 1
    except BaseException:
        shutil.rmtree(dst, ignore_errors=True)  # no half-written bag left behind
        raise
    return {"input": str(src), "output": str(dst), "format": "rosbag2", "storage": "mcap",
            "recording_id": data.recording_id, "scenario": session.get("scenario"), "states": len(k),
            "messages": sum(counts.values()), "topics": dict(sorted(counts.items())),
            "bytes": sum(f.stat().st_size for f in dst.iterdir())}


def _ns(t: float) -> int:
    return int(np.int64(round(t * 1e9)))
