"""SDF export (cdpr.tools.sdf, `cdpr export-sdf`): every link and joint against the robot file, then DART.

The XML is read back with xml.etree and compared number by number with the robot (mass, inertia, attach
points, joint frames and limits); DART's own SDF parser then loads it, and the tree version, closed
with ball-joint constraints at the platform points, must hold the platform still under the tensions the
project's QP computes for it, and let it fall without them.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import dartpy as dart
import numpy as np
import pytest

from cdpr.config.robot import load_robot, shipped_robots
from cdpr.mechanics.dynamics import gravity_wrench
from cdpr.mechanics.kinematics import inverse_kinematics
from cdpr.mechanics.robot import Robot
from cdpr.mechanics.rotation import rpy_to_matrix
from cdpr.mechanics.tda import make_tda
from cdpr.tools.sdf import LINK_MASS, matrix_to_rpy, sdf_string, sdf_world, write_sdf
from conftest import cdpr, last_json_line

ROBOTS = [name for name in shipped_robots() if load_robot(name).pulleys is None] + sorted(
    str(p) for p in (Path(__file__).parent / "robots" / "valid").glob("*.yaml")
)  # (a robot with exit pulleys has no SDF: test_a_robot_with_pulleys_is_refused)


def test_a_robot_with_pulleys_is_refused() -> None:
    proc = cdpr("export-sdf", "caroca_pulleys", "-o", "-", timeout=60)
    assert proc.returncode == 2
    assert "caroca_pulleys: exit pulleys: the SDF's U-P-S legs pivot at fixed frame points" in proc.stderr


def nums(el: ET.Element | None) -> np.ndarray:
    assert el is not None
    assert el.text is not None
    return np.array([float(x) for x in el.text.split()])


def pose(el: ET.Element) -> tuple[np.ndarray, np.ndarray]:
    """(position, rotation) of an element's <pose>."""
    p = nums(el.find("pose"))
    assert p.shape == (6,)
    return p[:3], rpy_to_matrix(*p[3:])


def model_of(robot: Robot, close_loops: bool = True) -> ET.Element:
    root = ET.fromstring(sdf_string(robot, close_loops))
    assert root.tag == "sdf"
    assert root.get("version") == "1.6"
    model = root.find("world/model")
    assert model is not None
    return model


def by_name(model: ET.Element, tag: str) -> dict[str, ET.Element]:
    return {el.get("name"): el for el in model.findall(tag)}


def test_rpy_round_trip() -> None:
    rng = np.random.default_rng(1)
    for rpy in [*rng.uniform(-3.0, 3.0, (50, 3)), [0.3, np.pi / 2, 0.0], [0.3, -np.pi / 2, 0.2]]:
        R = rpy_to_matrix(*rpy)
        np.testing.assert_allclose(rpy_to_matrix(*matrix_to_rpy(R)), R, atol=1e-12)


@pytest.mark.parametrize("name", ROBOTS, ids=lambda r: Path(r).stem)
def test_links_and_joints_match_the_robot_file(name: str) -> None:
    robot = load_robot(name)
    m = robot.m
    model = model_of(robot)
    links, joints = by_name(model, "link"), by_name(model, "joint")
    legs = [f"cable_{i}_{part}" for i in range(m) for part in ("upper", "lower")]
    assert set(links) == {"frame", "platform", *legs}
    assert len(model.findall("link")) == 2 + 2 * m
    expected = {"frame_fixed": ("fixed", "world", "frame")}
    for i in range(m):
        expected[f"cable_{i}_universal"] = ("universal", "frame", f"cable_{i}_upper")
        expected[f"cable_{i}"] = ("prismatic", f"cable_{i}_upper", f"cable_{i}_lower")
        expected[f"cable_{i}_ball"] = ("ball", f"cable_{i}_lower", "platform")
    got = {n: (j.get("type"), j.findtext("parent"), j.findtext("child")) for n, j in joints.items()}
    assert got == expected
    assert len(model.findall("joint")) == 1 + 3 * m

    # The platform: home pose, mass and the full inertia about the centre of mass.
    platform = links["platform"]
    p, R = pose(platform)
    np.testing.assert_allclose(p, robot.home_position, atol=1e-12)
    np.testing.assert_allclose(R, robot.home_rotation, atol=1e-12)
    assert float(platform.findtext("inertial/mass")) == robot.mass
    np.testing.assert_array_equal(nums(platform.find("inertial/pose")), np.zeros(6))
    moments = {
        k: float(platform.findtext(f"inertial/inertia/{k}"))
        for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
    }
    full = np.array([[moments[f"i{a}{b}" if f"i{a}{b}" in moments else f"i{b}{a}"] for b in "xyz"] for a in "xyz"])
    np.testing.assert_array_equal(full, robot.inertia)
    geometry = platform.find(f"visual/geometry/{robot.shape.type}")
    assert geometry is not None
    size = (
        nums(geometry.find("size"))
        if robot.shape.type == "box"
        else np.array(
            [float(geometry.findtext(t)) for t in ("radius", "length") if geometry.find(t) is not None]
        )
    )
    np.testing.assert_array_equal(size, robot.shape.size)

    # The legs, cable by cable, against the inverse kinematics at the home pose.
    ik = inverse_kinematics(robot, robot.home_position, robot.home_rotation)
    for i in range(m):
        upper, lower = links[f"cable_{i}_upper"], links[f"cable_{i}_lower"]
        pu, Ru = pose(upper)
        pl, Rl = pose(lower)
        np.testing.assert_allclose(pu, robot.frame_points[i], atol=1e-12)
        np.testing.assert_allclose(pl, ik.platform_points_world[i], atol=1e-12)
        np.testing.assert_allclose(Ru, Rl, atol=1e-12)
        np.testing.assert_allclose(Ru[:, 2], -ik.directions[i], atol=1e-12)  # leg z: from a_i to the platform
        for link in (upper, lower):
            assert float(link.findtext("inertial/mass")) == LINK_MASS

        universal = joints[f"cable_{i}_universal"]
        np.testing.assert_array_equal(nums(universal.find("pose")), np.zeros(6))  # at a_i
        np.testing.assert_array_equal(nums(universal.find("axis/xyz")), [1, 0, 0])
        np.testing.assert_array_equal(nums(universal.find("axis2/xyz")), [0, 1, 0])
        for tag in ("axis", "axis2"):
            assert float(universal.findtext(f"{tag}/dynamics/damping")) == robot.passive_damping

        prismatic = joints[f"cable_{i}"]
        # axis −z of the leg frame, expressed in the world: from the platform point towards a_i.
        axis_world = Rl @ nums(prismatic.find("axis/xyz"))
        np.testing.assert_allclose(axis_world, ik.directions[i], atol=1e-12)
        assert float(prismatic.findtext("axis/limit/effort")) == robot.tmax[i]
        assert float(prismatic.findtext("axis/limit/velocity")) == robot.max_speed
        assert float(prismatic.findtext("axis/dynamics/damping")) == robot.cable_damping
        lo, hi = float(prismatic.findtext("axis/limit/lower")), float(prismatic.findtext("axis/limit/upper"))
        assert hi == pytest.approx(ik.lengths[i], abs=1e-12)  # position l_home − l: l = 0 at the top
        assert hi - lo == pytest.approx(robot.max_length[i], abs=1e-12)

        ball = joints[f"cable_{i}_ball"]
        bp, bR = pose(ball)  # in the child's (platform's) frame: b_i
        np.testing.assert_allclose(bp, robot.platform_points[i], atol=1e-12)
        np.testing.assert_allclose(bR, np.eye(3), atol=1e-12)
        assert float(ball.findtext("axis/dynamics/damping")) == robot.passive_damping
        # The joint meets the leg's end: platform pose ∘ b_i is the lower link's origin.
        np.testing.assert_allclose(p + R @ bp, pl, atol=1e-12)


@pytest.mark.parametrize("name", ROBOTS, ids=lambda r: Path(r).stem)
def test_the_tree_version_only_drops_the_ball_joints(name: str) -> None:
    robot = load_robot(name)
    closed, tree = sdf_world(robot, close_loops=True), sdf_world(robot, close_loops=False)
    closed_model = closed.find("world/model")
    assert closed_model is not None
    for ball in [j for j in closed_model.findall("joint") if j.get("type") == "ball"]:
        closed_model.remove(ball)
    assert ET.tostring(closed) == ET.tostring(tree)


def load_dart(path: Path) -> dart.simulation.World:
    world = dart.utils.SdfParser.readWorld(dart.common.Uri(str(path)))
    assert world.getNumSkeletons() == 1
    return world


@pytest.mark.parametrize("name", ROBOTS, ids=lambda r: Path(r).stem)
def test_dart_loads_the_tree_version(name: str, tmp_path: Path) -> None:
    robot = load_robot(name)
    world = load_dart(write_sdf(robot, tmp_path / f"{Path(name).stem}.sdf", close_loops=False))
    np.testing.assert_allclose(world.getGravity(), [0.0, 0.0, -9.81])
    assert world.getTimeStep() == 0.001
    sk = world.getSkeleton(0)
    m = robot.m
    assert sk.getNumBodyNodes() == 2 + 2 * m
    assert sk.getNumJoints() == 2 + 2 * m  # frame_fixed, m universal, m prismatic, the platform's free root
    assert sk.getNumDofs() == 3 * m + 6
    platform = sk.getBodyNode("platform")
    assert platform.getMass() == robot.mass
    assert platform.getParentJoint().getType() == "FreeJoint"
    np.testing.assert_allclose(platform.getInertia().getMoment(), robot.inertia)
    np.testing.assert_allclose(platform.getTransform().translation(), robot.home_position, atol=1e-12)
    assert sk.getJoint("frame_fixed").getType() == "WeldJoint"
    ik = inverse_kinematics(robot, robot.home_position, robot.home_rotation)
    for i in range(m):
        upper, lower = sk.getBodyNode(f"cable_{i}_upper"), sk.getBodyNode(f"cable_{i}_lower")
        assert upper.getParentJoint().getType() == "UniversalJoint"
        np.testing.assert_allclose(upper.getTransform().translation(), robot.frame_points[i], atol=1e-12)
        np.testing.assert_allclose(
            lower.getTransform().translation(), ik.platform_points_world[i], atol=1e-12
        )
        prismatic = sk.getJoint(f"cable_{i}")
        assert (
            prismatic.getType() == "PrismaticJoint"
        )
        assert (
            prismatic.getParentBodyNode().getName() == f"cable_{i}_upper"
        )
        np.testing.assert_allclose(
            lower.getTransform().rotation() @ prismatic.getAxis(), ik.directions[i], atol=1e-12
        )
        assert prismatic.getDampingCoefficient(0) == robot.cable_damping
        assert prismatic.getPositionUpperLimit(0) == pytest.approx(ik.lengths[i], abs=1e-12)
        assert lower.getMass() == LINK_MASS


@pytest.mark.parametrize("name", ROBOTS, ids=lambda r: Path(r).stem)
def test_dart_keeps_one_closing_joint_of_the_full_version(name: str, tmp_path: Path) -> None:
    """DART's parser builds trees: of the m ball joints whose child is the platform it keeps the first
    and drops the others (with an error message each). What is left loads and is consistent."""
    robot = load_robot(name)
    sk = load_dart(write_sdf(robot, tmp_path / f"{Path(name).stem}.sdf")).getSkeleton(0)
    assert sk.getNumBodyNodes() == 2 + 2 * robot.m
    assert sk.getNumJoints() == 2 + 2 * robot.m  # the free root is replaced by cable_0_ball
    platform = sk.getBodyNode("platform")
    assert platform.getMass() == robot.mass
    joint = platform.getParentJoint()
    assert (joint.getType(), joint.getName(), joint.getParentBodyNode().getName()) == (
        "BallJoint",
        "cable_0_ball",
        "cable_0_lower",
    )
    np.testing.assert_allclose(platform.getTransform().translation(), robot.home_position, atol=1e-9)


@pytest.mark.parametrize("name", ["caroca", "cogiro", "point_mass_4", "kntu_planar"])
def test_in_dart_the_static_tensions_hold_the_platform(name: str, tmp_path: Path) -> None:
    """Tree version + one BallJointConstraint per cable at the platform point: the closed U-P-S
    mechanism of the paper. With each prismatic effort set to the QP's static tension (the SDF says
    effort = tension) the platform does not move; with no tension it falls at g."""
    robot = load_robot(name)
    ik = inverse_kinematics(robot, robot.home_position, robot.home_rotation)
    rows = list(robot.controlled_rows)
    w = -gravity_wrench(robot)
    tensions = make_tda("qp").solve(
        ik.wrench_matrix[rows], w if robot.mode == "point_mass" else w[rows], robot.tmin, robot.tmax
    )
    assert tensions.feasible

    def accel_after_one_step(f: np.ndarray) -> np.ndarray:
        world = load_dart(write_sdf(robot, tmp_path / "tree.sdf", close_loops=False))
        sk = world.getSkeleton(0)
        platform = sk.getBodyNode("platform")
        for i in range(robot.m):
            lower = sk.getBodyNode(f"cable_{i}_lower")
            world.getConstraintSolver().addConstraint(
                dart.constraint.BallJointConstraint(lower, platform, ik.platform_points_world[i])
            )
        for j in range(sk.getNumJoints()):  # DART's implicit joint damping eats tension on light links
            joint = sk.getJoint(j)
            for k in range(joint.getNumDofs()):
                joint.setDampingCoefficient(k, 0.0)
        for i in range(robot.m):
            sk.getJoint(f"cable_{i}").setForce(0, float(f[i]))
        world.step()
        return platform.getLinearVelocity() / world.getTimeStep()

    held = accel_after_one_step(tensions.tensions)
    fall = accel_after_one_step(np.zeros(robot.m))
    # The 2m links of 1e-4 kg are not in the QP's model: a residual of order m·LINK_MASS·g / mass.
    assert np.linalg.norm(held) < 20 * robot.m * LINK_MASS * 9.81 / robot.mass
    np.testing.assert_allclose(fall, [0.0, 0.0, -9.81], atol=0.05)


def test_cli_export_sdf(tmp_path: Path) -> None:
    out = tmp_path / "caroca.sdf"
    proc = cdpr("export-sdf", "caroca", "-o", str(out), check=True)
    assert last_json_line(proc.stdout) == {
        "robot": "caroca",
        "file": str(out),
        "links": 18,
        "joints": 25,
        "ball_joints": 8,
    }
    assert out.read_text() == sdf_string(load_robot("caroca"))
    proc = cdpr("export-sdf", "kntu_planar", "--tree", "-o", "-", check=True)
    assert proc.stdout == sdf_string(load_robot("kntu_planar"), close_loops=False)
    proc = cdpr("export-sdf", "caroca", "-o", str(tmp_path / "no" / "such" / "dir.sdf"))
    assert proc.returncode == 2
    assert "cannot write" in proc.stderr
