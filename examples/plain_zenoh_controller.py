"""A cdpr controller written from docs/protocol.md alone: Zenoh, msgpack and numpy, no cdpr import.

    python examples/plain_zenoh_controller.py --connect tcp/HOST:7447 [--session ID]

PD on the pose error scaled by the platform's mass and inertia, plus gravity compensation; the
wrench is turned into tensions by least norm, with the cables that would go slack held at tmin. Port it
to any language with a Zenoh binding and a msgpack library: nothing else is needed.
"""

import argparse
import json
import queue
import signal
import threading

import msgpack
import numpy as np
import zenoh

KP, KD, GRAVITY = 400.0, 40.0, 9.81  # 1/s², 1/s (critically damped at 20 rad/s), m/s²
ROWS = {"spatial": [0, 1, 2, 3, 4, 5], "planar": [0, 2, 4], "point_mass": [0, 1, 2]}
PLANE_ROWS = {"xz": [0, 2, 4], "xy": [0, 1, 5]}  # a planar robot's rows, by its plane


def exit_points(a, B, pulleys):
    """Where each cable leaves the frame for the platform points B: a_i, or over an exit pulley its tangent point
    (docs/robots.md, "Exit pulleys")."""
    if pulleys is None:
        return a
    r, u = np.array(pulleys["radius"]), np.array(pulleys["axis"])
    v = B - a
    along = np.einsum("ij,ij->i", v, u)
    across = v - along[:, None] * u
    n = np.linalg.norm(across, axis=1)
    e = across / np.maximum(n, 1e-300)[:, None]
    phi = np.arctan2(along, n - r) + np.arccos(r / np.hypot(n - r, along))
    return a + r[:, None] * ((1 + np.cos(phi))[:, None] * e + np.sin(phi)[:, None] * u)


def quat_to_matrix(q):
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def rotation_vector(R):
    """log(R) as a rotation vector (fine away from half turns, which a tracking error never is)."""
    v = 0.5 * np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    s, c = np.linalg.norm(v), np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    return v if s < 1e-12 else v * (np.arctan2(s, c) / s)


def tensions(W, w, tmin, tmax):
    """Least-norm f with W f = w; a cable that would pull less than its tmin is held at it, and again."""
    f, free = np.array(tmin, dtype=float), np.ones(W.shape[1], dtype=bool)
    while free.sum() >= W.shape[0]:
        f[free] = np.linalg.pinv(W[:, free]) @ (w - W[:, ~free] @ f[~free])
        low = np.flatnonzero(free & (f < tmin))
        if low.size == 0:
            break
        worst = low[np.argmin((f - tmin)[low])]
        f[worst], free[worst] = tmin[worst], False
    return np.clip(f, tmin, tmax)


class Controller:
    """The control law, built from the session's `session/info` map."""

    def __init__(self, info):
        robot = info["robot"]
        self.a, self.b = np.array(robot["frame_points"]), np.array(robot["platform_points"])
        self.mass, self.inertia = robot["mass"], np.array(robot["inertia"])
        limits = robot["cable_limits"]  # each cable's own [tmin, tmax]
        self.tmin, self.tmax = np.array(limits["tmin"]), np.array(limits["tmax"])
        self.pulleys = robot.get("pulleys")
        three = info.get("controller", {}).get("variant") == "3dof"
        rows = PLANE_ROWS[robot.get("plane", "xz")] if robot["mode"] == "planar" else ROWS[robot["mode"]]
        self.rows = [r for r in rows if r < 3] if three and robot.get("plane") == "xy" else [0, 1, 2] if three else rows

    def __call__(self, state, setpoint):
        p, R = np.array(state["pose"][:3]), quat_to_matrix(state["pose"][3:])
        R_d = quat_to_matrix(setpoint["pose"][3:])
        e = np.r_[np.subtract(setpoint["pose"][:3], p), rotation_vector(R_d @ R.T)]  # position, orientation
        accel = KP * e + KD * np.subtract(setpoint["twist"], state["twist"])
        w = np.r_[self.mass * accel[:3], R @ self.inertia @ R.T @ accel[3:]]  # mass-scaled PD
        w[2] += self.mass * GRAVITY  # the cables also carry the weight
        rb = self.b @ R.T  # platform points in the world frame, relative to the centre of mass
        d = exit_points(self.a, p + rb, self.pulleys) - p - rb
        d /= np.linalg.norm(d, axis=1, keepdims=True)  # unit vectors from the platform to the frame
        W = np.vstack([d.T, np.cross(rb, d).T])  # column i: the wrench of a unit tension in cable i
        return tensions(W[self.rows], w[self.rows], self.tmin, self.tmax)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--connect", action="append", default=[], help="router endpoint (tcp/127.0.0.1:7447)")
    parser.add_argument("--session", default="default")
    args = parser.parse_args()
    prefix = f"cdpr/{args.session}"
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps(args.connect or ["tcp/127.0.0.1:7447"]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/timeout_ms", '{"client": 30000}')  # the router may start after us
    conf.insert_json5("connect/retry", '{"period_init_ms": 100, "period_max_ms": 1000}')
    stop = threading.Event()
    inbox = queue.SimpleQueue()

    def on_signal(*_):  # also wake the wait below: a signal alone may leave it waiting for the next message
        stop.set()
        inbox.put(None)

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, on_signal)
    with zenoh.open(conf) as session:
        info = None  # 1. the robot and dt, from the session's clock (retried until it answers)
        while info is None and not stop.is_set():
            for reply in session.get(f"{prefix}/session/info", timeout=2.0):
                if reply.ok is not None:
                    info = msgpack.unpackb(reply.ok.payload.to_bytes())
            if info is None:
                stop.wait(0.5)
        if info is None:
            return 130
        control = Controller(info)
        # 2. subscribe, then hold the liveliness token
        def on_sample(sample, name):
            inbox.put((name, sample.payload.to_bytes()))

        subs = [session.declare_subscriber(f"{prefix}/{name}", lambda s, n=name: on_sample(s, n))
                for name in ("sim/state", "trajectory/setpoints", "clock/status")]
        pub = session.declare_publisher(f"{prefix}/controller/command", priority=zenoh.Priority.REAL_TIME,
                                        congestion_control=zenoh.CongestionControl.BLOCK, express=True)
        token = session.liveliness().declare_token(f"{prefix}/alive/controller")
        setpoints, waiting, answered, code = {}, None, -1, 130
        while not stop.is_set():  # 3. answer state k once setpoint k is there; answer a repeated state again
            try:
                item = inbox.get(timeout=0.2)
            except queue.Empty:
                continue
            if item is None:
                continue
            name, payload = item
            msg = msgpack.unpackb(payload)
            if name == "clock/status":
                if msg["state"] in ("finished", "aborted"):
                    code = 0 if msg["state"] == "finished" else 1
                    break
                continue
            if name == "trajectory/setpoints":  # a block: row i is the setpoint of step first + i
                for i, t in enumerate(msg["t"]):
                    setpoints[msg["first"] + i] = {"t": t, "pose": msg["pose"][7 * i:7 * i + 7],
                                                   "twist": msg["twist"][6 * i:6 * i + 6]}
                state = waiting
                if state is None or state["step"] <= answered:
                    continue
            else:
                state = msg
            k = state["step"]
            if k not in setpoints:
                waiting = state
                continue
            waiting = None
            f = control(state, setpoints[k])
            pub.put(msgpack.packb({"v": 2, "step": k, "t": state["t"], "tensions": f.tolist()}))
            answered = max(answered, k)
            setpoints.pop(k - 1, None)
        token.undeclare()
        for s in subs:
            s.undeclare()
        print(f"answered up to step {answered}", flush=True)
        return code


if __name__ == "__main__":
    raise SystemExit(main())
