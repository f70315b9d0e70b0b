"""Remote PD + gravity compensation on cdpr.runtime.client: python remote_controller.py --connect tcp/HOST:7447"""
import numpy as np

from cdpr.mechanics.dynamics import gravity_wrench, mass_matrix
from cdpr.mechanics.kinematics import inverse_kinematics
from cdpr.mechanics.rotation import orientation_error, quat_to_matrix
from cdpr.mechanics.tda import make_tda
from cdpr.runtime.client import RemoteController


class PDGravity(RemoteController):
    def setup(self, info):  # mass-scaled gains, critically damped at 20 rad/s on every axis; QP tensions
        self.robot, self.rows, self.tda, self.kp, self.kd = info.robot, info.rows, make_tda("qp"), 400.0, 40.0

    def step(self, state, setpoint):
        R, R_d, robot = quat_to_matrix(state.pose[3:]), quat_to_matrix(setpoint.pose[3:]), self.robot
        e = np.r_[np.subtract(setpoint.pose[:3], state.pose[:3]), orientation_error(R_d, R)]
        M = mass_matrix(robot, R)  # 6×6 (3×3 for a point mass)
        w = M @ (self.kp * e + self.kd * np.subtract(setpoint.twist, state.twist))[: len(M)]
        W = inverse_kinematics(robot, state.pose[:3], R).wrench_matrix[self.rows]
        return self.tda.solve(W, (w - gravity_wrench(robot))[self.rows], robot.tmin, robot.tmax)


if __name__ == "__main__":
    PDGravity().main()
