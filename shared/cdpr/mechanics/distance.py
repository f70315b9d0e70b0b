"""Distances between a cable's straight span (a segment) and what it may touch: another span, a sphere, a box, a
cylinder, a triangle mesh. Pure numpy, no I/O; every shape is solid (a segment inside one is at distance 0).

Each function returns the distance and the closest points (on the segment first). Conventions:

* A segment is its two end points ``p0, p1`` (world frame, m); a degenerate one (``p0 = p1``) is a point.
* A box is its centre, its rotation ``R`` (box frame → world) and its half sizes; a cylinder its centre, ``R``
  (its axis is R's z column), radius and half length; a sphere its centre and radius; a mesh its triangles
  ``(n, 3, 3)`` (a closed mesh is *not* filled: the distance is to its surface).
* Exact up to rounding: segment–segment, –sphere, –box and –triangle are closed forms (for the box, the segment is
  cut where it crosses the box's slabs, and on each piece the squared distance is one quadratic in the segment's
  parameter, minimised exactly); for the cylinder the pieces where both the radial and the axial excess are
  positive are convex in the parameter and minimised by safeguarded Newton steps to rounding.
"""

from __future__ import annotations

import itertools
import math
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from cdpr.mechanics.rotation import Array

_NEAR_PARALLEL = 1e-8  # sin² of the angle below which segment_distances searches instead of solving (1e-4 rad)


class Closest(NamedTuple):
    """A distance and where it is reached: ``on_segment`` (the first shape's point) and ``on_other``."""

    distance: float
    on_segment: Array  # (3,)
    on_other: Array  # (3,)
    s: float  # the segment's parameter at its closest point, in [0, 1]


def _clamp(x: float) -> float:
    return 0.0 if x < 0.0 else 1.0 if x > 1.0 else x


def segment_distances(p0: Array, p1: Array, q0: Array, q1: Array) -> tuple[Array, Array, Array]:
    """(distance, s, t) of segment pairs, vectorised over leading axes (…, 3): the least of the interior stationary
    point (Ericson, Real-Time Collision Detection 5.1.9) and the four edges of the unit square (each end of one
    segment against the other, clamped) — every face of the convex problem, so that nearly parallel segments,
    whose interior point is ill-conditioned, are exact too; an interior point's distance is the lines'
    ``|r · n| / |n|``, n = d1 × d2."""
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a = np.einsum("...i,...i->...", d1, d1)
    e = np.einsum("...i,...i->...", d2, d2)
    with np.errstate(divide="ignore", invalid="ignore"):
        cands_s, cands_t, dists = [], [], []
        for fix_s in (0.0, 1.0):  # an end of p against q
            x = p0 + fix_s * d1
            t = np.where(e > 0.0, np.clip(np.einsum("...i,...i->...", x - q0, d2) / np.where(e > 0.0, e, 1.0), 0, 1),
                         0.0)
            cands_s.append(np.full_like(t, fix_s))
            cands_t.append(t)
            dists.append(np.linalg.norm(x - q0 - t[..., None] * d2, axis=-1))
        for fix_t in (0.0, 1.0):  # an end of q against p
            y = q0 + fix_t * d2
            s = np.where(a > 0.0, np.clip(np.einsum("...i,...i->...", y - p0, d1) / np.where(a > 0.0, a, 1.0), 0, 1),
                         0.0)
            cands_s.append(s)
            cands_t.append(np.full_like(s, fix_t))
            dists.append(np.linalg.norm(p0 + s[..., None] * d1 - y, axis=-1))
        b = np.einsum("...i,...i->...", d1, d2)
        c = np.einsum("...i,...i->...", d1, r)
        f = np.einsum("...i,...i->...", d2, r)
        denom = a * e - b * b
        ok = denom > _NEAR_PARALLEL * a * e
        s = (b * f - c * e) / np.where(ok, denom, 1.0)
        t = (a * f - b * c) / np.where(ok, denom, 1.0)
        inside = ok & (s >= 0.0) & (s <= 1.0) & (t >= 0.0) & (t <= 1.0)
        n = np.cross(d1, d2)
        line = np.abs(np.einsum("...i,...i->...", r, n)) / np.sqrt(np.einsum("...i,...i->...", n, n))
        cands_s.append(np.where(inside, s, 0.0))
        cands_t.append(np.where(inside, t, 0.0))
        dists.append(np.where(inside, line, np.inf))
        # nearly parallel (the interior point ill-conditioned, < 1e-4 rad): the distance from p(s) to segment q is
        # convex in s and well-conditioned; a golden-section search over s finds its least to the last bit
        near = ~ok & (a > 0.0) & (e > 0.0)
        s_near = np.zeros_like(a)
        if np.any(near):
            s_near[near] = _golden_s(p0[near], d1[near], q0[near], d2[near], e[near])
        x = p0 + s_near[..., None] * d1
        t_near = np.where(e > 0.0, np.clip(np.einsum("...i,...i->...", x - q0, d2) / np.where(e > 0.0, e, 1.0), 0, 1),
                          0.0)
        cands_s.append(s_near)
        cands_t.append(t_near)
        dists.append(np.where(near, np.linalg.norm(x - q0 - t_near[..., None] * d2, axis=-1), np.inf))
    D_ = np.stack(dists, axis=-1)
    k = np.argmin(D_, axis=-1)[..., None]
    pick = lambda xs: np.take_along_axis(np.stack(xs, axis=-1), k, axis=-1)[..., 0]  # noqa: E731
    return pick(dists), pick(cands_s), pick(cands_t)


def _golden_s(p0: Array, d1: Array, q0: Array, d2: Array, e: Array) -> Array:
    """argmin over s in [0, 1] of the distance from p0 + s d1 to the segment q0 + t d2 (rows (n, 3)), a convex
    function: golden-section search, 80 halvings of the bracket by the golden ratio (below 1e-16)."""
    def f(s: Array) -> Array:
        x = p0 + s[:, None] * d1
        t = np.clip(np.einsum("ni,ni->n", x - q0, d2) / e, 0.0, 1.0)
        return np.linalg.norm(x - q0 - t[:, None] * d2, axis=1)

    lo, hi = np.zeros(len(p0)), np.ones(len(p0))
    g = (math.sqrt(5.0) - 1.0) / 2.0
    for _ in range(80):
        x1, x2 = hi - g * (hi - lo), lo + g * (hi - lo)
        left = f(x1) <= f(x2)
        hi = np.where(left, x2, hi)
        lo = np.where(left, lo, x1)
    return 0.5 * (lo + hi)


def segments(p0: ArrayLike, p1: ArrayLike, q0: ArrayLike, q1: ArrayLike) -> Closest:
    """Segment p0p1 to segment q0q1."""
    P0, P1, Q0, Q1 = (np.asarray(x, dtype=float) for x in (p0, p1, q0, q1))
    d, s, t = segment_distances(P0, P1, Q0, Q1)
    a, b = P0 + float(s) * (P1 - P0), Q0 + float(t) * (Q1 - Q0)
    return Closest(float(d), a, b, float(s))


def segment_point(p0: ArrayLike, p1: ArrayLike, x: ArrayLike) -> Closest:
    """Segment p0p1 to point x."""
    P0, P1, X = (np.asarray(v, dtype=float) for v in (p0, p1, x))
    d = P1 - P0
    dd = float(d @ d)
    s = _clamp(float((X - P0) @ d) / dd) if dd > 0.0 else 0.0
    a = P0 + s * d
    return Closest(float(np.linalg.norm(X - a)), a, X.copy(), s)


def segment_sphere(p0: ArrayLike, p1: ArrayLike, centre: ArrayLike, radius: float) -> Closest:
    """Segment p0p1 to the solid sphere (0 when they meet; the sphere's point: towards the segment's)."""
    c = segment_point(p0, p1, centre)
    if c.distance <= radius:
        return Closest(0.0, c.on_segment, c.on_segment.copy(), c.s)
    towards = c.on_other + radius * (c.on_segment - c.on_other) / c.distance
    return Closest(c.distance - radius, c.on_segment, towards, c.s)


def _quadratic_min(a: float, b: float, c: float, lo: float, hi: float) -> tuple[float, float]:
    """(t, value) minimising a t² + b t + c on [lo, hi] (a ≥ 0)."""
    t = _clamp_to(-b / (2.0 * a), lo, hi) if a > 0.0 else (lo if b >= 0.0 else hi)
    return t, max(0.0, (a * t + b) * t + c)


def _clamp_to(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else hi if x > hi else x


def _frame(p0: ArrayLike, p1: ArrayLike, centre: ArrayLike, R: ArrayLike) -> tuple[Array, Array, Array, Array]:
    Rm = np.asarray(R, dtype=float)
    c = np.asarray(centre, dtype=float)
    a = Rm.T @ (np.asarray(p0, dtype=float) - c)
    d = Rm.T @ (np.asarray(p1, dtype=float) - c) - a
    return a, d, c, Rm


def segment_box(p0: ArrayLike, p1: ArrayLike, centre: ArrayLike, R: ArrayLike, half: ArrayLike) -> Closest:
    """Segment p0p1 to the solid box (centre, rotation R box → world, half sizes)."""
    a, d, c, Rm = _frame(p0, p1, centre, R)
    h = np.asarray(half, dtype=float)
    cuts = {0.0, 1.0}
    for j in range(3):
        if d[j] != 0.0:
            for bound in (-h[j], h[j]):
                t = (bound - a[j]) / d[j]
                if 0.0 < t < 1.0:
                    cuts.add(float(t))
    knots = sorted(cuts)
    best_t, best = 0.0, math.inf
    for lo, hi in itertools.pairwise(knots):
        mid = a + 0.5 * (lo + hi) * d
        qa = qb = qc = 0.0
        for j in range(3):  # on this piece, each axis is below, within or above its slab throughout
            bound = -h[j] if mid[j] < -h[j] else h[j] if mid[j] > h[j] else None
            if bound is not None:
                off = a[j] - bound
                qa += d[j] * d[j]
                qb += 2.0 * d[j] * off
                qc += off * off
        t, value = _quadratic_min(qa, qb, qc, lo, hi)
        if value < best:
            best_t, best = t, value
    point = a + best_t * d
    inside = np.clip(point, -h, h)
    return Closest(float(np.linalg.norm(point - inside)), c + Rm @ point, c + Rm @ inside, best_t)


def _cylinder_excess(x: Array, radius: float, half_length: float) -> tuple[float, Array]:
    """The distance of point x (cylinder frame) to the solid cylinder, and the cylinder's closest point."""
    rho = math.hypot(float(x[0]), float(x[1]))
    z = _clamp_to(float(x[2]), -half_length, half_length)
    if rho > radius:
        scale = radius / rho
        q = np.array([x[0] * scale, x[1] * scale, z])
    else:
        q = np.array([x[0], x[1], z])
    return float(np.linalg.norm(x - q)), q


def segment_cylinder(p0: ArrayLike, p1: ArrayLike, centre: ArrayLike, R: ArrayLike, radius: float,
                     half_length: float) -> Closest:
    """Segment p0p1 to the solid cylinder (centre, rotation R whose z column is the axis, radius, half length)."""
    a, d, c, Rm = _frame(p0, p1, centre, R)
    cuts = {0.0, 1.0}
    if d[2] != 0.0:
        for bound in (-half_length, half_length):
            t = (bound - a[2]) / d[2]
            if 0.0 < t < 1.0:
                cuts.add(float(t))
    A, B, C = d[0] ** 2 + d[1] ** 2, 2.0 * (a[0] * d[0] + a[1] * d[1]), a[0] ** 2 + a[1] ** 2 - radius ** 2
    if A > 0.0:  # where the segment crosses the radius: ρ(t)² = r²
        disc = B * B - 4.0 * A * C
        if disc > 0.0:
            root = math.sqrt(disc)
            for t in ((-B - root) / (2.0 * A), (-B + root) / (2.0 * A)):
                if 0.0 < t < 1.0:
                    cuts.add(float(t))
    knots = sorted(cuts)
    best_t, best = 0.0, math.inf
    for lo, hi in itertools.pairwise(knots):
        tm = 0.5 * (lo + hi)
        mid = a + tm * d
        radial = math.hypot(float(mid[0]), float(mid[1])) > radius
        above = mid[2] > half_length
        axial = above or mid[2] < -half_length
        bound = half_length if above else -half_length
        if not radial and not axial:
            t, value = tm, 0.0
        elif not radial:  # the axial excess alone: a quadratic
            off = a[2] - bound
            t, value = _quadratic_min(d[2] * d[2], 2.0 * d[2] * off, off * off, lo, hi)
            value = math.sqrt(value)
        elif not axial:  # the radial excess alone: ρ(t) − r, least where ρ² is
            t, rho2 = _quadratic_min(A, B, a[0] ** 2 + a[1] ** 2, lo, hi)
            value = math.sqrt(rho2) - radius
        else:
            t, value = _convex_min(a, d, radius, bound, lo, hi)
        value = max(0.0, value)
        if value < best:
            best_t, best = t, value
    point = a + best_t * d
    dist, q = _cylinder_excess(point, radius, half_length)
    return Closest(dist, c + Rm @ point, c + Rm @ q, best_t)


def _convex_min(a: Array, d: Array, radius: float, bound: float, lo: float, hi: float) -> tuple[float, float]:
    """Minimise √((ρ(t) − r)² + (z(t) − bound)²) on [lo, hi], where ρ > r and z beyond ``bound`` throughout (a
    convex function there): Newton on its square's derivative, kept within a shrinking bracket."""

    def f(t: float) -> tuple[float, float, float]:
        x, y, z = a + t * d
        rho = math.hypot(x, y)
        er, ez = rho - radius, z - bound
        drho = (x * d[0] + y * d[1]) / rho
        d2rho = (d[0] ** 2 + d[1] ** 2 - drho * drho) / rho
        g = 2.0 * (er * drho + ez * d[2])
        H = 2.0 * (drho * drho + er * d2rho + d[2] * d[2])
        return er * er + ez * ez, g, H

    left, right = lo, hi
    if f(lo)[1] >= 0.0:
        t = lo
    elif f(hi)[1] <= 0.0:
        t = hi
    else:
        t = 0.5 * (lo + hi)
        for _ in range(100):
            _, g, H = f(t)
            if g > 0.0:
                right = t
            else:
                left = t
            step = t - g / H if H > 0.0 else 0.5 * (left + right)
            nxt = step if left < step < right else 0.5 * (left + right)
            if abs(nxt - t) <= 1e-15 * max(1.0, abs(t)) or right - left <= 1e-16:
                t = nxt
                break
            t = nxt
    return t, math.sqrt(f(t)[0])


def _point_triangle(x: Array, A: Array, B: Array, C: Array) -> Array:
    """The triangle's closest point to x (Ericson 5.1.5)."""
    ab, ac, ax = B - A, C - A, x - A
    d1, d2 = ab @ ax, ac @ ax
    if d1 <= 0.0 and d2 <= 0.0:
        return A
    bx = x - B
    d3, d4 = ab @ bx, ac @ bx
    if d3 >= 0.0 and d4 <= d3:
        return B
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        return A + d1 / (d1 - d3) * ab
    cx = x - C
    d5, d6 = ab @ cx, ac @ cx
    if d6 >= 0.0 and d5 <= d6:
        return C
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        return A + d2 / (d2 - d6) * ac
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        return B + (d4 - d3) / ((d4 - d3) + (d5 - d6)) * (C - B)
    denom = 1.0 / (va + vb + vc)
    return A + ab * (vb * denom) + ac * (vc * denom)


def segment_triangle(p0: ArrayLike, p1: ArrayLike, triangle: ArrayLike) -> Closest:
    """Segment p0p1 to the triangle (3 × 3, its corners' rows): 0 where the segment crosses it; otherwise the
    least of the segment's ends to the triangle and the segment to its three edges."""
    P0, P1 = np.asarray(p0, dtype=float), np.asarray(p1, dtype=float)
    T = np.asarray(triangle, dtype=float)
    A, B, C = T
    d = P1 - P0
    n = np.cross(B - A, C - A)
    dn = float(d @ n)
    if dn != 0.0:  # the segment's crossing of the triangle's plane, if it is within both
        t = float((A - P0) @ n) / dn
        if 0.0 <= t <= 1.0:
            x = P0 + t * d
            u = float(np.cross(B - A, x - A) @ n)
            v = float(np.cross(C - B, x - B) @ n)
            w = float(np.cross(A - C, x - C) @ n)
            if (u >= 0.0 and v >= 0.0 and w >= 0.0) or (u <= 0.0 and v <= 0.0 and w <= 0.0):
                return Closest(0.0, x, x.copy(), t)
    best: Closest | None = None
    for s, x in ((0.0, P0), (1.0, P1)):
        q = _point_triangle(x, A, B, C)
        cand = Closest(float(np.linalg.norm(x - q)), x.copy(), q, s)
        if best is None or cand.distance < best.distance:
            best = cand
    for e0, e1 in ((A, B), (B, C), (C, A)):
        cand = segments(P0, P1, e0, e1)
        if cand.distance < best.distance:  # type: ignore[union-attr]
            best = cand
    assert best is not None
    return best


def segment_mesh(p0: ArrayLike, p1: ArrayLike, triangles: ArrayLike) -> Closest:
    """Segment p0p1 to a triangle mesh's surface ((n, 3, 3) corners): the least over its triangles."""
    T = np.asarray(triangles, dtype=float)
    if T.ndim != 3 or T.shape[1:] != (3, 3) or len(T) == 0:
        raise ValueError(f"triangles: expected (n, 3, 3) corners, got shape {T.shape}")
    P0, P1 = np.asarray(p0, dtype=float), np.asarray(p1, dtype=float)
    # a bound prunes most triangles: the distance to a triangle is at least the distance to its bounding sphere
    centres = T.mean(axis=1)
    radii = np.linalg.norm(T - centres[:, None, :], axis=2).max(axis=1)
    d = P1 - P0
    dd = float(d @ d)
    s = np.clip(((centres - P0) @ d) / dd, 0.0, 1.0) if dd > 0.0 else np.zeros(len(T))
    lower = np.linalg.norm(P0 + s[:, None] * d - centres, axis=1) - radii
    best: Closest | None = None
    for k in np.argsort(lower):
        if best is not None and lower[k] > best.distance:
            break
        cand = segment_triangle(P0, P1, T[k])
        if best is None or cand.distance < best.distance:
            best = cand
            if best.distance == 0.0:
                break
    assert best is not None
    return best
