"""Interference before a session (cdpr.mechanics.interference, cdpr check): cable pairs against the test's own
distances, the platform test against points of the cable, meshes read from STL and OBJ files, the shipped
crossing and obstacle scenarios, bad scenes refused in one line."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
import yaml

from cdpr.config.loading import resolve
from cdpr.config.mesh import load_mesh
from cdpr.config.robot import load_robot
from cdpr.mechanics.interference import Obstacle, cable_platform, clearances, spans
from cdpr.mechanics.rotation import rotvec_to_matrix
from conftest import cdpr
from test_distance import _faces_min, _interval_faces

CUBE = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
CUBE_FACES = [(0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5), (0, 4, 5), (0, 5, 1), (2, 3, 7), (2, 7, 6), (0, 2, 6),
              (0, 6, 4), (1, 5, 7), (1, 7, 3)]


def _poses(n: int, seed: int) -> list[tuple[np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(seed)
    return [(rng.uniform([-1.5, -1.0, 0.3], [1.5, 1.0, 2.2]), rotvec_to_matrix(rng.normal(0, 0.5, 3)))
            for _ in range(n)]


def test_cable_pairs_are_the_least_distance_of_pairs_that_share_no_end() -> None:
    robot = load_robot("caroca")
    for p, R in _poses(200, 1):
        exits, points = spans(robot, p, R)
        best = np.inf
        for i in range(8):
            for j in range(i + 1, 8):
                if np.allclose(exits[i], exits[j]) or np.allclose(points[i], points[j]):
                    continue  # CAROCA's pairs leave the frame at one point
                # the segments' distance by sampling both finely, then refined on the best cell (independent)
                s = np.linspace(0.0, 1.0, 401)
                a = exits[i] + s[:, None] * (points[i] - exits[i])
                b = exits[j] + s[:, None] * (points[j] - exits[j])
                d = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2)
                best = min(best, float(d.min()))
        got = clearances(robot, p, R).cable_cable.distance
        assert got <= best + 1e-12
        assert best - got <= 0.02  # the grid's spacing bounds how far above the minimum it can be


def test_a_cable_runs_into_the_platform_exactly_when_its_angle_is_negative() -> None:
    robot = load_robot("caroca")
    half = 0.5 * np.array(robot.shape.size)
    seen = {True: 0, False: 0}
    for p, R in _poses(2000, 2):
        exits, points = spans(robot, p, R)
        angle = cable_platform(robot, exits, points, p, R)
        # independent: a point of each cable just off its platform point, in the box?
        into = False
        for i in range(8):
            x = R.T @ (points[i] + 1e-6 * (exits[i] - points[i]) / np.linalg.norm(exits[i] - points[i]) - p)
            into |= bool(np.all(np.abs(x) < half))
        if abs(angle.distance) > 1e-4:
            assert (angle.distance < 0.0) == into
            seen[into] += 1
    assert seen[True] > 50
    assert seen[False] > 50


def _write_stl(path: Path, triangles: np.ndarray, binary: bool) -> None:
    if binary:
        out = bytearray(80) + struct.pack("<I", len(triangles))
        for t in triangles:
            out += struct.pack("<3f", 0.0, 0.0, 0.0) + struct.pack("<9f", *t.ravel()) + b"\0\0"
        path.write_bytes(bytes(out))
    else:
        lines = ["solid cube"]
        for t in triangles:
            lines += ["facet normal 0 0 0", " outer loop", *[f"  vertex {x} {y} {z}" for x, y, z in t],
                      " endloop", "endfacet"]
        path.write_text("\n".join([*lines, "endsolid cube"]), encoding="ascii")


def test_a_mesh_cube_read_from_stl_and_obj_keeps_the_cables_as_far_as_a_box(tmp_path: Path) -> None:
    triangles = CUBE[np.array(CUBE_FACES)]
    _write_stl(tmp_path / "b.stl", triangles, binary=True)
    _write_stl(tmp_path / "a.stl", triangles, binary=False)
    obj = ["v {} {} {}".format(*v) for v in CUBE] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in CUBE_FACES]
    (tmp_path / "c.obj").write_text("\n".join(obj), encoding="utf-8")
    for name in ("a.stl", "b.stl", "c.obj"):
        assert load_mesh(tmp_path / name) == pytest.approx(triangles)
    robot = load_robot("caroca")
    centre, R = np.array([1.9, 0.4, 0.6]), rotvec_to_matrix([0.1, 0.2, 0.3])
    box = Obstacle("box", "box", centre, R, size=np.ones(3))
    mesh = Obstacle("mesh", "mesh", centre, R, triangles=triangles @ R.T + centre)
    compared = 0
    for p, Rp in _poses(100, 3):
        b, m = clearances(robot, p, Rp, (box,)), clearances(robot, p, Rp, (mesh,))
        if b.cable_obstacle.distance > 0.0:  # a surface and a solid agree outside
            assert m.cable_obstacle.distance == pytest.approx(b.cable_obstacle.distance, abs=1e-12)
            compared += 1
    assert compared > 50


def _scenario(tmp_path: Path, base: str, **changes: object) -> Path:
    doc = yaml.safe_load(resolve(base, "scenarios", "scenario").read_text(encoding="utf-8"))
    doc.update(changes)
    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False), encoding="utf-8")
    return path


def test_cdpr_check_gives_the_crossing_cables_and_the_step_they_cross() -> None:
    res = cdpr("check", "caroca_15kg_crossing")
    assert res.returncode == 3, res.stderr
    assert res.stderr.strip().count("\n") == 0
    assert "cables 0 and 2 crossed since step 2159" in res.stderr
    assert "(step 2160)" in res.stderr
    every = cdpr("check", "caroca_15kg_crossing", "--every", "1", "--json")
    assert json.loads(every.stdout)["violation"]["step"] == 2160  # every step: the same one


def test_cdpr_check_gives_the_clearance_to_an_obstacle_and_its_margin(tmp_path: Path) -> None:
    res = cdpr("check", "caroca_15kg_obstacle", "--json")
    assert res.returncode == 0, res.stderr
    least = json.loads(res.stdout)["least"]["cable-obstacle"]
    assert least["between"] == "cable 3 and obstacle post"
    assert 0.05 < least["clearance"] < 0.065
    res = cdpr("check", "caroca_15kg_obstacle", "--margin", "0.07")
    assert res.returncode == 3
    assert "cable 3 and obstacle post" in res.stderr
    on_floor = _scenario(tmp_path, "caroca_15kg_obstacle", scene={"floor": 0.05})
    res = cdpr("check", str(on_floor))
    assert res.returncode == 3
    assert "below the floor" in res.stderr


@pytest.mark.parametrize(("scene", "why"), [
    ({"obstacles": [{"name": "p", "type": "cylinder", "position": [0, 0, 0], "radius": 0.1}]}, "length: a cylinder"),
    ({"obstacles": [{"name": "p", "type": "box", "position": [0, 0, 0], "size": [1, 1, 1], "radius": 1.0}]},
     "radius: a box has none"),
    ({"obstacles": [{"name": "m", "type": "mesh", "position": [0, 0, 0], "file": "missing.stl"}]}, "missing.stl"),
    ({"obstacles": [{"name": "m", "type": "mesh", "position": [0, 0, 0], "file": "bad.stl"}]}, "bad.stl"),
    ({"obstacles": [{"name": "m", "type": "mesh", "position": [0, 0, 0], "file": "short.obj"}]}, "line 2"),
])
def test_a_bad_scene_is_one_line_and_exit_2(tmp_path: Path, scene: dict[str, object], why: str) -> None:
    (tmp_path / "bad.stl").write_bytes(b"\xff\xfe not a mesh at all" * 10)
    (tmp_path / "short.obj").write_text("v 0 0 0\nv 1 0\nv 0 1 0\nf 1 2 3\n", encoding="utf-8")
    res = cdpr("check", str(_scenario(tmp_path, "caroca_15kg_obstacle", scene=scene)))
    assert res.returncode == 2, res.stderr
    assert why in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1, res.stderr


def test_the_interference_free_workspace_agrees_with_a_brute_force_check_of_its_grid() -> None:
    from cdpr.mechanics.interference import interference_free
    from cdpr.mechanics.rotation import rpy_to_matrix
    from cdpr.mechanics.workspace import grid_points

    robot, margin = load_robot("caroca"), 0.02
    R = rpy_to_matrix(0.0, 0.0, 0.3)
    points, _, _ = grid_points(robot, 0.25)
    free, _ = interference_free(robot, points, R, margin)
    # brute force, the test's own: each pair's distance as the least over the faces of the unit square (the convex
    # QP of the two segments' parameters: test_distance's), each cable's first micrometre tested against the box
    half = 0.5 * np.array(robot.shape.size)
    E = np.asarray(robot.frame_points)
    pairs = [(i, j) for i in range(8) for j in range(i + 1, 8)
             if not np.allclose(E[i], E[j]) and not np.allclose(robot.platform_points[i], robot.platform_points[j])]
    expected = np.ones(len(points), dtype=bool)
    B = points[:, None, :] + (robot.platform_points @ R.T)[None]  # (n, 8, 3)
    for i, j in pairs:
        d1, d2, r = B[:, i] - E[i], B[:, j] - E[j], np.broadcast_to(E[i] - E[j], B[:, i].shape)
        M = np.stack([d1, -d2], axis=2)  # z = (s, t): r + s d1 − t d2
        best = _faces_min(M, r, _interval_faces(2, [(0.0, 1.0)] * 2),
                          lambda z: np.all((z >= -1e-12) & (z <= 1 + 1e-12), axis=1))
        expected &= best > margin
    for i in range(8):
        u = (E[i] - B[:, i]) / np.linalg.norm(E[i] - B[:, i], axis=1)[:, None]
        x = (B[:, i] + 1e-6 * u - points) @ R
        expected &= ~np.all(np.abs(x) < half, axis=1)
    assert np.array_equal(free, expected)
    assert 0 < free.sum() < len(points)
    res = cdpr("workspace", "caroca", "--step", "0.25", "--orientation", "0", "0", "0.3", "--interference",
               "--margin", "0.02", "--tmin", "1", "--tmax", "6500", "--mass", "15")
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout.strip().splitlines()[-1])["interference_free"] == int(free.sum())
