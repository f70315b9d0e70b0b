"""SDF export: a robot file as an SDF 1.6 world in the style of the seed paper's generator (§3.2).

The paper's simulator ran in Gazebo from an SDF file generated from a few numbers (frame, platform,
attach points, joint properties, home pose). :func:`sdf_world` writes the same model for any robot
file, with every cable a U-P-S leg (seed paper §3.1):

* link ``frame``: the fixed base, a box outline (12 edge cylinders) over ``robot.frame_min..frame_max``,
  "nearly infinite" mass 1e5 kg as in the paper, held by the fixed joint ``frame_fixed`` to ``world``;
* link ``platform``: mass, full inertia about the centre of mass, and the robot's shape (box, sphere
  or cylinder) as visual and collision, at the home pose;
* per cable i (0-based, as in the robot file and on the wire):

  - link ``cable_i_upper`` at a_i and joint ``cable_i_universal`` (type ``universal``, parent
    ``frame``): axes x and y of the leg frame, whose z axis points from a_i to the platform point at
    the home pose (so both angles start at 0, away from the joint's singularity);
  - link ``cable_i_lower`` at the platform point b_i (home pose, in the world) and joint ``cable_i``
    (type ``prismatic``, the actuated cable): axis −z of the leg frame, from the platform towards a_i,
    as in the paper's generator, so the joint effort *is* the cable tension (pulling is positive) and
    the joint position is l_home − l; limits: position for 0 ≤ l ≤ max_length, effort tmax, velocity
    max_speed, damping ``cable_damping``. Its visual is the cable: a cylinder of length max_length
    ending at the platform (Gazebo cannot resize a body, so the part beyond a_i sticks out of the
    frame, as in the paper's Fig. 1);
  - joint ``cable_i_ball`` (type ``ball``, parent ``cable_i_lower``, child ``platform``) at b_i in the
    platform frame: the spherical joint that closes the loop.

  Both leg links are near-massless (:data:`LINK_MASS`); the U and S joints carry the passive damping.

A CDPR is a closed chain and SDF describes a model as a tree: the ball joints make ``platform`` the child
of m joints. The paper's generator did the same (its last spherical revolute joint has a child that
another joint already holds); Gazebo accepts it. ``close_loops=False`` leaves the ball joints out: the
platform is then a free link, the model a tree that strict tree parsers (DART's) load whole; the loops
are closed in the simulator (e.g. ``dartpy.constraint.BallJointConstraint`` at the platform points, as
:mod:`cdpr_sim.ups` does).

SDF 1.6 conventions used: link poses are in the model (= world) frame, a joint's pose is in its child
link's frame, an axis is expressed in the joint frame; rpy as in :mod:`cdpr.mechanics.rotation`.
Pure: :func:`sdf_world` builds an ``xml.etree`` element; :func:`write_sdf` writes the file.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from cdpr.errors import InputError
from cdpr.mechanics.robot import GRAVITY
from cdpr.mechanics.rotation import Array

if TYPE_CHECKING:
    from cdpr.mechanics.robot import Robot

SDF_VERSION = "1.6"
LINK_MASS = 1e-4  # kg, each virtual leg link (as cdpr_sim.ups: "negligible masses")
CABLE_RADIUS = 0.005  # m, cable visual radius (the paper's Gazebo model); also sizes the links' inertia
FRAME_MASS = 1e5  # kg, the paper's "nearly infinite" base mass (the base is also fixed to the world)
FRAME_EDGE_RADIUS = 0.02  # m


def _num(x: float) -> str:
    """Shortest round-trip text of a float (no '-0')."""
    return repr(float(x) + 0.0)


def _vec(values: ArrayLike) -> str:
    return " ".join(_num(v) for v in np.asarray(values, dtype=float).ravel())


def matrix_to_rpy(R: ArrayLike) -> Array:
    """Roll, pitch, yaw of R = Rz(yaw) Ry(pitch) Rx(roll) (inverse of :func:`cdpr.mechanics.rotation.rpy_to_matrix`)."""
    m = np.asarray(R, dtype=float)
    pitch = math.atan2(-m[2, 0], math.hypot(m[0, 0], m[1, 0]))
    if math.hypot(m[0, 0], m[1, 0]) > 1e-12:
        return np.array([math.atan2(m[2, 1], m[2, 2]), pitch, math.atan2(m[1, 0], m[0, 0])])
    return np.array([math.atan2(-m[1, 2], m[1, 1]), pitch, 0.0])  # gimbal lock: yaw folded into roll


def _pose(position: ArrayLike, R: ArrayLike | None = None) -> str:
    rpy = np.zeros(3) if R is None else matrix_to_rpy(R)
    return _vec(np.concatenate([np.asarray(position, dtype=float), rpy]))


def leg_frame(u: ArrayLike) -> Array:
    """A rotation whose z axis is the unit vector ``u`` (x from the world axis least along u)."""
    z = np.asarray(u, dtype=float)
    helper = np.eye(3)[int(np.argmin(np.abs(z)))]
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.column_stack((x, np.cross(z, x), z))


def _sub(parent: ET.Element, tag: str, text: str | None = None, **attrib: str) -> ET.Element:
    el = ET.SubElement(parent, tag, attrib)
    if text is not None:
        el.text = text
    return el


def _inertial(link: ET.Element, mass: float, inertia: ArrayLike) -> None:
    J = np.asarray(inertia, dtype=float)
    el = _sub(link, "inertial")
    _sub(el, "pose", "0 0 0 0 0 0")
    _sub(el, "mass", _num(mass))
    block = _sub(el, "inertia")
    for name, (i, j) in {
        "ixx": (0, 0),
        "ixy": (0, 1),
        "ixz": (0, 2),
        "iyy": (1, 1),
        "iyz": (1, 2),
        "izz": (2, 2),
    }.items():
        _sub(block, name, _num(J[i, j]))


def _geometry(parent: ET.Element, kind: str, size: tuple[float, ...]) -> None:
    geom = _sub(_sub(parent, "geometry"), kind)
    if kind == "box":
        _sub(geom, "size", _vec(size))
    elif kind == "sphere":
        _sub(geom, "radius", _num(size[0]))
    else:
        _sub(geom, "radius", _num(size[0]))
        _sub(geom, "length", _num(size[1]))


def _visual(link: ET.Element, name: str, kind: str, size: tuple[float, ...], pose: str, rgba: str) -> None:
    vis = _sub(link, "visual", name=name)
    _sub(vis, "pose", pose)
    _geometry(vis, kind, size)
    mat = _sub(vis, "material")
    _sub(mat, "ambient", rgba)
    _sub(mat, "diffuse", rgba)


def _axis(
    joint: ET.Element,
    tag: str,
    xyz: str,
    damping: float,
    lower: float = -1e16,
    upper: float = 1e16,
    effort: float | None = None,
    velocity: float | None = None,
) -> None:
    axis = _sub(joint, tag)
    _sub(axis, "xyz", xyz)
    _sub(axis, "use_parent_model_frame", "false")
    _sub(_sub(axis, "dynamics"), "damping", _num(damping))
    limit = _sub(axis, "limit")
    _sub(limit, "lower", _num(lower))
    _sub(limit, "upper", _num(upper))
    if effort is not None:
        _sub(limit, "effort", _num(effort))
    if velocity is not None:
        _sub(limit, "velocity", _num(velocity))


def _joint(model: ET.Element, name: str, kind: str, parent: str, child: str, pose: str) -> ET.Element:
    joint = _sub(model, "joint", name=name, type=kind)
    _sub(joint, "parent", parent)
    _sub(joint, "child", child)
    _sub(joint, "pose", pose)
    return joint


def _frame_edges(link: ET.Element, lo: Array, hi: Array) -> None:
    """The 12 edges of the box lo..hi as cylinder visuals (the generator's outline of the base)."""
    size = hi - lo
    along = {0: np.array([0.0, math.pi / 2, 0.0]), 1: np.array([-math.pi / 2, 0.0, 0.0]), 2: np.zeros(3)}
    count = 0
    for axis in range(3):
        others = [j for j in range(3) if j != axis]
        for s0 in (0.0, 1.0):
            for s1 in (0.0, 1.0):
                centre = lo + 0.5 * size * np.eye(3)[axis]
                centre[others[0]] = lo[others[0]] + s0 * size[others[0]]
                centre[others[1]] = lo[others[1]] + s1 * size[others[1]]
                pose = _vec(np.concatenate([centre, along[axis]]))
                _visual(
                    link,
                    f"edge_{count}",
                    "cylinder",
                    (FRAME_EDGE_RADIUS, float(size[axis])),
                    pose,
                    "0.55 0.55 0.55 1",
                )
                count += 1


def sdf_world(robot: Robot, close_loops: bool = True, dt: float = 0.001) -> ET.Element:
    """The ``<sdf>`` element of a world holding ``robot`` at its home pose (module docstring: layout)."""
    if robot.pulleys is not None:
        raise InputError(f"{robot.name}: exit pulleys: the SDF's U-P-S legs pivot at fixed frame points and cannot "
                         "swivel a pulley; export the robot without them (a radius of 0)")
    p0, R0 = np.asarray(robot.home_position, dtype=float), np.asarray(robot.home_rotation, dtype=float)
    sdf = ET.Element("sdf", version=SDF_VERSION)
    world = _sub(sdf, "world", name=robot.name)
    _sub(world, "gravity", _vec(GRAVITY))
    physics = _sub(world, "physics", name="default", type="ode")
    _sub(physics, "max_step_size", _num(dt))
    _sub(physics, "real_time_factor", "1")
    model = _sub(world, "model", name=robot.name)
    _sub(model, "pose", "0 0 0 0 0 0")

    model.append(ET.Comment(" fixed base: a box outline of nearly infinite mass, fixed to the world "))
    frame = _sub(model, "link", name="frame")
    _sub(frame, "pose", "0 0 0 0 0 0")
    lo, hi = np.asarray(robot.frame_min, dtype=float), np.asarray(robot.frame_max, dtype=float)
    size = hi - lo
    box_inertia = (
        FRAME_MASS
        / 12.0
        * np.diag([size[1] ** 2 + size[2] ** 2, size[0] ** 2 + size[2] ** 2, size[0] ** 2 + size[1] ** 2])
    )
    _inertial(frame, FRAME_MASS, box_inertia)
    _frame_edges(frame, lo, hi)
    _joint(model, "frame_fixed", "fixed", "world", "frame", "0 0 0 0 0 0")

    model.append(ET.Comment(" moving platform at the home pose, origin at its centre of mass "))
    platform = _sub(model, "link", name="platform")
    _sub(platform, "pose", _pose(p0, R0))
    _inertial(platform, robot.mass, robot.inertia)
    shape = robot.shape
    _visual(platform, "platform_visual", shape.type, shape.size, "0 0 0 0 0 0", "0.27 0.51 0.71 1")
    coll = _sub(platform, "collision", name="platform_collision")
    _sub(coll, "pose", "0 0 0 0 0 0")
    _geometry(coll, shape.type, shape.size)

    link_inertia = np.eye(3) * 0.4 * LINK_MASS * CABLE_RADIUS**2
    ends = p0 + robot.platform_points @ R0.T
    for i, (a, b, end) in enumerate(zip(robot.frame_points, robot.platform_points, ends, strict=True)):
        vec = end - a
        length = float(np.linalg.norm(vec))
        if length < 1e-9:
            raise ValueError(f"cable {i} has zero length at the home pose")
        Ri = leg_frame(vec / length)
        model.append(
            ET.Comment(f" cable {i}: universal joint at a_{i}, actuated prismatic, ball joint at b_{i} ")
        )
        upper = _sub(model, "link", name=f"cable_{i}_upper")
        _sub(upper, "pose", _pose(a, Ri))
        _inertial(upper, LINK_MASS, link_inertia)
        universal = _joint(
            model, f"cable_{i}_universal", "universal", "frame", f"cable_{i}_upper", "0 0 0 0 0 0"
        )
        _axis(universal, "axis", "1 0 0", robot.passive_damping)
        _axis(universal, "axis2", "0 1 0", robot.passive_damping)

        lower = _sub(model, "link", name=f"cable_{i}_lower")
        _sub(lower, "pose", _pose(end, Ri))
        _inertial(lower, LINK_MASS, link_inertia)
        _visual(
            lower,
            "cable",
            "cylinder",
            (CABLE_RADIUS, float(robot.max_length[i])),
            _vec([0, 0, -float(robot.max_length[i]) / 2, 0, 0, 0]),
            "0.1 0.1 0.1 1",
        )
        prismatic = _joint(
            model, f"cable_{i}", "prismatic", f"cable_{i}_upper", f"cable_{i}_lower", "0 0 0 0 0 0"
        )
        _axis(
            prismatic,
            "axis",
            "0 0 -1",
            robot.cable_damping,
            lower=length - float(robot.max_length[i]),
            upper=length,
            effort=float(robot.tmax[i]),
            velocity=robot.max_speed,
        )
        if close_loops:
            ball = _joint(model, f"cable_{i}_ball", "ball", f"cable_{i}_lower", "platform", _pose(b))
            _axis(ball, "axis", "0 0 1", robot.passive_damping)
    return sdf


def sdf_string(robot: Robot, close_loops: bool = True, dt: float = 0.001) -> str:
    """The SDF document as text (XML declaration, two-space indentation)."""
    root = sdf_world(robot, close_loops, dt)
    ET.indent(root, space="  ")
    return '<?xml version="1.0" ?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def write_sdf(robot: Robot, path: str | Path, close_loops: bool = True, dt: float = 0.001) -> Path:
    """Write :func:`sdf_string` to ``path``; returns it."""
    out = Path(path)
    out.write_text(sdf_string(robot, close_loops, dt))
    return out
