"""Planar robots in either plane (#32): the vertical x–z plane (gravity in it) and the horizontal x–y plane
(gravity out of it, as CASPR's planar robots lie), with a planar inertia given as one number."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from cdpr.config.robot import load_robot
from cdpr.errors import InputError
from cdpr.mechanics.control import controlled_rows
from cdpr.mechanics.kinematics import forward_kinematics, inverse_kinematics
from cdpr.mechanics.rotation import rotvec_to_matrix
from cdpr.mechanics.workspace import compute_workspace
from cdpr.protocol.session import robot_from_summary
from conftest import cdpr, last_json_line

SHIPPED = Path(__file__).parents[1] / "shared" / "cdpr" / "robots"


def test_a_horizontal_robot_controls_x_y_and_the_turn_about_z() -> None:
    robot = load_robot("planar_xy_4")
    assert (robot.mode, robot.plane, robot.dof, robot.normal_axis) == ("planar", "xy", 3, 2)
    assert robot.controlled_rows == (0, 1, 5)
    assert controlled_rows(robot, "3dof") == (0, 1)  # the forces in its plane
    assert np.array_equal(robot.inertia, np.eye(3) * 10.0)  # one number: the moment about the normal
    vertical = load_robot("kntu_planar")
    assert (vertical.plane, vertical.controlled_rows, controlled_rows(vertical, "3dof")) == ("xz", (0, 2, 4),
                                                                                             (0, 1, 2))
    again = robot_from_summary(robot.summary())
    assert (again.plane, again.controlled_rows) == ("xy", (0, 1, 5))
    assert "plane" not in load_robot("caroca").summary()


def test_forward_kinematics_and_the_workspace_stay_in_the_plane() -> None:
    robot = load_robot("planar_xy_4")
    p, R = np.array([0.62, 0.41, 0.0]), rotvec_to_matrix([0.0, 0.0, 0.12])
    lengths = inverse_kinematics(robot, p, R).lengths
    fk = forward_kinematics(robot, lengths)
    assert fk.converged
    np.testing.assert_allclose(fk.position, p, atol=1e-9)
    np.testing.assert_allclose(fk.rotation, R, atol=1e-9)
    ws = compute_workspace(robot, 0.1)
    assert ws.shape[2] == 1
    assert np.all(ws.points[:, 2] == 0.0)
    assert 0.2 < ws.fraction < 1.0


def _robot_file(tmp_path: Path, change: dict) -> Path:
    """The shipped planar_xy_4 with ``change`` (dotted paths; None deletes the key), as a file."""
    spec = yaml.safe_load((SHIPPED / "planar_xy_4.yaml").read_text())
    for dotted, value in change.items():
        *path, last = dotted.split(".")
        node = spec
        for key in path:
            node = node[int(key)] if isinstance(node, list) else node[key]
        if value is None:
            del node[last]
        else:
            node[last] = value
    out = tmp_path / "robot.yaml"
    out.write_text(yaml.safe_dump(spec))
    return out


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"cables.2.frame": [1.0, 1.0, 0.1]}, "cables: a planar robot lives in the x–y plane: every z must be 0"),
        ({"home.position": [0.5, 0.5, 0.2]}, "home.position: a planar robot lives in the x–y plane: every z must "
                                             "be 0"),
        ({"platform.com": [0.0, 0.0, 0.1]}, "platform.com: a planar robot lives in the x–y plane: every z must be 0"),
        ({"mode": "spatial", "plane": None, "platform.inertia": 10.0}, "platform.inertia: one number is a planar"),
        ({"mode": "point_mass", "plane": "xy"}, "plane: only a planar robot has a plane"),
        ({"plane": "yz"}, "plane"),
        ({"platform.inertia": -1.0}, "platform.inertia: must be > 0"),
    ],
)
def test_bad_planar_files_name_the_field(tmp_path: Path, change: dict, message: str) -> None:
    path = _robot_file(tmp_path, change)
    with pytest.raises(InputError) as err:
        load_robot(path)
    assert message in str(err.value)
    assert str(err.value).startswith(str(path))


@pytest.mark.parametrize(("scenario", "plane"), [("planar_xy_4", "xy"), ("kntu_planar", "xz")])
def test_a_planar_session_tracks_its_trajectory(scenario: str, plane: str) -> None:
    """A real session of each plane: the x–y robot moves and turns in the horizontal plane with its weight out of
    the plane, the x–z robot in the vertical one. The x–z session as separate processes, the x–y one with its nodes
    in one process (`--in-process`: the same nodes and messages, the same states as separate processes)."""
    proc = cdpr("run", scenario, *(["--in-process"] if plane == "xy" else []), timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    s = last_json_line(proc.stdout)
    assert s["exit_ok"]
    assert s["max_position_error"] < 1e-4, s
    assert s["max_orientation_error"] < 1e-4, s
    assert (s["clamped_commands"], s["infeasible_commands"]) == (0, 0)
    assert load_robot(yaml.safe_load((SHIPPED.parent / "scenarios" / f"{scenario}.yaml").read_text())["robot"]
                      ).plane == plane
