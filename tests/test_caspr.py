"""`cdpr import caspr` (#32): eight single-rigid-body robots of CASPR's model library, imported from XML files in
CASPR's format (tests/caspr/: the published models' numbers), against cable lengths and wrench matrices computed
here from the XML alone; then a short session of each. The eight imports share one process, and so do the
sessions but one (each `cdpr run --in-process`: the same nodes, messages and states); that one runs as separate
processes."""

from __future__ import annotations

import json
import re
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


def test_the_eight_robots_are_there() -> None:
    assert MODELS == ["caspr_spatial_example", "fast", "ipanema_1", "ipanema_2", "mpi_cable_robot_simulator",
                      "nist_robocrane", "planar_xy_example", "segesta"]


def elementary(axis: int, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    i, j = [k for k in range(3) if k != axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


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
        for c in cable_els:
            ends = c.findall("attachments/attachment")
            self.a.append(np.array(ends[0].findtext("location").split(), dtype=float))
            b = np.array(ends[1].findtext("location").split(), dtype=float)
            self.b.append(b + self.com if c.get("attachment_reference") == "com" else b)  # from the joint frame
            self.fmin.append(float(c.findtext("properties/force_min")))
            self.fmax.append(float(c.findtext("properties/force_max")))

    def pose(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The joint frame's position and rotation at joint coordinates q (CASPR's joint models)."""
        if self.joint == "SPATIAL_EULER_XYZ":
            return q[:3], elementary(0, q[3]) @ elementary(1, q[4]) @ elementary(2, q[5])
        assert self.joint == "PLANAR_XY"
        return np.array([q[0], q[1], 0.0]), elementary(2, q[2])

    def lengths_and_wrench(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cable lengths, and W with moments about the centre of mass, at q."""
        p, R = self.pose(q)
        lengths, W = [], []
        for a, b in zip(self.a, self.b, strict=True):
            v = a - (p + R @ b)
            L = float(np.sqrt(v @ v))
            d = v / L
            lengths.append(L)
            W.append(np.r_[d, np.cross(R @ (b - self.com), d)])
        return np.array(lengths), np.array(W).T

    def turned(self) -> np.ndarray:
        """A pose beside q_initial, rotated."""
        q = self.q0.copy()
        if self.joint == "PLANAR_XY":
            return q + np.array([0.02, -0.01, 0.1])
        return q + np.array([0.01, -0.02, 0.015, 0.05, -0.04, 0.1])


@pytest.fixture(scope="module")
def imports(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, subprocess.CompletedProcess[str]]]:
    """Each model imported once by `cdpr import caspr` (as :func:`_import` does; the eight in one process), for the
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


@pytest.mark.parametrize("name", MODELS)
def test_the_import_has_caspr_s_lengths_and_wrench_matrix(name: str, imports: dict) -> None:
    path, report = _imported(imports, name)
    robot = load_robot(path)
    model = Caspr(name)
    assert robot.m == len(model.a) == report["cables"]
    assert robot.mass == model.mass
    assert robot.tmin.tolist() == model.fmin
    assert robot.tmax.tolist() == model.fmax
    assert robot.mode == ("planar" if model.joint == "PLANAR_XY" else "spatial")
    home_q = model.q0.copy()
    if name in HOME:
        home_q[:3] = [0.0, 0.0, 200.0]
    for q in (home_q, model.turned()):
        lengths, W = model.lengths_and_wrench(q)
        p, R = model.pose(q)
        ours = inverse_kinematics(robot, p + R @ model.com, R)  # the project's platform frame is at the COM
        np.testing.assert_allclose(ours.lengths, lengths, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(ours.wrench_matrix, W, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(robot.home_position, model.pose(home_q)[0] + model.pose(home_q)[1] @ model.com,
                               rtol=0, atol=1e-12)
    assert "Assumed (CASPR does not give them)" in robot.source


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
    """A 0.6 s scenario of the imported robot at ``path``: a small quintic move along x from its home."""
    robot = load_robot(path)
    step = 0.005 if robot.mode == "spatial" else 0.002  # m along x from home
    scenario = {
        "name": f"caspr_{name}", "robot": str(path), "dt": 0.001, "duration": 0.6,
        "trajectory": {"type": "quintic", "waypoints": [
            {"t": 0.0, "position": robot.home_position.tolist()},
            {"t": 0.5, "position": (robot.home_position + np.array([step, 0.0, 0.0])).tolist()}]},
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
    if "cables" in change:
        cables = cables.replace(*change["cables"], 1)
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
