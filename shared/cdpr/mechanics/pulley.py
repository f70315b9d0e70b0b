"""Swivelling exit pulleys (the seed paper's "pulley offset", left out of its model). Pure numpy, no I/O.

A cable leaves the frame over a pulley of radius r that swivels about an axis through the point a (the robot
file's ``frame`` point, where the cable runs into the pulley along that axis) with unit direction u (pointing the
way the cable runs into the pulley, from its winch). The pulley turns about u to face the platform point B, so
its wheel lies in the plane of u and e, the unit vector from the axis towards B; its centre is C = a + r e. The
cable wraps the wheel from a over the arc β to the tangent point T and runs straight from T to B:

    v = B − a,  n = |v − (v·u) u|,  e = (v − (v·u) u) / n
    in the wheel's plane, B − C = (n − r) e + (v·u) u:  d = |B − C|,  ψ = atan2(v·u, n − r)
    φ = ψ + arccos(r / d)            (the angle of T on the wheel, from e towards u)
    β = π − φ                        (the wrapped arc, from a at angle π to T)
    T = C + r (cos φ e + sin φ u),   l = r β + √(d² − r²)

The force on the platform acts along the free span, from B towards T: that unit vector replaces a − B in the
wrench matrix, and l̇ = −(T − B)/|T − B| · Ḃ exactly (the wrap's change and the swivel's cancel), so W = −Jᵀ
holds as for the point model. With r = 0, T = a, β has no length and everything is the point model's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from cdpr.mechanics.rotation import Array


@dataclass(frozen=True)
class Pulleys:
    """The exit pulleys of a robot's cables: ``radius`` (m,) (0: a fixed exit point, no pulley), ``axis`` (m, 3)
    unit swivel axes (along the cable into the pulley; unused where the radius is 0). Read-only arrays."""

    radius: Array
    axis: Array

    def perpendicular(self) -> Array:
        """For each axis, a unit vector normal to it: the wheel's direction when B lies on the swivel axis."""
        u = self.axis
        helper = np.where(np.abs(u[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
        p = helper - np.einsum("ij,ij->i", helper, u)[:, None] * u
        return p / np.linalg.norm(p, axis=1, keepdims=True)


@dataclass(frozen=True)
class PulleyGeometry:
    """Cables over pulleys at one pose, row i for cable i (a cable without a pulley: T = a, wrap 0)."""

    lengths: Array  # (m,) r β + |T − B|
    tangent_points: Array  # (m, 3) T, where the free span leaves the wheel (a without a pulley)
    free_spans: Array  # (m, 3) T − B, platform → frame
    free_lengths: Array  # (m,) |T − B|
    wrap: Array  # (m,) β, rad
    swivel: Array  # (m, 3) e, the wheel's direction from the axis


def pulley_geometry(frame_points: ArrayLike, pulleys: Pulleys, platform_world: ArrayLike) -> PulleyGeometry:
    """Where each cable leaves its pulley for platform points ``platform_world`` (m, 3), world frame, or for
    several poses at once (…, m, 3)."""
    a = np.asarray(frame_points, dtype=float)
    B = np.asarray(platform_world, dtype=float)
    u, r = pulleys.axis, pulleys.radius
    v = B - a
    along = np.einsum("...j,...j->...", v, u)
    across = v - along[..., None] * u
    n = np.sqrt(np.einsum("...j,...j->...", across, across))
    on_axis = n < 1e-12
    e = np.where(on_axis[..., None], pulleys.perpendicular(), across / np.where(on_axis, 1.0, n)[..., None])
    bx = n - r
    with np.errstate(invalid="ignore", divide="ignore"):  # a platform point on or in the wheel (d ≤ r): NaN
        d = np.hypot(bx, along)
        phi = np.arctan2(along, bx) + np.arccos(r / d)
    has = r > 0.0
    beta = np.where(has, np.pi - phi, 0.0)
    wheel = a + r[:, None] * ((1.0 + np.cos(phi))[..., None] * e + np.sin(phi)[..., None] * u)
    T = np.where(has[:, None], wheel, a)
    spans = T - B
    free = np.sqrt(np.einsum("...j,...j->...", spans, spans))
    return PulleyGeometry(r * beta + free, T, spans, free, beta, e)
