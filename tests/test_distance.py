"""cdpr.mechanics.distance against computations written here from the definitions: the distance between a segment
and a convex polytope-like set is a convex quadratic program, whose minimum lies in the relative interior of one
face of its feasible set — so the least over every face's unconstrained minimiser that is feasible is exact (for
the segment pair, box and triangle); for the round shapes (sphere, cylinder), a golden-section search of the
convex distance along the segment. 10,000 random configurations each, with parallel, touching, degenerate and
inside cases."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from cdpr.mechanics import distance as dist
from cdpr.mechanics.rotation import rotvec_to_matrix

N = 10_000
TOL = 1e-12
FEASIBLE = 1e-12


def _faces_min(M: np.ndarray, q: np.ndarray, faces: list[tuple[np.ndarray, np.ndarray]], feasible) -> np.ndarray:
    """min ‖M z + q‖ over z feasible, for a batch: M (n, 3, k), q (n, 3); each face z = z0 + N w (z0 (k,), N (k, j))
    — its minimiser over w by least squares, kept where ``feasible(z)``."""
    best = np.full(len(q), np.inf)
    for z0, Nf in faces:
        base = np.einsum("nik,k->ni", M, z0) + q
        if Nf.shape[1]:
            MN = np.einsum("nik,kj->nij", M, Nf)
            w = -np.einsum("nji,ni->nj", np.linalg.pinv(MN), base)
            z = z0 + np.einsum("kj,nj->nk", Nf, w)
        else:
            z = np.broadcast_to(z0, (len(q), len(z0)))
        value = np.linalg.norm(np.einsum("nik,nk->ni", M, z) + q, axis=1)
        best = np.where(feasible(z), np.minimum(best, value), best)
    return best


def _interval_faces(k: int, bounds: list[tuple[float, float]]) -> list[tuple[np.ndarray, np.ndarray]]:
    """The faces of a product of intervals: each coordinate free, at its low or at its high bound."""
    faces = []
    for choice in itertools.product(("free", "low", "high"), repeat=k):
        z0 = np.array([0.0 if c == "free" else bounds[i][0] if c == "low" else bounds[i][1]
                       for i, c in enumerate(choice)])
        free = [i for i, c in enumerate(choice) if c == "free"]
        Nf = np.zeros((k, len(free)))
        for j, i in enumerate(free):
            Nf[i, j] = 1.0
        faces.append((z0, Nf))
    return faces


def _segments(rng: np.random.Generator, n: int) -> tuple[np.ndarray, ...]:
    """Random segment pairs, a fifth each: general, parallel, touching, collinear overlapping, one degenerate."""
    p0, p1 = rng.normal(0, 1, (n, 3)), rng.normal(0, 1, (n, 3))
    q0, q1 = rng.normal(0, 1, (n, 3)), rng.normal(0, 1, (n, 3))
    k = n // 5
    par = slice(k, 2 * k)  # parallel: q = a shifted, scaled copy of p's direction
    q0[par] = p0[par] + rng.normal(0, 0.5, (k, 3))
    q1[par] = q0[par] + rng.uniform(-2, 2, (k, 1)) * (p1[par] - p0[par])
    touch = slice(2 * k, 3 * k)  # touching: q starts on p
    q0[touch] = p0[touch] + rng.uniform(0, 1, (k, 1)) * (p1[touch] - p0[touch])
    col = slice(3 * k, 4 * k)  # collinear, overlapping or not
    q0[col] = p0[col] + rng.uniform(-1, 2, (k, 1)) * (p1[col] - p0[col])
    q1[col] = p0[col] + rng.uniform(-1, 2, (k, 1)) * (p1[col] - p0[col])
    deg = slice(4 * k, 4 * k + k // 2)  # a point
    q1[deg] = q0[deg]
    near = slice(4 * k + k // 2, 5 * k)  # nearly parallel: 1e-9 to 1e-3 rad apart, crossing or not
    h = k - k // 2
    turn = np.array([rotvec_to_matrix(w) for w in rng.normal(0, 1, (h, 3)) * 10 ** rng.uniform(-9, -3, (h, 1))])
    q0[near] = p0[near] + rng.normal(0, 0.3, (h, 3)) * rng.choice([0.0, 1e-6, 1.0], (h, 1))
    q1[near] = q0[near] + np.einsum("nij,nj->ni", turn, p1[near] - p0[near]) * rng.uniform(-2, 2, (h, 1))
    return p0, p1, q0, q1


def test_segment_segment_against_the_faces_of_the_unit_square() -> None:
    p0, p1, q0, q1 = _segments(np.random.default_rng(1), N)
    M = np.stack([p1 - p0, -(q1 - q0)], axis=2)  # z = (s, t): p0 + s d1 − q0 − t d2
    ref = _faces_min(M, p0 - q0, _interval_faces(2, [(0.0, 1.0)] * 2),
                     lambda z: np.all((z >= -FEASIBLE) & (z <= 1 + FEASIBLE), axis=1))
    got = np.array([dist.segments(*x).distance for x in zip(p0, p1, q0, q1, strict=True)])
    assert np.abs(got - ref).max() <= TOL
    d, s, t = dist.segment_distances(p0, p1, q0, q1)  # the vectorised form, the same
    assert np.abs(d - ref).max() <= TOL
    vec = np.linalg.norm(p0 + s[:, None] * (p1 - p0) - q0 - t[:, None] * (q1 - q0), axis=1)
    assert np.abs(vec - ref).max() <= 1e-9  # the closest points of a nearly parallel pair: to its conditioning
    assert np.all(got[2 * (N // 5):3 * (N // 5)] <= TOL)  # touching


def _boxes(rng: np.random.Generator, n: int) -> tuple[np.ndarray, ...]:
    c = rng.normal(0, 0.5, (n, 3))
    R = np.array([rotvec_to_matrix(w) for w in rng.normal(0, 1.5, (n, 3))])
    h = rng.uniform(0.05, 1.0, (n, 3))
    p0, p1 = rng.normal(0, 1.5, (n, 3)), rng.normal(0, 1.5, (n, 3))
    k = n // 5
    face = slice(k, 2 * k)  # parallel to a face, just touching it or not
    local = rng.uniform(-1, 1, (k, 2, 3)) * h[face, None, :]
    local[:, :, 2] = h[face, None, 2] * np.where(rng.uniform(size=(k, 1)) < 0.5, 1.0, rng.uniform(1, 1.5, (k, 1)))
    p0[face] = c[face] + np.einsum("nij,nj->ni", R[face], local[:, 0])
    p1[face] = c[face] + np.einsum("nij,nj->ni", R[face], local[:, 1])
    inside = slice(2 * k, 3 * k)  # one end inside
    p0[inside] = c[inside] + np.einsum("nij,nj->ni", R[inside], rng.uniform(-0.9, 0.9, (k, 3)) * h[inside])
    return c, R, h, p0, p1


def test_segment_box_against_the_faces_of_segment_times_box() -> None:
    c, R, h, p0, p1 = _boxes(np.random.default_rng(2), N)
    a = np.einsum("nji,nj->ni", R, p0 - c)  # box frame
    d = np.einsum("nji,nj->ni", R, p1 - p0)
    M = np.concatenate([d[:, :, None], -np.broadcast_to(np.eye(3), (N, 3, 3))], axis=2)  # z = (t, x)
    best = np.full(N, np.inf)
    for i in range(N):  # the box differs per configuration: the faces too
        faces = _interval_faces(4, [(0.0, 1.0), *[(-h[i, j], h[i, j]) for j in range(3)]])
        lo, hi = np.array([0.0, *(-h[i])]), np.array([1.0, *h[i]])
        best[i] = _faces_min(M[i:i + 1], a[i:i + 1], faces,
                             lambda z, lo=lo, hi=hi: np.all((z >= lo - FEASIBLE) & (z <= hi + FEASIBLE), axis=1))[0]
        if i >= 1500:  # the faces' enumeration is slow in a loop: the rest against a vectorised grid of boxes
            break
    got = np.array([dist.segment_box(p0[i], p1[i], c[i], R[i], h[i]).distance for i in range(N)])
    assert np.abs(got[:1501] - best[:1501]).max() <= TOL
    ref = _golden(lambda t: _point_box(a[:, None, :] + t[..., None] * d[:, None, :], h), N)
    assert np.abs(got - ref).max() <= TOL


def _point_box(x: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Distance of points x (n, k, 3) to the boxes of half sizes h (n, 3), in their frames: from the definition."""
    return np.linalg.norm(np.maximum(np.abs(x) - h[:, None, :], 0.0), axis=2)


def _golden(f, n: int, iterations: int = 200) -> np.ndarray:
    """min over t in [0, 1] of a convex f, for n functions at once: golden-section search to the last bit, then the
    least of the bracket and both ends (f maps (n, k) parameters to (n, k) values)."""
    lo, hi = np.zeros(n), np.ones(n)
    g = (math.sqrt(5.0) - 1.0) / 2.0
    for _ in range(iterations):
        x1, x2 = hi - g * (hi - lo), lo + g * (hi - lo)
        f1, f2 = f(np.stack([x1, x2], axis=1)).T
        left = f1 <= f2
        hi = np.where(left, x2, hi)
        lo = np.where(left, lo, x1)
    ends = np.stack([np.zeros(n), np.ones(n), lo, hi, 0.5 * (lo + hi)], axis=1)
    return f(ends).min(axis=1)


def test_segment_sphere_and_cylinder_against_a_search_along_the_segment() -> None:
    rng = np.random.default_rng(3)
    c = rng.normal(0, 0.5, (N, 3))
    R = np.array([rotvec_to_matrix(w) for w in rng.normal(0, 1.5, (N, 3))])
    r, hl = rng.uniform(0.05, 1.0, N), rng.uniform(0.05, 1.0, N)
    p0, p1 = rng.normal(0, 1.5, (N, 3)), rng.normal(0, 1.5, (N, 3))
    k = N // 4
    axial = slice(k, 2 * k)  # parallel to the axis, on the surface or off it
    off = np.stack([r[axial] * rng.choice([1.0, 1.3], k), np.zeros(k), rng.uniform(-2, 2, k)], axis=1)
    p0[axial] = c[axial] + np.einsum("nij,nj->ni", R[axial], off)
    p1[axial] = p0[axial] + R[axial][:, :, 2] * rng.uniform(-2, 2, (k, 1))
    a = np.einsum("nji,nj->ni", R, p0 - c)
    d = np.einsum("nji,nj->ni", R, p1 - p0)

    def cylinder(t: np.ndarray) -> np.ndarray:
        x = a[:, None, :] + t[..., None] * d[:, None, :]
        radial = np.maximum(np.hypot(x[..., 0], x[..., 1]) - r[:, None], 0.0)
        axial_ = np.maximum(np.abs(x[..., 2]) - hl[:, None], 0.0)
        return np.hypot(radial, axial_)

    got = np.array([dist.segment_cylinder(p0[i], p1[i], c[i], R[i], r[i], hl[i]).distance for i in range(N)])
    assert np.abs(got - _golden(cylinder, N)).max() <= TOL

    def sphere(t: np.ndarray) -> np.ndarray:
        x = (p0 - c)[:, None, :] + t[..., None] * (p1 - p0)[:, None, :]
        return np.maximum(np.linalg.norm(x, axis=2) - r[:, None], 0.0)

    got = np.array([dist.segment_sphere(p0[i], p1[i], c[i], r[i]).distance for i in range(N)])
    assert np.abs(got - _golden(sphere, N)).max() <= TOL


def _triangle_faces() -> list[tuple[np.ndarray, np.ndarray]]:
    """The faces of [0, 1] × the triangle {u, v ≥ 0, u + v ≤ 1}: z = (t, u, v)."""
    tri = [(np.array([0.0, 0.0]), np.eye(2)),  # interior
           (np.array([0.0, 0.0]), np.array([[0.0], [1.0]])), (np.array([0.0, 0.0]), np.array([[1.0], [0.0]])),
           (np.array([1.0, 0.0]), np.array([[-1.0], [1.0]])),  # u = 0, v = 0, u + v = 1
           (np.array([0.0, 0.0]), np.zeros((2, 0))), (np.array([1.0, 0.0]), np.zeros((2, 0))),
           (np.array([0.0, 1.0]), np.zeros((2, 0)))]
    faces = []
    for t0, tN in ((0.0, np.ones((1, 1))), (0.0, np.zeros((1, 0))), (1.0, np.zeros((1, 0)))):
        for z0, Nf in tri:
            full = np.zeros((3, tN.shape[1] + Nf.shape[1]))
            full[:1, :tN.shape[1]] = tN
            full[1:, tN.shape[1]:] = Nf
            faces.append((np.array([t0, *z0]), full))
    return faces


def _triangle_feasible(z: np.ndarray) -> np.ndarray:
    return ((z[:, 0] >= -FEASIBLE) & (z[:, 0] <= 1 + FEASIBLE) & (z[:, 1] >= -FEASIBLE) & (z[:, 2] >= -FEASIBLE)
            & (z[:, 1] + z[:, 2] <= 1 + FEASIBLE))


def test_segment_triangle_and_mesh_against_the_faces_of_segment_times_triangle() -> None:
    rng = np.random.default_rng(4)
    T = rng.normal(0, 1, (N, 3, 3))
    p0, p1 = rng.normal(0, 1, (N, 3)), rng.normal(0, 1, (N, 3))
    k = N // 4
    cross = slice(k, 2 * k)  # through the triangle, or ending on it
    w = rng.dirichlet([1, 1, 1], k)
    inside = np.einsum("nk,nki->ni", w, T[cross])
    p0[cross] = inside + rng.normal(0, 1, (k, 3)) * rng.choice([0.0, 1.0], (k, 1))
    p1[cross] = inside + (inside - p0[cross]) * rng.uniform(0, 1, (k, 1))
    inplane = slice(2 * k, 3 * k)  # in the triangle's plane
    e1, e2 = T[inplane, 1] - T[inplane, 0], T[inplane, 2] - T[inplane, 0]
    uv = rng.uniform(-0.5, 1.5, (k, 2, 2))
    p0[inplane] = T[inplane, 0] + uv[:, 0, :1] * e1 + uv[:, 0, 1:] * e2
    p1[inplane] = T[inplane, 0] + uv[:, 1, :1] * e1 + uv[:, 1, 1:] * e2
    A = T[:, 0]
    M = np.stack([p1 - p0, -(T[:, 1] - A), -(T[:, 2] - A)], axis=2)
    ref = _faces_min(M, p0 - A, _triangle_faces(), _triangle_feasible)
    got = np.array([dist.segment_triangle(p0[i], p1[i], T[i]).distance for i in range(N)])
    assert np.abs(got - ref).max() <= TOL
    # a mesh of 8 of them, against every segment: the least
    mesh = T[:8]
    M8 = np.stack([np.broadcast_to(p1 - p0, (8, N, 3)).transpose(1, 0, 2).reshape(-1, 3),
                   -np.tile(mesh[:, 1] - mesh[:, 0], (N, 1)), -np.tile(mesh[:, 2] - mesh[:, 0], (N, 1))], axis=2)
    q8 = np.repeat(p0, 8, axis=0) - np.tile(mesh[:, 0], (N, 1))
    ref8 = _faces_min(M8, q8, _triangle_faces(), _triangle_feasible).reshape(N, 8).min(axis=1)
    got8 = np.array([dist.segment_mesh(p0[i], p1[i], mesh).distance for i in range(N)])
    assert np.abs(got8 - ref8).max() <= TOL


def test_closest_points_are_on_their_shapes_and_as_far_apart_as_the_distance() -> None:
    rng = np.random.default_rng(5)
    R = rotvec_to_matrix([0.3, -0.2, 0.5])
    c, h = np.array([0.1, 0.2, 0.3]), np.array([0.4, 0.3, 0.2])
    for _ in range(200):
        p0, p1 = rng.normal(0, 1.5, 3), rng.normal(0, 1.5, 3)
        for res, inside in (
                (dist.segment_box(p0, p1, c, R, h), lambda x: np.all(np.abs(R.T @ (x - c)) <= h + 1e-12)),
                (dist.segment_cylinder(p0, p1, c, R, 0.3, 0.4), lambda x: (np.hypot(*(R.T @ (x - c))[:2]) <= 0.3 + 1e-12
                                                                         and abs((R.T @ (x - c))[2]) <= 0.4 + 1e-12)),
                (dist.segment_sphere(p0, p1, c, 0.5), lambda x: np.linalg.norm(x - c) <= 0.5 + 1e-12)):
            assert inside(res.on_other)
            assert np.linalg.norm(res.on_segment - (p0 + res.s * (p1 - p0))) <= 1e-12
            assert np.linalg.norm(res.on_segment - res.on_other) == pytest.approx(res.distance, abs=1e-12)
    with pytest.raises(ValueError, match="triangles"):
        dist.segment_mesh(np.zeros(3), np.ones(3), np.zeros((2, 3)))
