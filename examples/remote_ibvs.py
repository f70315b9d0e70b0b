"""Image-based visual servoing from another process or machine: tensions from a camera's frames alone.

    cdpr up caroca_15kg_ibvs --without controller             # sim (and its camera `top`), trajectory, clock
    python examples/remote_ibvs.py --connect tcp/HOST:7447 [--camera top] [--goal -0.9 -0.9 1.0 [R P Y]]

The session's cameras come with session/info (``info.cameras``: intrinsics, mount, markers, rate, latency),
their frames on ``sim/camera/<name>`` (``on_camera``: the markers' pixels and depths). Each frame updates the
servo (``cdpr_controller.ibvs.IbvsCore``: the platform's pose fitted to the markers, the classical law
``(v*, w*) = -lambda J+ (s - s*)`` towards the markers' image at the goal); each state is answered with the
tensions that servo the platform's twist to that law. The state says which step to answer and, until the
first frame is in, where the platform starts; the setpoints are not used at all.
"""

import argparse
import sys

import numpy as np

from cdpr.mechanics.rotation import quat_to_matrix, rpy_to_matrix
from cdpr.mechanics.tda import make_tda
from cdpr.runtime.client import RemoteController
from cdpr_controller.ibvs import IbvsCore, desired_image


class RemoteIbvs(RemoteController):
    """IBVS from a session's camera frames (examples/remote_ibvs.py)."""

    def __init__(self, camera, goal, rpy, gain, kv):
        self.camera, self.goal, self.goal_R, self.gain, self.kv = camera, np.array(goal), rpy_to_matrix(*rpy), gain, kv

    def setup(self, info):
        super().setup(info)
        cameras = info.cameras  # rebuilt from session/info at each access
        if self.camera not in cameras:
            sys.exit(f"remote_ibvs: the session has no camera {self.camera!r} (it has: {sorted(cameras)})")
        cam = cameras[self.camera]
        self.servo = IbvsCore(info.robot, cam, desired_image(cam, self.goal, self.goal_R), self.gain, self.kv,
                              0.5, 0.5, make_tda(info.tda), info.dt, self.goal.copy(), self.goal_R.copy())

    def on_camera(self, frame):
        if frame.camera == self.camera:
            self.servo.on_frame(frame)

    def step(self, state, setpoint):
        if self.servo.frame_step < 0:  # no frame yet: held where the session starts it
            self.servo.position, self.servo.rotation = np.array(state.pose[:3]), quat_to_matrix(state.pose[3:])
        return self.servo.step(state.step)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], add_help=False)
    parser.add_argument("--camera", default="top", help="the session's camera to servo from (default: top)")
    parser.add_argument("--goal", type=float, nargs="+", default=[-0.9, -0.9, 1.0], metavar="X",
                        help="the goal pose whose image is the target: x y z [roll pitch yaw] (default: B)")
    parser.add_argument("--gain", type=float, default=1.0, help="lambda, 1/s (default: 1)")
    parser.add_argument("--kv", type=float, default=10.0, help="the twist loop's gain, 1/s (default: 10)")
    args, rest = parser.parse_known_args()
    if len(args.goal) not in (3, 6):
        parser.error("--goal: x y z, or x y z roll pitch yaw")
    RemoteIbvs(args.camera, args.goal[:3], (args.goal[3:] or [0.0, 0.0, 0.0]), args.gain, args.kv).main(rest)
