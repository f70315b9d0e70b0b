"""`cdpr import caspr` (#32, #50): ten single-rigid-body robots of CASPR's model library, imported from XML files in
CASPR's format (tests/caspr/: the published models' numbers), against cable lengths and wrench matrices computed
here from the XML alone — at CASPR's own joint coordinates q, given to `cdpr ik --angles xyz` as they are, and over
CAROCA's rotating pulleys by CASPR's own pulley geometry; then a short session of each, and the files and folders
a user gives it. The ten imports share one process, and so do the sessions but one (each `cdpr run --in-process`:
the same nodes, messages and states); that one runs as separate processes."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import yaml

from cdpr.config.robot import load_robot
from cdpr.mechanics.kinematics import inverse_kinematics
from conftest import cdpr, cdpr_here, cdpr_in_one_process, last_json_line

FIXTURES = Path(__file__).parent / "caspr"
MODELS = sorted(p.name for p in FIXTURES.iterdir() if p.is_dir())
HOME = {"fast": ["--home", "0", "0", "200"]}  # FAST's q_initial (z = 100 m) is below what its 120 kN floor can hold


def cable_sets(name: str) -> list[str]:
    """The ids of a fixture's cable sets, in the file's order."""
    root = ET.parse(FIXTURES / name / f"{name}_cables.xml").getroot()
    return [s.get("id", "") for s in root.findall("cable_set")]


CASES = [(name, cable_set) for name in MODELS for cable_set in cable_sets(name)]  # every set of every model


def test_the_ten_robots_are_there() -> None:
    assert MODELS == ["caroca", "caspr_spatial_example", "cogiro", "fast", "ipanema_1", "ipanema_2",
                      "mpi_cable_robot_simulator", "nist_robocrane", "planar_xy_example", "segesta"]
    assert cable_sets("caroca") == ["original", "with_rotating_pulleys", "gazebo_sim"]


def elementary(axis: int, angle: float) -> np.ndarray:
    """A turn by ``angle`` about x, y or z (0, 1, 2): CASPR's RevoluteX, RevoluteY, RevoluteZ RelRotationMatrix."""
    c, s = np.cos(angle), np.sin(angle)
    return [np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
            np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])][axis]


def caspr_pulley(F: np.ndarray, v_F: np.ndarray, B: np.ndarray, R: float) -> tuple[np.ndarray, float]:
    """CASPR's BaseRotatingPulleyAttachment.ComputePulleyLeavingLocation, line by line: where the cable that runs
    into the pulley at F along v_F leaves it for B (r_A), and the arc it wraps (l_arc)."""
    v_FB = B - F
    n_plane = np.cross(v_F, v_FB)
    n_plane_unit = n_plane / np.linalg.norm(n_plane)
    v_FC = np.cross(n_plane, v_F)
    r_C = F + R * v_FC / np.linalg.norm(v_FC)
    rho = R / np.linalg.norm(B - r_C)
    r_A = r_C + rho**2 * (B - r_C) - rho * np.sqrt(1 - rho**2) * np.cross(n_plane_unit, B - r_C)
    n1 = (F - r_C) / np.linalg.norm(F - r_C)
    n2 = (r_A - r_C) / np.linalg.norm(r_A - r_C)
    return r_A, R * float(np.arccos(n1 @ n2))


class Caspr:
    """A model's numbers read straight from its XML (no project code): CASPR's own conventions."""

    def __init__(self, name: str, cable_set: str | None = None) -> None:
        bodies = ET.parse(FIXTURES / name / f"{name}_bodies.xml").getroot()
        cables = ET.parse(FIXTURES / name / f"{name}_cables.xml").getroot()
        joint = bodies.find("links/link_rigid/joint")
        self.joint = joint.get("type")
        self.q0 = np.array(joint.get("q_initial").split(), dtype=float)
        self.com = np.array(bodies.findtext("links/link_rigid/physical/com_location").split(), dtype=float)
        self.mass = float(bodies.findtext("links/link_rigid/physical/mass"))
        chosen = cable_set or cables.get("default_cable_set")
        cable_els = next(s for s in cables.findall("cable_set") if s.get("id") == chosen)
        self.a, self.b, self.fmin, self.fmax = [], [], [], []
        self.pulleys: list[tuple[float, np.ndarray] | None] = []  # (radius, cable entry vector) of a rotating pulley
        for c in cable_els:
            base, platform = list(c.find("attachments"))
            if base.tag == "base_rotating_pulley":
                self.a.append(np.array(base.findtext("fixed_location").split(), dtype=float))
                self.pulleys.append((float(base.findtext("pulley_radius")),
                                     np.array(base.findtext("cable_entry_vector").split(), dtype=float)))
            else:
                self.a.append(np.array(base.findtext("location").split(), dtype=float))
                self.pulleys.append(None)
            b = np.array(platform.findtext("location").split(), dtype=float)
            self.b.append(b + self.com if c.get("attachment_reference") == "com" else b)  # from the joint frame
            self.fmin.append(float(c.findtext("properties/force_min")))
            self.fmax.append(float(c.findtext("properties/force_max")))

    def pose(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The joint frame's position and rotation at joint coordinates q (CASPR's joint models)."""
        if self.joint == "SPATIAL_EULER_XYZ":
            return q[:3], elementary(0, q[3]) @ elementary(1, q[4]) @ elementary(2, q[5])
        assert self.joint == "PLANAR_XY"
        return np.array([q[0], q[1], 0.0]), elementary(2, q[2])

    def cli_pose(self, q: np.ndarray) -> list[str]:
        """q as `cdpr ik --pose X Y Z A B C --angles xyz` takes it (exact decimal strings)."""
        full = q if self.joint == "SPATIAL_EULER_XYZ" else np.array([q[0], q[1], 0.0, 0.0, 0.0, q[2]])
        return [repr(float(x)) for x in full]

    def lengths_and_wrench(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cable lengths, and W with moments about the centre of mass, at q: a straight cable from a_i to B_i, or over
        its rotating pulley (CASPR's arc plus the free span from where it leaves the wheel)."""
        p, R = self.pose(q)
        lengths, W = [], []
        for a, b, pulley in zip(self.a, self.b, self.pulleys, strict=True):
            B = p + R @ b
            leaves, arc = (a, 0.0) if pulley is None else caspr_pulley(a, pulley[1], B, pulley[0])
            v = leaves - B
            L = float(np.sqrt(v @ v))
            d = v / L
            lengths.append(L + arc)
            W.append(np.r_[d, np.cross(R @ (b - self.com), d)])
        return np.array(lengths), np.array(W).T

    def turned(self) -> np.ndarray:
        """A pose beside q_initial, rotated."""
        q = self.q0.copy()
        if self.joint == "PLANAR_XY":
            return q + np.array([0.02, -0.01, 0.1])
        return q + np.array([0.01, -0.02, 0.015, 0.05, -0.04, 0.1])

    def tilted(self) -> np.ndarray:
        """q_initial's position, turned by tenths of a radian about every axis."""
        q = self.q0.copy()
        if self.joint == "PLANAR_XY":
            return q + np.array([0.0, 0.0, 0.3])
        return q + np.array([0.0, 0.0, 0.0, 0.2, -0.15, 0.3])


def ik(path: Path, q: list[str], *extra: str) -> dict:
    """`cdpr ik FILE --pose q --angles xyz` (CASPR's q as it is), its JSON."""
    proc = cdpr_here("ik", str(path), "--pose", *q, "--angles", "xyz", *extra)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


@pytest.fixture(scope="module")
def imports(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, subprocess.CompletedProcess[str]]]:
    """Each model imported once by `cdpr import caspr` (as :func:`_import` does; the ten in one process), for the
    tests that check the import and those that run it: its file and the command's outcome."""
    folder = tmp_path_factory.mktemp("imported")
    files = {name: folder / f"{name}.yaml" for name in MODELS}
    procs = cdpr_in_one_process([["import", "caspr", str(FIXTURES / name), "-o", str(files[name]), *HOME.get(name, [])]
                                 for name in MODELS], folder / "results.json", timeout=300)
    return {name: (files[name], proc) for name, proc in zip(MODELS, procs, strict=True)}


def _imported(imports: dict[str, tuple[Path, subprocess.CompletedProcess[str]]], name: str) -> tuple[Path, dict]:
    """As :func:`_import`, from the :func:`imports` fixture."""
    out, proc = imports[name]
    assert proc.returncode == 0, proc.stderr
    return out, json.loads(proc.stdout)


def _import(name: str, tmp_path: Path, *extra: str, out_name: str | None = None) -> tuple[Path, dict]:
    out = tmp_path / f"{out_name or name}.yaml"
    proc = cdpr("import", "caspr", str(FIXTURES / name), "-o", str(out), *HOME.get(name, []), *extra, timeout=60)
    assert proc.returncode == 0, proc.stderr
    return out, json.loads(proc.stdout)


@pytest.mark.parametrize(("name", "cable_set"), CASES)
def test_caspr_s_q_gives_caspr_s_lengths_and_wrench_matrix(name: str, cable_set: str, imports: dict) -> None:
    """Every cable set of every model, at CASPR's q (the joint frame's position, Euler XYZ angles) given to `cdpr ik
    --angles xyz` unchanged: q_initial, a pose beside it and one turned by tenths of a radian."""
    path, report = _imported(imports, name)
    robot = load_robot(path, cable_set)
    model = Caspr(name, cable_set)
    assert robot.m == len(model.a)
    assert report["cable_sets"] == cable_sets(name)
    assert robot.mass == model.mass
    assert robot.tmin.tolist() == model.fmin
    assert robot.tmax.tolist() == model.fmax
    assert robot.mode == ("planar" if model.joint == "PLANAR_XY" else "spatial")
    assert (robot.pulleys is not None) == any(model.pulleys)
    home_q = model.q0.copy()
    if name in HOME:
        home_q[:3] = [0.0, 0.0, 200.0]
    for q in (home_q, model.turned(), model.tilted()):
        lengths, W = model.lengths_and_wrench(q)
        ours = ik(path, model.cli_pose(q), "--cable-set", cable_set)
        np.testing.assert_allclose(ours["lengths"], lengths, rtol=0, atol=1e-12)
        np.testing.assert_allclose(ours["wrench_matrix"], W, rtol=0, atol=1e-12)
    # the file's platform frame is CASPR's joint frame: its home is q_initial's, the COM at platform.com in it
    data = yaml.safe_load(path.read_text())
    p, R = model.pose(home_q)
    assert data["home"]["position"] == p.tolist()
    assert data["platform"].get("com", [0.0, 0.0, 0.0]) == model.com.tolist()
    np.testing.assert_allclose(robot.home_position, p + R @ model.com, rtol=0, atol=1e-12)  # the COM's
    assert "Assumed (CASPR does not give them)" in robot.source


def test_a_com_off_the_joint_frame_is_platform_com(imports: dict) -> None:
    """IPAnema 2 (its COM 0.5 m above the joint frame) and CoGiRo (off on every axis): CASPR's q is the file's pose,
    and the worked example of docs/robots.md holds."""
    path, report = _imported(imports, "ipanema_2")
    data = yaml.safe_load(path.read_text())
    assert (data["platform"]["com"], data["home"]["position"]) == ([0.0, 0.0, 0.5], [0.0, 0.0, 3.0])
    assert "the centre of mass is at [0.0, 0.0, 0.5] in it (platform.com)" in " ".join(report["notes"])
    lengths = ik(path, ["0", "0", "3", "0", "0", "0"])["lengths"]
    assert [round(x, 3) for x in (lengths[0], lengths[4])] == [4.749, 5.151]  # docs/robots.md
    np.testing.assert_allclose(lengths, Caspr("ipanema_2").lengths_and_wrench(np.array([0, 0, 3.0, 0, 0, 0]))[0],
                               rtol=1e-12)
    path, _ = _imported(imports, "cogiro")
    assert yaml.safe_load(path.read_text())["platform"]["com"] == [-0.034, -0.013, 0.264]
    q = np.array([0.4, -0.3, 2.2, 0.25, -0.2, 0.5])
    lengths = Caspr("cogiro").lengths_and_wrench(q)[0]
    np.testing.assert_allclose(ik(path, [repr(float(x)) for x in q])["lengths"], lengths, rtol=0, atol=1e-12)


def test_caroca_s_rotating_pulleys_are_exit_pulleys(imports: dict, tmp_path: Path) -> None:
    """CAROCA's `with_rotating_pulleys` set: each base_rotating_pulley an exit pulley (frame: its fixed_location;
    radius, axis: its cable_entry_vector); lengths as CASPR's pulley geometry gives them over a spread of poses,
    where they are not the straight lines'; and the set chosen as the file's cables."""
    path, report = _imported(imports, "caroca")
    assert report["cable_sets"] == ["original", "with_rotating_pulleys", "gazebo_sim"]
    data = yaml.safe_load(path.read_text())
    over = data["cable_sets"]["with_rotating_pulleys"]
    assert [c["pulley"] for c in over] == [{"radius": 0.045, "axis": [0.0, 0.0, 1.0]}] * 8
    assert [c["frame"] for c in over] == [c["frame"] for c in data["cables"]]  # CASPR's fixed_location: the same
    assert not any("pulley" in c for c in data["cables"] + data["cable_sets"]["gazebo_sim"])
    model, straight = Caspr("caroca", "with_rotating_pulleys"), Caspr("caroca", "original")
    rng = np.random.default_rng(50)
    for _ in range(12):
        q = np.r_[rng.uniform(-1.0, 1.0, 2), rng.uniform(0.5, 2.5), rng.uniform(-0.3, 0.3, 3)]
        lengths = model.lengths_and_wrench(q)[0]
        assert np.abs(lengths - straight.lengths_and_wrench(q)[0]).min() > 1e-3  # the pulleys count
        ours = ik(path, [repr(float(x)) for x in q], "--cable-set", "with_rotating_pulleys")["lengths"]
        np.testing.assert_allclose(ours, lengths, rtol=0, atol=1e-12)
    chosen, report = _import("caroca", tmp_path, "--cable-set", "with_rotating_pulleys")
    robot = load_robot(chosen)
    assert (robot.cable_set, report["cable_set"]) == ("with_rotating_pulleys",) * 2
    assert robot.pulleys is not None
    assert robot.pulleys.radius.tolist() == [0.045] * 8
    assert "the rotating pulleys (base_rotating_pulley) of cable set 'with_rotating_pulleys' are exit pulleys" in \
        " ".join(report["notes"])


def test_beyond_half_a_turn_caspr_s_arc_folds_back(imports: dict) -> None:
    """docs/robots.md: under a pulley (the platform point less than 2r from its swivel line) the cable wraps more
    than half a turn; the project's arc keeps growing, CASPR's arccos folds it back: the two arcs add up to a turn,
    the tangent point and free span the same."""
    path, _ = _imported(imports, "caroca")
    model = Caspr("caroca", "with_rotating_pulleys")
    F, (r, v_F) = model.a[0], model.pulleys[0]
    p = F - model.b[0] + np.array([-r, 0.0, -1.5])  # cable 1's platform point r from the swivel line, 1.5 m down
    B = p + model.b[0]
    r_A, arc = caspr_pulley(F, v_F, B, r)
    ours = ik(path, [repr(float(x)) for x in p] + ["0", "0", "0"], "--cable-set", "with_rotating_pulleys")
    free = float(np.linalg.norm(r_A - B))
    np.testing.assert_allclose(ours["lengths"][0] - free + arc, 2 * np.pi * r, rtol=0, atol=1e-12)
    assert ours["lengths"][0] - free > np.pi * r > arc


def test_every_cable_set_comes_along_and_either_can_be_chosen(tmp_path: Path, imports: dict) -> None:
    path, report = _imported(imports, "caspr_spatial_example")
    assert report["cable_sets"] == ["basic_7_cables", "alternative_7_cables", "basic_8_cables", "cross_8_cables"]
    data = yaml.safe_load(path.read_text())
    assert data["cable_set"] == "basic_7_cables"
    assert sorted(data["cable_sets"]) == ["alternative_7_cables", "basic_8_cables", "cross_8_cables"]
    eight = load_robot(path, "cross_8_cables")
    assert (eight.m, eight.cable_set) == (8, "cross_8_cables")
    lengths, _ = Caspr("caspr_spatial_example", "cross_8_cables").lengths_and_wrench(Caspr("caspr_spatial_example").q0)
    np.testing.assert_allclose(inverse_kinematics(eight, eight.home_position, eight.home_rotation).lengths, lengths,
                               rtol=1e-12)
    chosen, report = _import("caspr_spatial_example", tmp_path, "--cable-set", "basic_8_cables", out_name="eight")
    assert (load_robot(chosen).m, report["cable_set"]) == (8, "basic_8_cables")
    proc = cdpr_here("robots", str(path), "--cable-set", "nope")
    assert proc.returncode == 2
    assert "cable_set: no cable set 'nope' (this robot has: basic_7_cables, alternative_7_cables" in proc.stderr


def short_session(path: Path, name: str, folder: Path) -> Path:
    """A 0.6 s scenario of the imported robot at ``path``: a small quintic move along x from its home (the
    waypoints, as the file's home, of its platform frame: CASPR's joint frame)."""
    robot = load_robot(path)
    home = np.array(yaml.safe_load(path.read_text())["home"]["position"])
    step = 0.005 if robot.mode == "spatial" else 0.002  # m along x from home
    scenario = {
        "name": f"caspr_{name}", "robot": str(path), "dt": 0.001, "duration": 0.6,
        "trajectory": {"type": "quintic", "waypoints": [
            {"t": 0.0, "position": home.tolist()},
            {"t": 0.5, "position": (home + np.array([step, 0.0, 0.0])).tolist()}]},
        "controller": {"kp": 100.0, "kd": 20.0},
    }
    file = folder / f"{name}_scenario.yaml"
    file.write_text(yaml.safe_dump(scenario))
    return file


MULTI_PROCESS = "caspr_spatial_example"  # its session as separate processes (`cdpr run`), the others' in-process


@pytest.fixture(scope="module")
def sessions(imports: dict, tmp_path_factory: pytest.TempPathFactory) -> dict[str, subprocess.CompletedProcess[str]]:
    """The short session of every imported robot but :data:`MULTI_PROCESS`, each `cdpr run --in-process` (every
    node in one process, the same nodes and messages), one after the other in one process."""
    folder = tmp_path_factory.mktemp("sessions")
    argvs = {name: ["run", str(short_session(path, name, folder)), "--in-process"]
             for name, (path, proc) in imports.items() if name != MULTI_PROCESS and proc.returncode == 0}
    procs = cdpr_in_one_process(list(argvs.values()), folder / "results.json", timeout=600)
    return dict(zip(argvs, procs, strict=True))


@pytest.mark.parametrize("name", MODELS)
def test_a_short_session_of_each_imported_robot_finishes(name: str, imports: dict, sessions: dict,
                                                         tmp_path: Path) -> None:
    path, _ = _imported(imports, name)
    if name == MULTI_PROCESS:
        proc = cdpr("run", str(short_session(path, name, tmp_path)), timeout=300)
    else:
        proc = sessions[name]
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = last_json_line(proc.stdout)
    assert summary["exit_ok"]
    assert summary["steps"] == 600
    assert summary["max_position_error"] < 1e-3


MULTI_LINK = """<?xml version="1.0" encoding="utf-8"?>
<bodies_system><links>
  <link_rigid num="1" name="upper arm"><joint type="R_Z" q_initial="0"/></link_rigid>
  <link_rigid num="2" name="forearm"><joint type="R_Z" q_initial="0"/></link_rigid>
</links></bodies_system>
"""


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"bodies": MULTI_LINK},
         "a CASPR model with 2 link(s) (link_rigid): cdpr imports single-rigid-body models only"),
        ({"joint": ("SPATIAL_EULER_XYZ", "S_EULER_XYZ")}, "joint type 'S_EULER_XYZ': cdpr imports SPATIAL_EULER_XYZ"),
        ({"cables": ("<link>1</link>", "<link>2</link>")}, "attached to links 0, 2: cdpr imports cables that run from "
                                                            "the frame (link 0) straight to the platform (link 1)"),
        ({"cables": ("<force_max>1000</force_max>", "<force_max>lots</force_max>")}, "force_max: expected"),
        ({"bodies": "<bodies_system><links>"}, "not valid XML"),
        ({"arg": ["--cable-set", "nope"]}, "--cable-set: no cable set 'nope'"),
        ({"cables": ("<attachment><link>0</link><location>-3.0 -1.7321 3.0</location></attachment>",
                     "<screw_base_rotating_pulley><constant_winch_point>-3 -1.7 3</constant_winch_point>"
                     "</screw_base_rotating_pulley>")},
         "cable set 'original', cable 'cable 1': a screw-drive rotating pulley (<screw_base_rotating_pulley>)"),
        ({"cables": ("<attachment><link>0</link><location>-3.0 -1.7321 3.0</location></attachment>",
                     "<base_rotating_pulley><fixed_location>-3.0 -1.7321 3.0</fixed_location><pulley_radius>-0.1"
                     "</pulley_radius><cable_entry_vector>0 0 1</cable_entry_vector></base_rotating_pulley>")},
         "cable 'cable 1': base_rotating_pulley: pulley_radius must not be negative, got -0.1"),
        ({"cables": ('<cable_ideal name="cable 1" attachment_reference="joint">',
                     '<cable_passive_linear_spring name="cable 1" attachment_reference="joint">'),
          "cables2": ("</cable_ideal>", "</cable_passive_linear_spring>")},
         "cable 'cable 1': a passive spring (<cable_passive_linear_spring>): cdpr's cables are all actuated"),
        ({"bodies_text": ("<location>0 0 0</location></parent>", "<location>0 0 0.5</location></parent>")},
         "parent location 0 0 0.5: cdpr imports a platform whose joint frame is at q from the world's origin"),
    ],
)
def test_a_model_it_cannot_import_gives_one_line_and_exit_2(tmp_path: Path, change: dict, message: str) -> None:
    src = FIXTURES / "nist_robocrane"
    bodies = (src / "nist_robocrane_bodies.xml").read_text()
    cables = (src / "nist_robocrane_cables.xml").read_text()
    if "bodies" in change:
        bodies = change["bodies"]
    if "joint" in change:
        bodies = bodies.replace(*change["joint"])
    if "bodies_text" in change:
        bodies = bodies.replace(*change["bodies_text"], 1)
    for key in ("cables", "cables2"):
        if key in change:
            assert change[key][0] in cables
            cables = cables.replace(*change[key], 1)
    (tmp_path / "m_bodies.xml").write_text(bodies)
    (tmp_path / "m_cables.xml").write_text(cables)
    args = ("import", "caspr", str(tmp_path / "m_bodies.xml"), str(tmp_path / "m_cables.xml"),
            "-o", str(tmp_path / "out.yaml"), *change.get("arg", []))
    # the first case as the real command's process (nothing else on its stderr), the others in this process
    proc = cdpr(*args, timeout=60) if change.get("bodies") == MULTI_LINK else cdpr_here(*args)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert message in lines[0]
    assert not (tmp_path / "out.yaml").exists()


def test_a_home_its_cables_cannot_hold_is_refused_with_the_way_out(tmp_path: Path) -> None:
    proc = cdpr("import", "caspr", str(FIXTURES / "fast"), "-o", str(tmp_path / "fast.yaml"), timeout=60)
    assert proc.returncode == 2
    assert "home: no tensions in [120000, 1.2e+06] N" in proc.stderr
    assert "--home X Y Z" in proc.stderr


def test_the_two_files_in_either_order(tmp_path: Path) -> None:
    """BODIES CABLES or CABLES BODIES: the same robot file (told apart by their root tags); two of one kind, or a
    file that is neither, one line and exit 2."""
    src = FIXTURES / "cogiro"
    bodies, cables = src / "cogiro_bodies.xml", src / "cogiro_cables.xml"
    proc = cdpr("import", "caspr", str(cables), str(bodies), "-o", str(tmp_path / "swapped.yaml"), timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["cables"] == 8
    proc = cdpr_here("import", "caspr", str(bodies), str(cables), "-o", str(tmp_path / "ordered.yaml"))
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "swapped.yaml").read_text() == (tmp_path / "ordered.yaml").read_text()
    (tmp_path / "notes.xml").write_text("<notes/>")
    for args, message in (
        ([bodies, bodies], "cogiro_bodies.xml <bodies_system> and cogiro_bodies.xml <bodies_system>: a CASPR model is "
                           "a bodies file (<bodies_system>) and a cables file (<cables>)"),
        ([cables, tmp_path / "notes.xml"], "cogiro_cables.xml <cables> and notes.xml <notes>: a CASPR model is"),
        ([bodies], "cogiro_bodies.xml: is a file: give a CASPR model folder, or its BODIES.xml and CABLES.xml"),
        ([bodies, cables, bodies], "3 paths given: give BODIES.xml and CABLES.xml (either order), or a CASPR model"),
        ([bodies, cables, "--model", "cogiro"], "--model picks one of a folder's models: the two files given are one"),
    ):
        proc = cdpr_here("import", "caspr", *map(str, args), "-o", str(tmp_path / "no.yaml"))
        assert proc.returncode == 2, proc.stderr
        assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr
        assert message in proc.stderr
    assert not (tmp_path / "no.yaml").exists()


def _flat_folder(tmp_path: Path, names: list[str]) -> Path:
    """CASPR models side by side in one folder, as CASPR names them: NAME_bodies.xml and NAME_cables.xml."""
    folder = tmp_path / "models"
    folder.mkdir()
    for name in names:
        for kind in ("bodies", "cables"):
            shutil.copy(FIXTURES / name / f"{name}_{kind}.xml", folder)
    return folder


def test_a_folder_of_several_models(tmp_path: Path) -> None:
    """A flat folder of three models: a robot file each (the same as each model's alone), or --model NAME's."""
    folder = _flat_folder(tmp_path, ["caroca", "cogiro", "ipanema_2"])
    out = tmp_path / "robots"  # a folder not yet made: -o robots/
    proc = cdpr("import", "caspr", str(folder), "-o", f"{out}/", timeout=60)
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    assert report["models"] == ["caroca", "cogiro", "ipanema_2"]
    files = {r["model"]: Path(r["file"]) for r in report["robots"]}
    assert sorted(p.name for p in out.iterdir()) == ["caroca.yaml", "cogiro.yaml", "ipanema_2.yaml"]
    for name, path in files.items():
        alone = tmp_path / f"{name}_alone.yaml"
        proc = cdpr_here("import", "caspr", str(FIXTURES / name), "-o", str(alone))
        assert proc.returncode == 0, proc.stderr
        assert path.read_text() == alone.read_text()
    # --model NAME: that one alone, to a file or a folder
    proc = cdpr_here("import", "caspr", str(folder), "--model", "cogiro", "-o", str(tmp_path / "one.yaml"))
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["model"] == "cogiro"
    assert (tmp_path / "one.yaml").read_text() == files["cogiro"].read_text()
    chosen = tmp_path / "chosen"
    chosen.mkdir()
    proc = cdpr_here("import", "caspr", str(folder), "--model", "caroca", "--cable-set", "with_rotating_pulleys", "-o",
                     str(chosen))
    assert proc.returncode == 0, proc.stderr
    assert [p.name for p in chosen.iterdir()] == ["caroca.yaml"]
    assert load_robot(chosen / "caroca.yaml").cable_set == "with_rotating_pulleys"


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--model", "nope"], "--model: no model 'nope' in {folder} (it has: caroca, cogiro, ipanema_2)"),
        (["-o", "{tmp}/one.yaml"], "-o: {folder} holds 3 models (caroca, cogiro, ipanema_2): -o names a folder for "
                                   "their robot files (an existing one, or ending in /), or --model NAME picks one"),
        (["-o", "-"], "-o: {folder} holds 3 models"),
        (["--cable-set", "original"], "--cable-set: {folder} holds 3 models (caroca, cogiro, ipanema_2): --model NAME "
                                      "picks the one --cable-set is for"),
        (["--name", "mine"], "--name: {folder} holds 3 models"),
        (["--home", "0", "0", "1"], "--home: {folder} holds 3 models"),
    ],
)
def test_what_a_folder_of_several_models_cannot_do(tmp_path: Path, args: list[str], message: str) -> None:
    folder = _flat_folder(tmp_path, ["caroca", "cogiro", "ipanema_2"])
    args = [a.replace("{tmp}", str(tmp_path)) for a in args]
    proc = cdpr_here("import", "caspr", str(folder), *args)
    assert proc.returncode == 2, proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert message.format(folder=folder) in proc.stderr
    assert not (tmp_path / "one.yaml").exists()


def test_a_folder_with_a_model_it_cannot_import_or_a_file_alone(tmp_path: Path) -> None:
    """All or nothing: one model the folder holds cannot be imported, none is written (the line names it); a bodies
    file without its cables file, or no model at all, is named."""
    folder = _flat_folder(tmp_path, ["cogiro", "ipanema_2"])
    (folder / "arm_bodies.xml").write_text(MULTI_LINK)
    shutil.copy(FIXTURES / "nist_robocrane" / "nist_robocrane_cables.xml", folder / "arm_cables.xml")
    out = tmp_path / "robots"
    out.mkdir()
    proc = cdpr_here("import", "caspr", str(folder), "-o", str(out))
    assert proc.returncode == 2, proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert "arm_bodies.xml: a CASPR model with 2 link(s) (link_rigid)" in proc.stderr
    assert "(nothing written; --model NAME imports another of the folder's models alone)" in proc.stderr
    assert list(out.iterdir()) == []
    proc = cdpr_here("import", "caspr", str(folder), "--model", "ipanema_2", "-o", str(out))
    assert proc.returncode == 0, proc.stderr
    (folder / "arm_cables.xml").unlink()
    proc = cdpr_here("import", "caspr", str(folder), "-o", str(out))
    assert proc.returncode == 2
    assert f"{folder}: arm_bodies.xml has no arm_cables.xml beside it" in proc.stderr
    empty = tmp_path / "empty"
    empty.mkdir()
    proc = cdpr_here("import", "caspr", str(empty))
    assert proc.returncode == 2
    assert f"{empty}: no CASPR model in it (a model is NAME_bodies.xml and NAME_cables.xml" in proc.stderr


def test_a_set_it_cannot_model_is_left_out_unless_chosen(tmp_path: Path) -> None:
    """CAROCA with one cable of its gazebo_sim set routed to a link 2: the other sets import, the file's source and
    the report name what was left out; choosing that set is refused with the reason."""
    folder = _variant(tmp_path, "caroca", cables=("<link>1</link><location>0.6 -0.3 -0.2</location>",
                                                  "<link>2</link><location>0.6 -0.3 -0.2</location>"))
    proc = cdpr_here("import", "caspr", str(folder), "-o", str(tmp_path / "caroca.yaml"))
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    assert report["cable_sets"] == ["original", "with_rotating_pulleys"]
    left_out = "cable set 'gazebo_sim' was left out: attached to links 0, 2: cdpr imports cables that run from the " \
               "frame (link 0) straight to the platform (link 1)"
    assert left_out in report["notes"]
    assert "Cable set 'gazebo_sim' was left out" in yaml.safe_load((tmp_path / "caroca.yaml").read_text())["source"]
    proc = cdpr_here("import", "caspr", str(folder), "--cable-set", "gazebo_sim", "-o", str(tmp_path / "no.yaml"))
    assert proc.returncode == 2
    assert "cable set 'gazebo_sim', cable '1': attached to links 0, 2" in proc.stderr
    assert not (tmp_path / "no.yaml").exists()


def _variant(tmp_path: Path, name: str, bodies: tuple[str, str] | None = None,
             cables: tuple[str, str] | None = None, every: bool = False) -> Path:
    """A copy of fixture ``name``'s model with text replaced in its bodies and cables files (the first place, or
    ``every`` place); returns its folder."""
    folder = tmp_path / f"{name}_variant"
    folder.mkdir()
    for kind, change in (("bodies", bodies), ("cables", cables)):
        text = (FIXTURES / name / f"{name}_{kind}.xml").read_text()
        if change is not None:
            assert change[0] in text
            text = text.replace(*change) if every else text.replace(*change, 1)
        (folder / f"m_{kind}.xml").write_text(text)
    return folder


def test_a_vertical_planar_model_a_point_mass_and_an_inertia_about_the_joint(tmp_path: Path) -> None:
    """PLANAR_XZ (q = [x, z, θ_y]), T_XYZ with every cable at the COM, and an inertia given about the joint frame
    (ref="joint": moved to the COM by the parallel-axis theorem), each against numbers computed here (the first import
    as the real command's process, the others in this process)."""
    # PLANAR_XZ: CASPR's planar example turned into the x-z plane (every (x, y, 0) point as (x, 0, y))
    folder = _variant(tmp_path, "planar_xy_example", bodies=("PLANAR_XY", "PLANAR_XZ"))
    text = (folder / "m_cables.xml").read_text()
    text = re.sub(r"<location>(\S+) (\S+) (\S+)</location>", lambda m: f"<location>{m[1]} {m[3]} {m[2]}</location>",
                  text)
    (folder / "m_cables.xml").write_text(text)
    out = tmp_path / "xz.yaml"
    proc = cdpr("import", "caspr", str(folder), "-o", str(out), timeout=60)
    assert proc.returncode == 0, proc.stderr
    robot = load_robot(out)
    assert (robot.mode, robot.plane) == ("planar", "xz")
    np.testing.assert_array_equal(robot.home_position, [0.5, 0.0, 0.5])  # q_initial [0.5, 0.5, 0]: x, z, θ
    q = np.array([0.55, 0.45, 0.1])
    p, R = np.array([q[0], 0.0, q[1]]), elementary(1, q[2])
    ends = re.findall(r"<location>(\S+) (\S+) (\S+)</location>", text)
    cable_set = ends[: 2 * robot.m]
    a = np.array(cable_set[0::2], dtype=float)
    b = np.array(cable_set[1::2], dtype=float)
    np.testing.assert_allclose(inverse_kinematics(robot, p, R).lengths, np.linalg.norm(a - p - b @ R.T, axis=1),
                               rtol=1e-12)
    # T_XYZ with every platform point at the COM: a point-mass robot
    folder = _variant(tmp_path, "nist_robocrane", bodies=('type="SPATIAL_EULER_XYZ" q_initial="0 0 1.5 0 0 0" '
                                                          'q_min="-3.0 -3.0 0.0 -3.1416 -3.1416 -3.1416" '
                                                          'q_max="3.0 3.0 3.0 3.1416 3.1416 3.1416"',
                                                          'type="T_XYZ" q_initial="0 0 1.5" q_min="-3 -3 0" '
                                                          'q_max="3 3 3"'))
    cables = re.sub(r"(<link>1</link><location>)[^<]*", r"\g<1>0 0 0", (folder / "m_cables.xml").read_text())
    (folder / "m_cables.xml").write_text(cables)
    out = tmp_path / "pm.yaml"
    proc = cdpr_here("import", "caspr", str(folder), "-o", str(out))
    assert proc.returncode == 0, proc.stderr
    point = load_robot(out)
    assert point.mode == "point_mass"
    np.testing.assert_array_equal(point.platform_points, np.zeros((6, 3)))
    # ... and with its platform points off the COM: refused
    folder = _variant(tmp_path, "segesta", bodies=("SPATIAL_EULER_XYZ", "T_XYZ"))
    text = (folder / "m_bodies.xml").read_text()
    (folder / "m_bodies.xml").write_text(re.sub(r'q_initial="(\S+) (\S+) (\S+) \S+ \S+ \S+"', r'q_initial="\1 \2 \3"',
                                                text.replace('q_min="-1.0 -1.0 0.0 -3.1416 -3.1416 -3.1416"',
                                                             'q_min="-1 -1 0"').replace(
                                                    'q_max="1.0 1.0 1.0 3.1416 3.1416 3.1416"', 'q_max="1 1 1"')))
    proc = cdpr_here("import", "caspr", str(folder), "-o", str(tmp_path / "no.yaml"))
    assert proc.returncode == 2
    assert "joint type 'T_XYZ' with platform points off the centre of mass" in proc.stderr
    # an inertia about the joint frame: IPAnema 2's COM is 0.5 m above its joint frame
    folder = _variant(tmp_path, "ipanema_2", bodies=('<inertia ref="com">', '<inertia ref="joint">'))
    text = (folder / "m_bodies.xml").read_text().replace("<Ixx>1.0</Ixx>", "<Ixx>5.0</Ixx>").replace(
        "<Iyy>1.0</Iyy>", "<Iyy>6.0</Iyy>")
    (folder / "m_bodies.xml").write_text(text)
    out = tmp_path / "joint.yaml"
    proc = cdpr_here("import", "caspr", str(folder), "-o", str(out))
    assert proc.returncode == 0, proc.stderr
    # about the COM: I − m (|c|² 1 − c cᵀ), m = 10 kg, c = (0, 0, 0.5) m
    np.testing.assert_allclose(load_robot(out).inertia, np.diag([5.0 - 2.5, 6.0 - 2.5, 1.0]), rtol=0, atol=1e-12)
