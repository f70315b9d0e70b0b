"""Robot files: the shipped robots load and can hold their platform at home; bad files fail in one line.

Static feasibility is checked with scipy's linprog, independently of the project's tension distribution:
there must be tensions f with tmin ≤ f ≤ tmax and W f + w_g = 0 at the home pose.
"""

from __future__ import annotations

import itertools
import subprocess
import sys
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import linprog

from cdpr.config.robot import load_robot, shipped_robots
from cdpr.errors import InputError
from cdpr.mechanics.kinematics import inverse_kinematics
from cdpr.mechanics.pulley import pulley_geometry
from cdpr.mechanics.robot import Robot
from cdpr.mechanics.rotation import rpy_to_matrix

TEST_ROBOTS = Path(__file__).parent / "robots"
VALID = TEST_ROBOTS / "valid"
INVALID = TEST_ROBOTS / "invalid"
G = 9.81


def static_tensions(robot: Robot, position: np.ndarray, R: np.ndarray) -> np.ndarray | None:
    """Tensions in [tmin, tmax] holding the platform still at the pose (least total tension), or None.

    Built from first principles: column i of the wrench is the unit vector from the platform point to
    the frame point (over an exit pulley, to where the cable leaves it: tests/test_pulley.py checks that point)
    and its moment about the centre of mass; gravity is m·g at the centre of mass.
    """
    pts = position + robot.platform_points @ R.T
    ends = robot.frame_points if robot.pulleys is None else pulley_geometry(robot.frame_points, robot.pulleys,
                                                                             pts).tangent_points
    d = ends - pts
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    W = np.vstack([d.T, np.cross(pts - position, d).T])
    weight = np.array([0.0, 0.0, -G * robot.mass, 0.0, 0.0, 0.0])
    if robot.mode == "planar" and robot.plane == "xy":  # the weight is out of the plane: what carries it holds it
        W, weight = W[[0, 1, 5]], weight[[0, 1, 5]]
    res = linprog(np.ones(robot.m), A_eq=W, b_eq=-weight, bounds=list(zip(robot.tmin, robot.tmax, strict=True)))
    if res.status != 0:
        return None
    f = np.asarray(res.x)
    assert np.allclose(W @ f, -weight, atol=1e-6 * G * robot.mass)
    return f


# --- shipped robots -----------------------------------------------------------------------------------

SHIPPED = shipped_robots()


def test_the_robots_the_project_promises_are_shipped() -> None:
    assert {"caroca", "caroca_original", "point_mass_4", "cogiro", "kntu_planar"} <= set(SHIPPED)
    modes = {load_robot(name).mode for name in SHIPPED}
    assert modes == {"spatial", "point_mass", "planar"}


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_robot_loads_with_consistent_data(name: str) -> None:
    robot = load_robot(name)
    assert robot.name == name
    assert robot.source.strip(), "every shipped robot says where its numbers come from"
    assert robot.m >= robot.dof
    assert robot.frame_points.shape == robot.platform_points.shape == (robot.m, 3)
    for arr in (robot.frame_points, robot.platform_points, robot.inertia, robot.home_position):
        assert not arr.flags.writeable
    assert np.allclose(robot.inertia, robot.inertia.T)
    assert np.linalg.eigvalsh(robot.inertia).min() > 0.0
    assert np.all(robot.tmin >= 0.0)
    assert np.all(robot.tmin < robot.tmax)
    assert np.allclose(robot.home_rotation @ robot.home_rotation.T, np.eye(3))

    # The frame points and the home position are inside the frame box.
    eps = 1e-9
    assert np.all(robot.frame_points >= robot.frame_min - eps)
    assert np.all(robot.frame_points <= robot.frame_max + eps)
    assert np.all(robot.home_position > robot.frame_min)
    assert np.all(robot.home_position < robot.frame_max)

    # The winch can pay out every cable anywhere in the frame box (corners are the farthest points).
    corners = np.array(list(itertools.product(*zip(robot.frame_min, robot.frame_max, strict=True))))
    farthest = np.linalg.norm(robot.frame_points[:, None, :] - corners[None, :, :], axis=2).max()
    assert np.all(farthest <= robot.max_length)

    # The platform points are on (or in) the platform's shape, centred at the centre of mass.
    if robot.shape.type == "box":
        assert np.all(np.abs(robot.platform_points) <= np.array(robot.shape.size) / 2 + eps)
    elif robot.shape.type == "sphere":
        assert np.all(np.linalg.norm(robot.platform_points, axis=1) <= robot.shape.size[0] + eps)


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_robot_holds_its_platform_at_home(name: str) -> None:
    robot = load_robot(name)
    f = static_tensions(robot, robot.home_position, robot.home_rotation)
    assert f is not None, f"{name}: no tensions in [{robot.tmin}, {robot.tmax}] hold the platform at home"
    assert np.all(f >= robot.tmin - 1e-6)
    assert np.all(f <= robot.tmax + 1e-6)
    # The project's wrench matrix agrees with the first-principles one used by linprog.
    W = inverse_kinematics(robot, robot.home_position, robot.home_rotation).wrench_matrix
    held = 0.0 if robot.mode == "planar" and robot.plane == "xy" else G * robot.mass  # (the weight off the plane)
    assert np.allclose(W @ f, [0.0, 0.0, held, 0.0, 0.0, 0.0], atol=1e-6 * robot.mass)


@pytest.mark.parametrize("name", SHIPPED)
def test_uncontrolled_wrench_rows_vanish_at_home(name: str) -> None:
    """Point-mass cables exert no moment; planar cables exert no force along y nor moment about x, z."""
    robot = load_robot(name)
    W = inverse_kinematics(robot, robot.home_position, robot.home_rotation).wrench_matrix
    free = [r for r in range(6) if r not in robot.controlled_rows]
    assert np.allclose(W[free], 0.0, atol=1e-12)
    assert np.linalg.matrix_rank(W[list(robot.controlled_rows)]) == robot.dof


@pytest.mark.parametrize(("name", "payload"), [("caroca", 1.0), ("caroca", 15.0), ("caroca_original", 15.0)])
def test_caroca_holds_the_papers_payloads_at_home(name: str, payload: float) -> None:
    robot = load_robot(name).with_payload(payload)
    assert static_tensions(robot, robot.home_position, robot.home_rotation) is not None


def test_caroca_original_frame_is_symmetric_after_the_cable_7_fix() -> None:
    a = load_robot("caroca_original").frame_points
    assert a[6, 0] == pytest.approx(1.350)  # CASPR has 1.359 there

    def as_set(points: np.ndarray) -> set[tuple[float, ...]]:
        return {tuple(np.round(p, 6)) for p in points}

    assert as_set(a * [-1.0, 1.0, 1.0]) == as_set(a)
    assert as_set(a * [1.0, -1.0, 1.0]) == as_set(a)


def test_load_by_name_and_by_path_agree() -> None:
    path = Path(str(resources.files("cdpr") / "robots" / "caroca.yaml"))
    assert load_robot("caroca").summary() == load_robot(path).summary()
    assert load_robot(str(path)).summary() == load_robot("caroca").summary()


def test_unknown_robot_name_lists_the_shipped_ones() -> None:
    with pytest.raises(InputError) as info:
        load_robot("no_such_robot")
    msg = str(info.value)
    assert msg.startswith("no_such_robot: unknown robot")
    assert all(name in msg for name in SHIPPED)
    assert "\n" not in msg


# --- test-only valid robots ----------------------------------------------------------------------------


def test_test_robots_are_not_shipped() -> None:
    test_names = {p.stem for p in TEST_ROBOTS.rglob("*.yaml")}
    assert test_names.isdisjoint(SHIPPED)


def test_optional_keys_take_their_defaults() -> None:
    robot = load_robot(VALID / "cube_8.yaml")
    assert robot.description == ""
    assert robot.mode == "spatial"
    assert robot.cable_damping == 0.0
    assert robot.passive_damping == 0.0
    assert np.array_equal(robot.home_rotation, np.eye(3))
    assert np.array_equal(robot.inertia, np.diag([0.2, 0.3, 0.4]))
    assert static_tensions(robot, robot.home_position, robot.home_rotation) is not None


def test_every_given_key_is_kept() -> None:
    robot = load_robot(VALID / "full_inertia.yaml")
    assert robot.description == "an 8-cable robot with products of inertia and a rotated home pose"
    assert np.array_equal(robot.inertia, [[1.0, 0.1, -0.05], [0.1, 2.0, 0.2], [-0.05, 0.2, 3.0]])
    assert np.allclose(robot.home_rotation, rpy_to_matrix(0.1, -0.05, 0.3))
    assert np.array_equal(robot.home_position, [0.2, -0.1, 1.2])
    assert (robot.cable_damping, robot.passive_damping) == (0.5, 0.02)
    assert (robot.tmin.tolist(), robot.tmax.tolist(), robot.max_length.tolist(), robot.max_speed) == (
        [2.0] * robot.m, [800.0] * robot.m, [7.0] * robot.m, 3.0)
    assert robot.shape.type == "cylinder"
    assert robot.shape.size == (0.3, 0.2)
    assert np.array_equal(robot.frame_points[3], [2.0, -2.0, 3.0])
    assert np.array_equal(robot.platform_points[3], [0.2, 0.2, -0.1])
    assert static_tensions(robot, robot.home_position, robot.home_rotation) is not None


@pytest.mark.parametrize(
    ("file", "mode"), [("triangle_planar", "planar"), ("tripod_point_mass", "point_mass")]
)
def test_the_fewest_cables_a_mode_allows_load(file: str, mode: str) -> None:
    robot = load_robot(VALID / f"{file}.yaml")
    assert (robot.mode, robot.dof, robot.m) == (mode, 3, 3)


# --- invalid robots ------------------------------------------------------------------------------------

# file stem → (the field the one-line message names, a fragment of the message after the field)
INVALID_CASES: dict[str, tuple[str, str]] = {
    "missing_mass": ("platform.mass", "missing required key"),
    "missing_cables": ("cables", "missing required key"),
    "missing_source": ("source", "missing required key"),
    "cable_point_2_numbers": ("cables.1.platform", "at least 3 items"),
    "nan_mass": ("platform.mass", "finite number"),
    "inf_frame_point": ("cables.3.frame.2", "finite number"),
    "nan_inertia": ("platform.inertia.1", "finite number"),
    "negative_mass": ("platform.mass", "must be > 0 (got -1)"),
    "zero_mass": ("platform.mass", "must be > 0 (got 0)"),
    "inertia_not_positive_definite": ("platform.inertia", "positive definite"),
    "inertia_not_symmetric": ("platform.inertia", "symmetric"),
    "inertia_wrong_shape": ("platform.inertia", "3 principal moments or a 3×3 matrix"),
    "tmin_above_tmax": ("limits", "tmin (600.0) must not exceed tmax (500.0)"),
    "negative_tmin": ("limits.tmin", "must be >= 0 (got -"),
    "too_few_cables": ("cables", "5 cable(s) cannot control the 6 DOF"),
    "rank_deficient": ("cables", "rank 3 < 6"),
    "unknown_key": ("platform.colour", "unknown key"),
    "unknown_mode": ("mode", "'spherical'"),
    "shape_size_count": ("platform.shape", "a box needs 3 size value(s), got 2"),
    "zero_length_at_home": ("cables.0", "zero cable length"),
    "point_mass_offset": ("cables", "every platform point at [0, 0, 0]"),
    "planar_out_of_plane": ("cables", "every y must be 0"),
    "frame_box_inverted": ("frame_box", "min must be below max"),
    "home_not_held": ("home", "no tensions in [0.5, 100] N (limits.tmin, limits.tmax) hold the 2 kg platform at rest "
                      "at the home pose (position [0, 0, 1] m, rpy [0, 0, 0] rad)"),
}

# Files that are not robot descriptions at all: the message names the file, then says what is wrong.
UNREADABLE_CASES: dict[str, str] = {
    "not_yaml": "not valid YAML at line",
    "not_mapping": "expected a mapping of keys at the top level, got list",
    "empty": "expected a mapping of keys at the top level, got NoneType",
}


def invalid_files() -> list[object]:
    """pytest params (path, prefix, fragment) for every invalid case, and for a file that is missing.

    ``prefix`` is how the one-line message must start (the file, then the field); ``fragment`` is a
    piece of the explanation that must follow it.
    """
    params = []
    for stem, (field, fragment) in INVALID_CASES.items():
        path = INVALID / f"{stem}.yaml"
        params.append(pytest.param(path, f"{path}: {field}: ", fragment, id=stem))
    for stem, fragment in UNREADABLE_CASES.items():
        path = INVALID / f"{stem}.yaml"
        params.append(pytest.param(path, f"{path}: ", fragment, id=stem))
    path = INVALID / "does_not_exist.yaml"
    params.append(pytest.param(path, f"{path}: ", "no such robot file", id="does_not_exist"))
    return params


def test_every_invalid_file_has_a_case() -> None:
    stems = {p.stem for p in INVALID.glob("*.yaml")}
    assert stems == set(INVALID_CASES) | set(UNREADABLE_CASES)


@pytest.mark.parametrize(("path", "prefix", "fragment"), invalid_files())
def test_invalid_robot_fails_with_one_line_naming_file_and_field(
    path: Path, prefix: str, fragment: str
) -> None:
    with pytest.raises(InputError) as info:
        load_robot(path)
    msg = str(info.value)
    assert "\n" not in msg
    assert msg.startswith(prefix), msg
    assert fragment in msg.removeprefix(prefix), msg


def test_a_file_that_is_not_text_fails_in_one_line(tmp_path: Path) -> None:
    path = tmp_path / "binary.yaml"
    path.write_bytes(b"name: \xff\xfe\x00 robot\n")
    with pytest.raises(InputError) as info:
        load_robot(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}: ")
    assert "\n" not in msg


def test_a_directory_is_not_a_robot_file(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no such robot file"):
        load_robot(str(tmp_path) + "/")


@pytest.mark.parametrize(("path", "prefix", "fragment"), invalid_files())
def test_cli_rejects_invalid_robot_with_exit_2_and_one_line(path: Path, prefix: str, fragment: str) -> None:
    """`python -m cdpr robots FILE` prints the loader's one line (file and field) and exits 2."""
    proc = subprocess.run(
        [sys.executable, "-m", "cdpr", "robots", str(path)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert prefix in lines[0]
    assert fragment in lines[0]


def _caroca_with(tmp_path: Path, name: str, **changes: object) -> Path:
    import yaml

    spec = yaml.safe_load((resources.files("cdpr") / "robots" / "caroca.yaml").read_text(encoding="utf-8"))
    for key, value in changes.items():
        where = spec
        *parents, last = key.split("__")
        for p in parents:
            where = where[p]
        where[last] = value
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False), encoding="utf-8")
    return path


def test_a_home_the_cables_cannot_hold_is_explained_and_a_held_one_found(tmp_path: Path) -> None:
    """CAROCA's geometry with its home in a corner of the frame: a session (and `cdpr robots FILE`) refuses the
    file, naming the wrench no pulling produces there and the cables that would have to push, and the way
    forward; the analysis tools take the file (saying a session would not); `cdpr robots FILE --find-home` gives
    a held home nearby, with which the file loads."""
    import json

    import yaml

    from conftest import cdpr_here

    path = _caroca_with(tmp_path, "corner", home={"position": [3.5, 2.0, 0.3], "rpy": [0.0, 0.0, 0.0]})
    with pytest.raises(InputError) as err:
        load_robot(path)
    message = str(err.value)
    assert message.startswith(f"{path}: home: no tensions in [50, 10000] N (limits.tmin, limits.tmax) hold the 150 kg "
                              "platform at rest at the home pose (position [3.5, 2, 0.3] m, rpy [0, 0, 0] rad): "
                              "pulling alone cannot: the wrench fx ")
    assert "would have to push" in message
    assert message.endswith(f"`cdpr robots {path} --find-home` finds a pose they hold (cdpr ik, tda and workspace "
                            "take this file)")
    for command in (("ik", str(path), "--pose", "0.9", "0.9", "1"), ("tda", str(path), "--pose", "0.9", "0.9", "1",
                                                                     "--static"),
                    ("workspace", str(path), "--step", "1.0")):
        proc = cdpr_here(*command)
        assert proc.returncode == 0, (command, proc.stderr)
        assert proc.stderr.strip().splitlines() == [f"cdpr: warning: {message} (a session would refuse this robot)"]
    refused = cdpr_here("robots", str(path))
    assert (refused.returncode, refused.stderr.strip()) == (2, f"cdpr: error: {message}")
    found = cdpr_here("robots", str(path), "--find-home")
    assert found.returncode == 0, found.stderr
    out = json.loads(found.stdout)
    assert out["home_held"] is False
    assert 0.0 < out["moved"] < 1.0  # near the corner the file gives
    spec = yaml.safe_load(path.read_text(encoding="utf-8"))
    spec["home"] = out["found"]
    path.write_text(yaml.safe_dump(spec, sort_keys=False), encoding="utf-8")
    held = load_robot(path)  # loads now: the cables hold it there
    assert np.allclose(held.home_position, out["found"]["position"])


def test_limits_too_low_anywhere_say_which_cables_would_pull_harder(tmp_path: Path) -> None:
    import json

    from conftest import cdpr_here

    path = _caroca_with(tmp_path, "weak", limits__tmax=150.0)
    with pytest.raises(InputError, match=r"the cables would have to pull harder than their tmax: cable \d+ \d+ N > "
                                         r"150 N"):
        load_robot(path)
    none = cdpr_here("robots", str(path), "--find-home")
    assert none.returncode == 3  # as cdpr tda: no held pose exists
    assert json.loads(none.stdout)["found"] is None
    assert none.stderr.strip().splitlines()[-1].startswith(
        "cdpr robots --find-home: no position in the frame box holds the platform at its home orientation: the "
        "cables would have to pull harder than their tmax")


def test_one_wording_for_a_bound_and_the_key_or_option_named(tmp_path: Path) -> None:
    """A negative mass says the same thing in a robot file, a scenario file and on the command line, naming the
    key or the option; a misspelt key is named, with the key it may have meant (not "missing" for the one it
    replaced)."""
    import yaml

    from conftest import cdpr_here

    robot = yaml.safe_load((resources.files("cdpr") / "robots" / "caroca.yaml").read_text(encoding="utf-8"))
    robot["plattform"] = robot.pop("platform")
    (tmp_path / "typo.yaml").write_text(yaml.safe_dump(robot, sort_keys=False), encoding="utf-8")
    robot["platform"] = robot.pop("plattform")
    robot["platform"]["mass"] = -5
    (tmp_path / "heavy.yaml").write_text(yaml.safe_dump(robot, sort_keys=False), encoding="utf-8")
    scenario = yaml.safe_load((resources.files("cdpr") / "scenarios" / "caroca_15kg.yaml").read_text(encoding="utf-8"))
    scenario["platform"] = {"mass": -5}
    (tmp_path / "scenario.yaml").write_text(yaml.safe_dump(scenario, sort_keys=False), encoding="utf-8")
    cases = [
        (("robots", str(tmp_path / "typo.yaml")), f"{tmp_path / 'typo.yaml'}: plattform: unknown key (did you mean "
                                                  "platform?)"),
        (("robots", str(tmp_path / "heavy.yaml")), f"{tmp_path / 'heavy.yaml'}: platform.mass: must be > 0 (got -5)"),
        (("scenarios", str(tmp_path / "scenario.yaml")),
         f"{tmp_path / 'scenario.yaml'}: platform.mass: must be > 0 (got -5)"),
        (("workspace", "caroca", "--mass", "-5"), "--mass: must be > 0 (got -5)"),
        (("workspace", "caroca", "--payload", "-3"), "--payload: must be >= 0 (got -3)"),
        (("tda", "caroca", "--pose", "0.9", "0.9", "1", "--static", "--payload", "-3"),
         "--payload: must be >= 0 (got -3)"),
        (("workspace", "caroca", "--step", "-1"), "--step: must be > 0 (got -1)"),
    ]
    for args, line in cases:
        proc = cdpr_here(*args)
        assert (proc.returncode, proc.stderr.strip().splitlines()) == (2, [f"cdpr: error: {line}"]), args
    real = subprocess.run([sys.executable, "-m", "cdpr", "robots", str(tmp_path / "typo.yaml")], capture_output=True,
                          text=True, timeout=60, check=False)  # and so as a process
    assert (real.returncode, real.stderr.strip()) == (2, f"cdpr: error: {cases[0][1]}")
