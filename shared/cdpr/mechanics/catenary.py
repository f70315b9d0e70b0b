"""Irvine's elastic catenary: a heavy, elastic cable between a frame point and a platform point. No I/O.

Model (H. M. Irvine, *Cable Structures*, 1981, §2.2)
-----------------------------------------------------
A cable of unstretched length ``L0`` (m), weight per unstretched length ``w`` (N/m) and axial stiffness
``EA`` (N) hangs in the vertical plane through its two ends. Put the **platform end** at the origin of
that plane and the **frame end** at ``(span, rise)``: ``span ≥ 0`` is the horizontal distance, ``rise`` the
height of the frame end above the platform end (negative when the frame end is lower). With ``s`` the
unstretched arc length from the platform end, the tension is ``T(s) = (H, V(s))``, pointing along the
cable towards the frame end:

* ``H`` (N, > 0), the horizontal component, is the same everywhere (no horizontal load);
* ``V(s) = V0 + w s``: each element carries the weight of the cable below it. ``V0`` is the vertical
  component at the platform end, ``V1 = V0 + w L0`` at the frame end.

The cable pulls the platform with the force ``H ê_h + V0 ẑ`` (``ê_h`` the horizontal unit vector towards
the frame end) and the frame with ``−(H ê_h + V1 ẑ)``. Hooke's law ``ds_stretched = (1 + T/EA) ds`` and
equilibrium give the frame end's coordinates in closed form (Irvine's eq. 2.21–2.22):

    span = H L0 / EA + (H / w) [asinh(V1 / H) − asinh(V0 / H)]
    rise = (V0 L0 + w L0² / 2) / EA + (1 / w) [√(H² + V1²) − √(H² + V0²)]

Given the ends and ``L0`` (a winch holds the length), :func:`solve_catenary` finds ``(H, V0)`` with
Newton's method on these two equations (analytic Jacobian, backtracking on the residual, started from
the inextensible catenary's exact solution or a warm start). Given the ends and the tension magnitude
at one end (a tension-controlled winch), :func:`solve_catenary_tension` finds the tension's angle and
``L0`` instead. Everything is vectorised over cables: arrays of shape ``(n,)``.

The inextensible catenary (EA → ∞) is the textbook ``z = a cosh((x − x0)/a) + c`` with ``a = H/w``;
:func:`inextensible_catenary` solves it in closed form up to one scalar equation, and serves as the
initial guess. A vertical cable (span → 0) is the limit H → 0; spans below ``MIN_SPAN`` are treated as
``MIN_SPAN`` (the horizontal force is then negligible, the vertical one exact to O(MIN_SPAN)).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from cdpr.mechanics.rotation import Array

MIN_SPAN = 1e-6  # m: shorter horizontal spans are treated as this one (a vertical cable's limit)
LENGTH_TOL = 1e-10  # m: Newton stops when the end-point residual is below this (or
#                   below the rounding floor of Irvine's terms, ≈ 32 ε (T0 + T1)/w, when that is larger)
MAX_ITER = 60
_EPS = float(np.finfo(float).eps)


class CatenaryError(ArithmeticError):
    """Newton's method did not converge (the message says for which cables and how far off)."""


@dataclass(frozen=True)
class CatenaryForces:
    """The solved cables. Arrays ``(n,)``; forces in N, lengths in m."""

    horizontal: Array  # H > 0, the horizontal component of the tension (the same all along)
    vertical_platform: Array  # V0: vertical component at the platform end (> 0: pulls the platform up)
    unstretched_length: Array  # L0
    weight_per_length: Array  # w, N/m
    iterations: int  # Newton iterations taken (the largest over the cables)

    @property
    def vertical_frame(self) -> Array:
        """V1 = V0 + w L0, the vertical component at the frame end."""
        return self.vertical_platform + self.weight_per_length * self.unstretched_length

    @property
    def tension_platform(self) -> Array:
        """|T| at the platform end."""
        return np.hypot(self.horizontal, self.vertical_platform)

    @property
    def tension_frame(self) -> Array:
        """|T| at the frame end (what a load cell at the winch reads)."""
        return np.hypot(self.horizontal, self.vertical_frame)


def _arrays(*values: ArrayLike) -> list[Array]:
    arrays = np.broadcast_arrays(*(np.atleast_1d(np.asarray(v, dtype=float)) for v in values))
    return [np.array(a, dtype=float) for a in arrays]


def cable_planes(frame_points: ArrayLike, platform_points: ArrayLike) -> tuple[Array, Array, Array]:
    """Each cable's vertical plane: ``(span (n,), rise (n,), ê_h (n, 3))``, ê_h horizontal, platform → frame.

    When a cable is vertical (span < MIN_SPAN) ê_h is the x axis (its horizontal force is ~0 anyway).
    """
    a = np.atleast_2d(np.asarray(frame_points, dtype=float))
    b = np.atleast_2d(np.asarray(platform_points, dtype=float))
    horizontal = a - b
    rise = horizontal[:, 2].copy()
    horizontal[:, 2] = 0.0
    span = np.sqrt(np.einsum("ij,ij->i", horizontal, horizontal))
    e_h = np.zeros_like(horizontal)
    e_h[:, 0] = 1.0
    ok = span >= MIN_SPAN
    e_h[ok] = horizontal[ok] / span[ok, None]
    return span, rise, e_h


def platform_forces(solution: CatenaryForces, e_h: ArrayLike) -> Array:
    """(n, 3) forces the cables exert on the platform, world frame: H ê_h + V0 ẑ."""
    f = solution.horizontal[:, None] * np.asarray(e_h, dtype=float)
    f[:, 2] += solution.vertical_platform
    return f


def end_point(H: ArrayLike, V0: ArrayLike, L0: ArrayLike, w: ArrayLike, EA: ArrayLike) -> tuple[Array, Array]:
    """Irvine's explicit equations: the frame end ``(span, rise)`` of cables with these end forces."""
    H, V0, L0, w, EA = _arrays(H, V0, L0, w, EA)
    V1 = V0 + w * L0
    span = H * L0 / EA + (H / w) * (np.arcsinh(V1 / H) - np.arcsinh(V0 / H))
    rise = (V0 * L0 + 0.5 * w * L0 * L0) / EA + (np.hypot(H, V1) - np.hypot(H, V0)) / w
    return span, rise


def _floor(H: Array, V0: Array, L0: Array, w: Array, span: Array, rise: Array, tol: float) -> Array:
    """Per-cable residual tolerance: ``tol``, or the rounding floor of Irvine's terms (≈ ε T/w) if larger."""
    V1 = V0 + w * L0
    return np.maximum(tol, 32.0 * _EPS * ((np.hypot(H, V0) + np.hypot(H, V1)) / w + span + np.abs(rise)))


def _residual_and_partials(
    H: Array, V0: Array, L0: Array, w: Array, EA: Array, span: Array, rise: Array
) -> tuple[Array, Array, Array, Array, Array, Array, Array, Array]:
    """Residuals (r1, r2) = end_point − (span, rise) and their partials by H, V0 and L0."""
    V1 = V0 + w * L0
    T0, T1 = np.hypot(H, V0), np.hypot(H, V1)
    a0, a1 = np.arcsinh(V0 / H), np.arcsinh(V1 / H)
    r1 = H * L0 / EA + (H / w) * (a1 - a0) - span
    r2 = (V0 * L0 + 0.5 * w * L0 * L0) / EA + (T1 - T0) / w - rise
    # d asinh(V/H)/dH = −V/(H T), so d[(H/w)(a1 − a0)]/dH = (a1 − a0)/w − (V1/T1 − V0/T0)/w.
    d1_dH = L0 / EA + (a1 - a0 - V1 / T1 + V0 / T0) / w
    d1_dV = (H / T1 - H / T0) / w
    d2_dH = (H / T1 - H / T0) / w
    d2_dV = L0 / EA + (V1 / T1 - V0 / T0) / w
    d1_dL = H / EA + H / T1
    d2_dL = V1 / EA + V1 / T1
    return r1, r2, d1_dH, d1_dV, d2_dH, d2_dV, d1_dL, d2_dL


def inextensible_catenary(span: ArrayLike, rise: ArrayLike, L0: ArrayLike,
                          w: ArrayLike) -> tuple[Array, Array]:
    """``(H, V0)`` of an inextensible catenary of length L0 (must exceed the chord) through the two ends.

    With λ = span·w/(2H) and μ the midpoint's offset from the lowest point (in units of a = H/w), the
    catenary gives ``√(L0² − rise²) = span·sinh(λ)/λ`` and ``tanh(μ) = rise/L0``; then
    ``V0 = H sinh(μ − λ)``. The first equation is solved for λ by Newton (sinh(λ)/λ is convex, increasing).
    Where L0 does not exceed the chord (a taut cable) λ is taken for a cable longer by 1e-8 of the chord.
    """
    span, rise, L0, w = _arrays(span, rise, L0, w)
    span = np.maximum(span, MIN_SPAN)
    chord = np.hypot(span, rise)
    length = np.maximum(L0, chord * (1.0 + 1e-8))
    ratio = np.sqrt(length * length - rise * rise) / span  # sinh(λ)/λ > 1
    lam = np.sqrt(6.0 * (ratio - 1.0))  # from sinh(λ)/λ ≈ 1 + λ²/6, a lower bound on the root
    lam = np.where(ratio > 10.0, np.log(2.0 * ratio * np.log(2.0 * ratio) + 1.0), lam)  # large-sag start
    for _ in range(100):
        g = np.sinh(lam) / lam - ratio
        dg = (lam * np.cosh(lam) - np.sinh(lam)) / (lam * lam)
        step = g / dg
        lam = np.maximum(lam - step, 0.5 * lam)
        if np.all((np.abs(step) <= 1e-13 * lam) | (np.abs(g) <= 8.0 * _EPS * ratio)):
            break
    H = w * span / (2.0 * lam)
    mu = np.arctanh(rise / length)
    return H, H * np.sinh(mu - lam)


def _guess(span: Array, rise: Array, L0: Array, w: Array, EA: Array) -> tuple[Array, Array]:
    """A starting point: a taut elastic cable's tension along the chord, or the inextensible catenary."""
    chord = np.hypot(span, rise)
    H_cat, V_cat = inextensible_catenary(span, rise, L0, w)
    taut = chord * (1.0 - 1e-4) > L0
    T = np.maximum(EA * (chord - L0) / L0, w * L0)
    H_taut = T * np.maximum(span, MIN_SPAN) / chord
    V_taut = T * rise / chord - 0.5 * w * L0
    return np.where(taut, H_taut, H_cat), np.where(taut, V_taut, V_cat)


def solve_catenary(
    span: ArrayLike,
    rise: ArrayLike,
    L0: ArrayLike,
    w: ArrayLike,
    EA: ArrayLike,
    guess: tuple[ArrayLike, ArrayLike] | None = None,
    tol: float = LENGTH_TOL,
) -> CatenaryForces:
    """End forces ``(H, V0)`` of cables with unstretched length ``L0`` between the given ends.

    ``guess`` (H, V0) warm-starts Newton (e.g. the previous step's answer); without it the start is
    :func:`_guess`. Raises :class:`CatenaryError` if Newton has not converged in ``MAX_ITER`` iterations.
    """
    span, rise, L0, w, EA = _arrays(span, rise, L0, w, EA)
    span = np.maximum(span, MIN_SPAN)
    if np.any(L0 <= 0.0) or np.any(w <= 0.0) or np.any(EA <= 0.0):
        raise ValueError("L0, w and EA must be > 0")
    if guess is None:
        H, V0 = _guess(span, rise, L0, w, EA)
    else:
        H, V0 = (np.array(np.broadcast_to(np.asarray(g, dtype=float), span.shape)) for g in guess)
        if not np.all(H > 0.0):
            H = np.where(H > 0.0, H, _guess(span, rise, L0, w, EA)[0])
    for it in range(MAX_ITER + 1):
        r1, r2, a, b, c, d, _, _ = _residual_and_partials(H, V0, L0, w, EA, span, rise)
        norm = np.hypot(r1, r2)
        limit = _floor(H, V0, L0, w, span, rise, tol)
        if np.all(norm <= limit):
            return CatenaryForces(H, V0, L0, w, it)
        if it == MAX_ITER:
            break
        det = a * d - b * c
        dH = -(d * r1 - b * r2) / det
        dV = -(-c * r1 + a * r2) / det
        step = np.ones_like(H)
        for _ in range(30):  # backtrack: keep H > 0 and do not let the residual grow
            H_new = H + step * dH
            V_new = V0 + step * dV
            ok = H_new > 0.0
            r1n, r2n = end_point(np.where(ok, H_new, H), V_new, L0, w, EA)
            better = ok & (np.hypot(r1n - span, r2n - rise) <= np.maximum(norm, limit))
            if np.all(better | (norm <= limit)):
                break
            step = np.where(better | (norm <= limit), step, 0.5 * step)
        done = norm <= limit
        H = np.where(done, H, np.where(H + step * dH > 0.0, H + step * dH, 0.5 * H))
        V0 = np.where(done, V0, V0 + step * dV)
    bad = np.flatnonzero(norm > limit)
    raise CatenaryError(f"catenary: Newton did not converge for cable(s) {bad.tolist()} "
                        f"(end-point residual {float(norm.max()):.3g} m)")


def solve_catenary_tension(
    span: ArrayLike,
    rise: ArrayLike,
    tension: ArrayLike,
    w: ArrayLike,
    EA: ArrayLike,
    end: str = "platform",
    guess: tuple[ArrayLike, ArrayLike] | None = None,
    tol: float = LENGTH_TOL,
) -> CatenaryForces:
    """Cables between the given ends whose tension magnitude at ``end`` (platform | frame) is ``tension``.

    Unknowns: the tension's angle φ above the horizontal at that end and the unstretched length L0
    (``H = T cos φ``; ``V0 = T sin φ`` at the platform end, ``V0 = T sin φ − w L0`` at the frame end).
    Newton on Irvine's two equations, started from the straight elastic cable along the chord (or from
    ``guess`` = (φ, L0)). The taut branch is found; raises :class:`CatenaryError` if Newton fails.
    """
    if end not in ("platform", "frame"):
        raise ValueError(f"end must be 'platform' or 'frame' (got {end!r})")
    span, rise, T, w, EA = _arrays(span, rise, tension, w, EA)
    span = np.maximum(span, MIN_SPAN)
    if np.any(T <= 0.0) or np.any(w <= 0.0) or np.any(EA <= 0.0):
        raise ValueError("tension, w and EA must be > 0")
    chord = np.hypot(span, rise)
    if guess is None:
        phi = np.arctan2(rise, span)
        L0 = chord * EA / (EA + T)
    else:
        phi, L0 = (np.array(np.broadcast_to(np.asarray(g, dtype=float), span.shape)) for g in guess)
    frame_end = end == "frame"

    def forces(phi: Array, L0: Array) -> tuple[Array, Array]:
        V0 = T * np.sin(phi) - (w * L0 if frame_end else 0.0)
        return T * np.cos(phi), V0

    for it in range(MAX_ITER + 1):
        H, V0 = forces(phi, L0)
        r1, r2, dH1, dV1, dH2, dV2, dL1, dL2 = _residual_and_partials(H, V0, L0, w, EA, span, rise)
        norm = np.hypot(r1, r2)
        limit = _floor(H, V0, L0, w, span, rise, tol)
        if np.all(norm <= limit):
            return CatenaryForces(H, V0, L0, w, it)
        if it == MAX_ITER:
            break
        # Chain rule: ∂H/∂φ = −T sin φ, ∂V0/∂φ = T cos φ, ∂V0/∂L0 = −w at the frame end.
        dHp, dVp = -T * np.sin(phi), T * np.cos(phi)
        dVL = -w if frame_end else np.zeros_like(w)
        a = dH1 * dHp + dV1 * dVp
        b = dL1 + dV1 * dVL
        c = dH2 * dHp + dV2 * dVp
        d = dL2 + dV2 * dVL
        det = a * d - b * c
        dphi = -(d * r1 - b * r2) / det
        dL = -(-c * r1 + a * r2) / det
        step = np.ones_like(phi)
        for _ in range(30):  # backtrack: keep H > 0 (|φ| < π/2) and L0 > 0, do not let the residual grow
            p_new, L_new = phi + step * dphi, L0 + step * dL
            ok = (np.abs(p_new) < 0.5 * np.pi) & (L_new > 0.0)
            H_new, V_new = forces(np.where(ok, p_new, phi), np.where(ok, L_new, L0))
            s_new, z_new = end_point(H_new, V_new, np.where(ok, L_new, L0), w, EA)
            better = ok & (np.hypot(s_new - span, z_new - rise) <= np.maximum(norm, limit))
            if np.all(better | (norm <= limit)):
                break
            step = np.where(better | (norm <= limit), step, 0.5 * step)
        done = norm <= limit
        phi = np.where(done, phi, phi + step * dphi)
        L0 = np.where(done, L0, L0 + step * dL)
    bad = np.flatnonzero(norm > limit)
    raise CatenaryError(f"catenary: Newton did not converge for cable(s) {bad.tolist()} "
                        f"(end-point residual {float(norm.max()):.3g} m)")
