"""Irvine's elastic catenary: a heavy, elastic cable between a frame point and a platform point. No I/O.

Model (H. M. Irvine, *Cable Structures*, 1981, §2.2)
-----------------------------------------------------
A cable of unstretched length ``L0`` (m), weight per unstretched length ``w`` (N/m) and axial stiffness
``EA`` (N) hangs in the vertical plane through its two ends. Put the **platform end** at the origin of
that plane and the **frame end** at ``(span, rise)``: ``span ≥ 0`` is the horizontal distance, ``rise`` the
height of the frame end above the platform end (negative when the frame end is lower). With ``s`` the
unstretched arc length from the platform end, the tension is ``T(s) = (H, V(s))``, pointing along the
cable towards the frame end:

* ``H`` (N, ≥ 0), the horizontal component, is the same everywhere (no horizontal load);
* ``V(s) = V0 + w s``: each element carries the weight of the cable below it. ``V0`` is the vertical
  component at the platform end, ``V1 = V0 + w L0`` at the frame end.

The cable pulls the platform with the force ``H ê_h + V0 ẑ`` (``ê_h`` the horizontal unit vector towards
the frame end) and the frame with ``−(H ê_h + V1 ẑ)``. Hooke's law ``ds_stretched = (1 + T/EA) ds`` and
equilibrium give the frame end's coordinates in closed form (Irvine's eq. 2.21–2.22):

    span = H L0 / EA + (H / w) [asinh(V1 / H) − asinh(V0 / H)]
    rise = (V0 L0 + w L0² / 2) / EA + (1 / w) [√(H² + V1²) − √(H² + V0²)]

Numerics
--------
Both are evaluated in forms free of cancellation (:func:`_shape`): ``(1/w)[asinh(V1/H) − asinh(V0/H)]``
is ``L0 q asinh(w L0 q)/(w L0 q)`` with ``q = (V0 + V1)/(V1 T0 + V0 T1)`` when V0 and V1 have the same
sign, and ``(T1 − T0)/w = L0 (V0 + V1)/(T0 + T1)``; nothing is divided by w, so a light cable is as
accurate as a heavy one and ``w → 0`` is the straight spring ``T = EA (chord − L0)/L0`` exactly.

The map (H, V0) → (span, rise) is the gradient of the cable's complementary energy
``Φ(H, V0) = ∫₀^L0 (T + T²/(2 EA)) ds``, strictly convex (T = |(H, V0 + w s)| is a norm of an affine
function of (H, V0)). So :func:`solve_catenary` (given the ends and ``L0``: a winch holds the length)
*minimises* ``Φ − H·span − V0·rise``, which has exactly one minimiser for every span ≥ 0, rise, L0 > 0,
w > 0, EA > 0: Newton's method with a backtracking (Armijo) line search on that function is globally
convergent, from any start. It starts from the best (lowest energy) of a warm start, the straight
elastic spring along the chord, the inextensible catenary and the vertical cable's solution with H from
its linearisation; a vertical cable (span = 0) is the hanging elastic rod, in closed form
(:func:`hanging_rod`).

:func:`solve_catenary_tension` (given the ends and the tension magnitude at one end: a tension-controlled
winch) finds the tension's angle and ``L0``. Paying out cable first lowers the end tension (the cable
sags), then raises it again (a deep loop hangs below): the **taut branch**, the shortest cable with that
tension, is the one a winch holding that tension settles on, and the one returned. Newton on Irvine's
two equations finds it from the straight cable (or a warm start); where Newton does not converge, or
converges on the loop branch, a bracketing search on L0 along the taut branch does (its end tension is
decreasing there). Tensions below the least a cable between those ends can have at that end have no
catenary: :class:`CatenaryError` (for instance less than the weight of the cable it must lift).
The frame-end problem is the platform-end problem of the mirrored cable (rise → −rise, V0 → −V1).
Everything is vectorised over cables: arrays of shape ``(n,)``.

The inextensible catenary (EA → ∞) is the textbook ``z = a cosh((x − x0)/a) + c`` with ``a = H/w``;
:func:`inextensible_catenary` solves it in closed form up to one scalar equation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from cdpr.errors import InputError
from cdpr.mechanics.rotation import Array, BoolArray

LENGTH_TOL = 1e-10  # m: iterations stop when the end-point residual is below this and the next correction
#                   negligible, or at the rounding floor of the end-point formulas, ≈ 64 ε (span + |rise|)
MAX_ITER = 100
_EPS = float(np.finfo(float).eps)
STEP_RTOL = 1e-10  # a Newton correction this small (relative) ends the iterations once within the tolerance
_ARMIJO = 1e-4  # sufficient decrease of the energy, as a fraction of the Newton step's predicted one


class CatenaryError(ArithmeticError):
    """No catenary found (the message says for which cables and how far off)."""


@dataclass(frozen=True)
class CatenaryForces:
    """The solved cables. Arrays ``(n,)``; forces in N, lengths in m."""

    horizontal: Array  # H ≥ 0, the horizontal component of the tension (the same all along)
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


def unstretched_lengths(lengths: ArrayLike, tensions: ArrayLike, EA: float) -> Array:
    """The unstretched lengths at which cables of these lengths hold these static tensions: l·EA/(EA + f).

    The inverse of the straight elastic cable's static law ``f = EA (l − l0)/l0``; for f ≥ 0 it is in (0, l].
    """
    return np.asarray(lengths, dtype=float) * EA / (EA + np.asarray(tensions, dtype=float))


def stretched_lengths(unstretched: ArrayLike, tensions: ArrayLike, EA: ArrayLike) -> Array:
    """The geometric lengths of elastic cables of unstretched lengths l0 under static tensions f: ``l0 (1 + f/EA)``
    (the inverse of :func:`unstretched_lengths`; ``EA`` one number or one per cable; forward kinematics from a
    winch's encoders, :mod:`cdpr.mechanics.forward`)."""
    EA = np.asarray(EA, dtype=float)
    if not np.all(EA > 0.0):
        raise InputError("EA: must be > 0")
    return np.asarray(unstretched, dtype=float) * (1.0 + np.asarray(tensions, dtype=float) / EA)


def _arrays(*values: ArrayLike) -> list[Array]:
    arrays = np.broadcast_arrays(*(np.atleast_1d(np.asarray(v, dtype=float)) for v in values))
    return [np.array(a, dtype=float) for a in arrays]


def cable_planes(frame_points: ArrayLike, platform_points: ArrayLike) -> tuple[Array, Array, Array]:
    """Each cable's vertical plane: ``(span (n,), rise (n,), ê_h (n, 3))``, ê_h horizontal, platform → frame.

    When a cable is exactly vertical (span = 0) ê_h is the x axis (its horizontal force is 0 anyway).
    """
    a = np.atleast_2d(np.asarray(frame_points, dtype=float))
    b = np.atleast_2d(np.asarray(platform_points, dtype=float))
    horizontal = a - b
    rise = horizontal[:, 2].copy()
    horizontal[:, 2] = 0.0
    span = np.sqrt(np.einsum("ij,ij->i", horizontal, horizontal))
    e_h = np.zeros_like(horizontal)
    e_h[:, 0] = 1.0
    ok = span > 0.0
    e_h[ok] = horizontal[ok] / span[ok, None]
    return span, rise, e_h


def platform_forces(solution: CatenaryForces, e_h: ArrayLike) -> Array:
    """(n, 3) forces the cables exert on the platform, world frame: H ê_h + V0 ẑ."""
    f = solution.horizontal[:, None] * np.asarray(e_h, dtype=float)
    f[:, 2] += solution.vertical_platform
    return f


class _Shape(NamedTuple):
    """A cable with end forces (H, V0): its frame end, the partials, and its complementary energy."""

    span: Array
    rise: Array
    s_h: Array  # ∂span/∂H
    s_v: Array  # ∂span/∂V0 = ∂rise/∂H (the energy's Hessian is symmetric)
    r_v: Array  # ∂rise/∂V0
    s_l: Array  # ∂span/∂L0
    r_l: Array  # ∂rise/∂L0
    energy: Array  # Φ = ∫ (T + T²/(2 EA)) ds
    T0: Array
    T1: Array


def _shape(H: Array, V0: Array, L0: Array, w: Array, EA: Array) -> _Shape:
    """Irvine's equations, their partials and the energy, without cancellation (module docstring).

    H = 0 is allowed (a vertical cable: span 0, its folded case with an infinite ∂span/∂H).
    """
    V1 = V0 + w * L0
    T0, T1 = np.hypot(H, V0), np.hypot(H, V1)
    Ts, Vs = T0 + T1, V0 + V1
    fold = (V0 < 0.0) & (V1 > 0.0)  # V = 0 somewhere along the cable
    vertical = H <= 0.0
    if not (fold.any() or vertical.any()):  # the common case, without the special ones' guards
        q = Vs / (V1 * T0 + V0 * T1)  # > 0
        x = w * L0 * q
        asinhc = np.divide(np.arcsinh(x), x, out=np.ones_like(x), where=x > 0.0)  # asinh(x)/x, 1 at 0
        ds_T = L0 * q * asinhc  # ∫ ds/T = (asinh(V1/H) − asinh(V0/H))/w
        vt = H * H * L0 * q / (T0 * T1)  # (V1/T1 − V0/T0)/w = ∫ H²/T³ ds
        ht = -H * L0 * Vs / (Ts * T0 * T1)  # (H/T1 − H/T0)/w
        span = H * (L0 / EA + ds_T)
        s_l = H / EA + H / T1
        r_l = V1 / EA + V1 / T1
        int_T = 0.25 * L0 * (Ts + Vs * Vs / Ts) + 0.5 * H * H * ds_T
    else:
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            q = Vs / (V1 * T0 + V0 * T1)
            x = w * L0 * q
            asinhc = np.divide(np.arcsinh(x), x, out=np.ones_like(x), where=x > 0.0)
            ds_T = np.where(fold, (np.arcsinh(V1 / H) + np.arcsinh(-V0 / H)) / w, L0 * q * asinhc)
            ds_T = np.where(vertical & fold, np.inf, ds_T)
            vt = np.where(fold, (V1 / T1 - V0 / T0) / w, H * H * L0 * q / (T0 * T1))
            vt = np.where(vertical, 0.0, vt)
            ht = np.where(vertical, 0.0, -H * L0 * Vs / (Ts * T0 * T1))
            span = np.where(vertical, 0.0, H * (L0 / EA + ds_T))
            s_l = H / EA + np.where(vertical, 0.0, H / T1)
            r_l = V1 / EA + np.where(T1 > 0.0, V1 / T1, 0.0)
            int_T = 0.25 * L0 * (Ts + Vs * Vs / Ts) + np.where(vertical, 0.0, 0.5 * H * H * ds_T)
    rise = L0 * Vs * (0.5 / EA + 1.0 / Ts)
    s_h = L0 / EA + ds_T - vt
    r_v = L0 / EA + vt
    int_T2 = L0 * (H * H + (V0 * V0 + V0 * V1 + V1 * V1) / 3.0)
    return _Shape(span, rise, s_h, ht, r_v, s_l, r_l, int_T + int_T2 / (2.0 * EA), T0, T1)


def end_point(H: ArrayLike, V0: ArrayLike, L0: ArrayLike, w: ArrayLike, EA: ArrayLike) -> tuple[Array, Array]:
    """Irvine's explicit equations: the frame end ``(span, rise)`` of cables with these end forces."""
    H, V0, L0, w, EA = _arrays(H, V0, L0, w, EA)
    shape = _shape(H, V0, L0, w, EA)
    return shape.span, shape.rise


def complementary_energy(H: ArrayLike, V0: ArrayLike, L0: ArrayLike, w: ArrayLike, EA: ArrayLike) -> Array:
    """Φ(H, V0) = ∫₀^L0 (T + T²/(2 EA)) ds, whose gradient is :func:`end_point` (J; N·m)."""
    H, V0, L0, w, EA = _arrays(H, V0, L0, w, EA)
    return _shape(H, V0, L0, w, EA).energy


def _floor(span: Array, rise: Array) -> Array:
    """Per-cable rounding floor of the end-point residual (m): the formulas' own rounding error."""
    return 64.0 * _EPS * (span + np.abs(rise))


def hanging_rod(rise: ArrayLike, L0: ArrayLike, w: ArrayLike, EA: ArrayLike) -> Array:
    """V0 of vertical cables (span = 0, H = 0) of unstretched length L0 whose top is ``rise`` above the bottom.

    The hanging elastic rod, in closed form: stretched upwards (V ≥ 0 all along: ``rise = L0 (1 + (V0 +
    w L0/2)/EA)``), downwards (V ≤ 0 all along: ``rise = L0 ((V0 + w L0/2)/EA − 1)``), or folded (V0 < 0 < V1,
    a U of zero width: ``rise = (V0 + w L0/2)(L0/EA + 2/w)``). ``rise`` is increasing in V0: one answer.
    """
    rise, L0, w, EA = _arrays(rise, L0, w, EA)
    up = EA * (rise / L0 - 1.0) - 0.5 * w * L0
    down = EA * (rise / L0 + 1.0) - 0.5 * w * L0
    fold = rise / (L0 / EA + 2.0 / w) - 0.5 * w * L0
    return np.where(up >= 0.0, up, np.where(down + w * L0 <= 0.0, down, fold))


def inextensible_catenary(span: ArrayLike, rise: ArrayLike, L0: ArrayLike,
                          w: ArrayLike) -> tuple[Array, Array]:
    """``(H, V0)`` of an inextensible catenary of length L0 (must exceed the chord) through the two ends.

    With λ = span·w/(2H) and μ the midpoint's offset from the lowest point (in units of a = H/w), the
    catenary gives ``√(L0² − rise²) = span·sinh(λ)/λ`` and ``tanh(μ) = rise/L0``; then
    ``V0 = H sinh(μ − λ)``. The first equation is solved for λ by Newton (sinh(λ)/λ is convex, increasing).
    Where L0 does not exceed the chord (a taut cable) λ is taken for a cable longer by 1e-8 of the chord.
    Spans must be > 0.
    """
    span, rise, L0, w = _arrays(span, rise, L0, w)
    chord = np.hypot(span, rise)
    length = np.maximum(L0, chord * (1.0 + 1e-8))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        ratio = np.sqrt(length * length - rise * rise) / span  # sinh(λ)/λ > 1
        lam = np.sqrt(6.0 * (ratio - 1.0))  # from sinh(λ)/λ ≈ 1 + λ²/6, a lower bound on the root
        lam = np.where(ratio > 10.0, np.log(2.0 * ratio * np.log(2.0 * ratio) + 1.0), lam)  # large-sag start
        for _ in range(100):
            g = np.sinh(lam) / lam - ratio
            dg = (lam * np.cosh(lam) - np.sinh(lam)) / (lam * lam)
            step = g / dg
            lam = np.maximum(lam - step, 0.5 * lam)
            if np.all((np.abs(step) <= 1e-13 * lam) | (np.abs(g) <= 8.0 * _EPS * ratio) | ~np.isfinite(lam)):
                break
        H = w * span / (2.0 * lam)
        mu = np.arctanh(rise / length)
        return H, H * np.sinh(mu - lam)


def _guess(span: Array, rise: Array, L0: Array, w: Array, EA: Array) -> tuple[Array, Array]:
    """The lowest-energy start of: the straight elastic spring along the chord (taut cables), the
    inextensible catenary (slack ones) and the vertical cable with H from its linearisation (near-vertical
    ones). Spans must be > 0."""
    chord = np.hypot(span, rise)
    candidates = []
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        T = EA * (chord - L0) / L0
        candidates.append((T * span / chord, T * rise / chord - 0.5 * w * L0))
        candidates.append(inextensible_catenary(span, rise, L0, w))
        V_rod = hanging_rod(rise, L0, w, EA)
        H = span / (L0 / EA + L0 / np.maximum(np.abs(V_rod), 0.5 * w * L0))
        for _ in range(6):  # span = H (L0/EA + ∫ds/T): a fixed point, ∫ds/T depends on H only through a log
            H = H * span / _shape(H, V_rod, L0, w, EA).span
            H = np.where(np.isfinite(H) & (H > 0.0), H, span * w)
        candidates.append((H, V_rod))
        best_H, best_V = np.full_like(span, np.nan), np.full_like(span, np.nan)
        best_F = np.full_like(span, np.inf)
        for H, V in candidates:
            F = _shape(H, V, L0, w, EA).energy - H * span - V * rise
            better = np.isfinite(F) & (H > 0.0) & np.isfinite(V) & (best_F > F)
            best_H, best_V = np.where(better, H, best_H), np.where(better, V, best_V)
            best_F = np.where(better, F, best_F)
    missing = ~np.isfinite(best_F)  # (none of them finite: the vertical cable's V0, a small H)
    return np.where(missing, span * w + 1e-300, best_H), np.where(missing, V_rod, best_V)


def _minimise(span: Array, rise: Array, L0: Array, w: Array, EA: Array, H: Array, V0: Array,
              tol: float) -> tuple[Array, Array, BoolArray, int]:
    """Damped Newton on the energy ``Φ − H span − V0 rise`` (spans > 0): (H, V0, converged, iterations).

    A cable has converged when its end-point residual is at the rounding floor, or below ``tol`` with a
    Newton correction below ``STEP_RTOL`` of its tensions, or below ``tol`` after a full Newton step of
    relative size ≤ 1e-5 (which leaves an error of the order of its square), or below ``tol`` with no
    step improving it any more.
    """
    floor = _floor(span, rise)
    within = np.maximum(tol, floor)
    done = np.zeros(span.shape, dtype=bool)
    sh = _shape(H, V0, L0, w, EA)
    it = 0
    for it in range(MAX_ITER + 1):
        r1, r2 = sh.span - span, sh.rise - rise
        norm = np.hypot(r1, r2)
        det = sh.s_h * sh.r_v - sh.s_v * sh.s_v
        dH = (sh.s_v * r2 - sh.r_v * r1) / det
        dV = (sh.s_v * r1 - sh.s_h * r2) / det
        close = norm <= within
        correction = (np.abs(dH) + np.abs(dV)) / (sh.T0 + sh.T1)
        done |= (norm <= floor) | (close & (correction <= STEP_RTOL))
        if done.all() or it == MAX_ITER:
            break
        slope = r1 * dH + r2 * dV  # the energy's directional derivative, < 0
        F = sh.energy - H * span - V0 * rise
        noise = 64.0 * _EPS * (np.abs(sh.energy) + np.abs(H * span) + np.abs(V0 * rise))
        step = np.ones_like(H)
        accepted = done.copy()
        H_new, V_new, n_new = H, V0, norm
        first = True
        for _ in range(60):
            Ht = np.abs(H + step * dH)
            Ht = np.where(Ht > 0.0, Ht, 1e-8 * H)
            Vt = V0 + step * dV
            st = _shape(Ht, Vt, L0, w, EA)
            with np.errstate(invalid="ignore"):
                Ft = st.energy - Ht * span - Vt * rise
                nt = np.hypot(st.span - span, st.rise - rise)
                ok = (Ft <= F + _ARMIJO * step * slope) | ((Ft <= F + noise) & (nt <= np.maximum(norm, floor)))
            ok &= ~accepted & np.isfinite(Ft) & np.isfinite(nt)
            if first and (ok | done).all():  # the common case: every full step taken
                H_new, V_new, n_new = np.where(done, H, Ht), np.where(done, V0, Vt), nt
                accepted |= ok
                break
            first = False
            H_new, V_new, n_new = np.where(ok, Ht, H_new), np.where(ok, Vt, V_new), np.where(ok, nt, n_new)
            accepted |= ok
            if accepted.all():
                break
            step = np.where(accepted, step, 0.5 * step)
        done |= close & ~accepted  # within tol and nothing improves it: the rounding floor
        done |= accepted & (step == 1.0) & (correction <= 1e-5) & (n_new <= within)
        H, V0 = H_new, V_new
        if (done | ~accepted).all():
            break  # converged, or the others are stuck
        sh = st if first else _shape(H, V0, L0, w, EA)  # (st's done cables are not looked at again)
    return H, V0, done, it


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

    ``guess`` (H, V0) warm-starts Newton (e.g. the previous step's answer); cables it does not bring to
    convergence are started again from :func:`_guess`. Vertical cables (span = 0) are solved in closed
    form. Raises :class:`CatenaryError` if the residual has not fallen below ``tol`` (or the rounding
    floor) in ``MAX_ITER`` iterations, which the module's convexity argument rules out for valid input.
    """
    span, rise, L0, w, EA = _arrays(span, rise, L0, w, EA)
    if not (np.all(L0 > 0.0) and np.all(w > 0.0) and np.all(EA > 0.0)):
        raise ValueError("L0, w and EA must be > 0")
    if not (np.all(span >= 0.0) and np.all(np.isfinite(span)) and np.all(np.isfinite(rise))
            and np.all(np.isfinite(L0)) and np.all(np.isfinite(w)) and np.all(np.isfinite(EA))):
        raise ValueError("span must be >= 0, and every input finite")
    H, V0 = np.zeros_like(span), np.zeros_like(span)
    vertical = span == 0.0
    V0[vertical] = hanging_rod(rise[vertical], L0[vertical], w[vertical], EA[vertical])
    todo = np.flatnonzero(~vertical)
    iterations = 0
    if todo.size:
        s, z, L, ww, ea = span[todo], rise[todo], L0[todo], w[todo], EA[todo]
        ok = np.zeros(todo.size, dtype=bool)
        if guess is not None:
            gH, gV = (np.broadcast_to(np.asarray(g, dtype=float), span.shape)[todo] for g in guess)
            valid = np.isfinite(gH) & np.isfinite(gV) & (gH > 0.0)
            if np.all(valid):
                h, v, ok, iterations = _minimise(s, z, L, ww, ea, gH, gV, tol)
                H[todo], V0[todo] = h, v
            elif np.any(valid):
                cold = _guess(s, z, L, ww, ea)
                h, v, ok, iterations = _minimise(s, z, L, ww, ea, np.where(valid, gH, cold[0]),
                                                 np.where(valid, gV, cold[1]), tol)
                H[todo], V0[todo] = h, v
        if not np.all(ok):
            redo = np.flatnonzero(~ok)
            h0, v0 = _guess(s[redo], z[redo], L[redo], ww[redo], ea[redo])
            h, v, ok_redo, its = _minimise(s[redo], z[redo], L[redo], ww[redo], ea[redo], h0, v0, tol)
            iterations = max(iterations, its)
            H[todo[redo]], V0[todo[redo]] = h, v
            if not np.all(ok_redo):
                bad = todo[redo[~ok_redo]]
                sh = _shape(H[bad], V0[bad], L0[bad], w[bad], EA[bad])
                off = float(np.hypot(sh.span - span[bad], sh.rise - rise[bad]).max())
                raise CatenaryError(f"catenary: Newton did not converge for cable(s) {bad.tolist()} "
                                    f"(end-point residual {off:.3g} m)")
    return CatenaryForces(H, V0, L0, w, iterations)


# -- given the tension at one end --------------------------------------------------------------------


def _rod_for_tension(rise: Array, T: Array, w: Array, EA: Array) -> tuple[Array, Array]:
    """Vertical cables (span = 0) with tension T at the platform end, on the taut branch: (V0, L0).

    rise > 0: straight up, V0 = T, ``(w/(2EA)) L0² + (1 + T/EA) L0 = rise``. rise < 0: straight down,
    V0 = −T, ``(w/(2EA)) L0² − (1 + T/EA) L0 = rise``, which needs V1 = w L0 − T ≤ 0 (the platform holds
    the whole cable): NaN where it does not. rise = 0: NaN (the ends coincide).
    """
    a = w / (2.0 * EA)
    b = 1.0 + T / EA
    with np.errstate(invalid="ignore"):
        u = np.abs(rise)
        up = 2.0 * u / (b + np.sqrt(b * b + 4.0 * a * u))
        down = 2.0 * u / (b + np.sqrt(b * b - 4.0 * a * u))
        down = np.where(w * down <= T * (1.0 + 8.0 * _EPS), down, np.nan)
    L0 = np.where(rise > 0.0, up, np.where(rise < 0.0, down, np.nan))
    return np.where(rise > 0.0, T, -T), L0


def _tension_newton(span: Array, rise: Array, T: Array, w: Array, EA: Array, phi: Array, L0: Array,
                    tol: float, iterations: int) -> tuple[Array, Array, BoolArray, int]:
    """Newton on Irvine's equations in (φ, L0), platform-end tension T: (φ, L0, converged, iterations).

    Converged as in :func:`_minimise`, with the correction measured in radians for φ and, for L0, as the
    relative change of tension it makes by stretching the cable, ``(EA + T)/T · dL0/L0``.
    """
    floor = _floor(span, rise)
    done = np.zeros(span.shape, dtype=bool)
    stuck = np.zeros(span.shape, dtype=bool)  # given up: no step, or no halving of the residual in 3 steps
    history: list[Array] = []
    it = 0
    for it in range(iterations + 1):
        H, V0 = T * np.cos(phi), T * np.sin(phi)
        sh = _shape(H, V0, L0, w, EA)
        r1, r2 = sh.span - span, sh.rise - rise
        norm = np.hypot(r1, r2)
        # Chain rule: ∂H/∂φ = −V0, ∂V0/∂φ = H.
        a = -sh.s_h * V0 + sh.s_v * H
        b = sh.s_l
        c = -sh.s_v * V0 + sh.r_v * H
        d = sh.r_l
        with np.errstate(invalid="ignore", divide="ignore"):
            det = a * d - b * c
            dphi = -(d * r1 - b * r2) / det
            dL = -(-c * r1 + a * r2) / det
            close = norm <= np.maximum(tol, floor)
            # φ's correction in radians, L0's as the tension it makes by stretching the cable (EA dL/L0)
            correction = np.maximum(np.abs(dphi), np.abs(dL) / L0 * (EA + T) / T)
            done |= (norm <= floor) | (close & (correction <= STEP_RTOL))
        history.append(norm)
        if len(history) > 3:
            stuck |= ~done & ~(norm <= 0.5 * history[-4])
        if np.all(done | stuck) or it == iterations:
            break
        step = np.ones_like(phi)
        accepted = done | stuck | ~np.isfinite(dphi) | ~np.isfinite(dL)
        moved = np.zeros(span.shape, dtype=bool)
        p_new, L_new, n_new = phi.copy(), L0.copy(), norm.copy()
        for _ in range(20):  # backtrack: keep |φ| ≤ π/2 and L0 > 0, do not let the residual grow
            pt, Lt = phi + step * dphi, L0 + step * dL
            st = _shape(T * np.cos(pt), T * np.sin(pt), Lt, w, EA)
            with np.errstate(invalid="ignore"):
                nt = np.hypot(st.span - span, st.rise - rise)
                ok = ~accepted & (np.abs(pt) <= 0.5 * np.pi) & (Lt > 0.0) & (nt <= np.maximum(norm, floor))
            p_new, L_new, n_new = np.where(ok, pt, p_new), np.where(ok, Lt, L_new), np.where(ok, nt, n_new)
            accepted |= ok
            moved |= ok
            if np.all(accepted):
                break
            step = np.where(accepted, step, 0.5 * step)
        done |= close & ~moved
        done |= moved & (step == 1.0) & (correction <= 1e-5) & (n_new <= np.maximum(tol, floor))
        stuck |= ~done & ~moved
        phi, L0 = p_new, L_new
        if np.all(done | stuck):
            break
    return phi, L0, done, it


def _tension_slope(sh: _Shape, H: Array, V0: Array) -> Array:
    """d|T0|/dL0 with both ends held (implicit differentiation of Irvine's equations)."""
    det = sh.s_h * sh.r_v - sh.s_v * sh.s_v
    dH = -(sh.r_v * sh.s_l - sh.s_v * sh.r_l) / det
    dV = -(-sh.s_v * sh.s_l + sh.s_h * sh.r_l) / det
    return (H * dH + V0 * dV) / np.hypot(H, V0)


FOLD_RTOL = 1e-8  # a tension this close (relative) to the least one a cable can have is taken as that one


def _bracket(span: float, rise: float, T: float, w: float, EA: float, tol: float) -> tuple[float, ...]:
    """One cable, platform-end tension T, by bracketing L0 on the taut branch, where the platform-end
    tension T0(L0) falls from ∞ (L0 → 0) to its least value: ``(φ, L0)`` of the cable found (polished by
    Newton); ``(H, V0, L0)`` where Newton does not polish it (at the least tension, within ``FOLD_RTOL``);
    or ``(least,)`` when no catenary between these ends has tension T at the platform end, ``least`` the
    least tension found. That is decided when T lies below the tangents of T0 at both ends of a bracket
    around its minimum (T0 is convex there), or below the least tension found once the bracket is closed.
    """
    args = (np.array([span]), np.array([rise]))
    mats = (np.array([w]), np.array([EA]))
    warm: list[tuple[Array, Array] | None] = [None]

    def at(L: float) -> tuple[float, float, float, float]:
        sol = solve_catenary(*args, np.array([L]), *mats, guess=warm[0], tol=tol)
        warm[0] = (sol.horizontal, sol.vertical_platform)
        H, V0 = sol.horizontal, sol.vertical_platform
        sh = _shape(H, V0, np.array([L]), *mats)
        return float(sol.tension_platform[0]), float(_tension_slope(sh, H, V0)[0]), float(H[0]), float(V0[0])

    chord = math.hypot(span, rise)
    lo = chord * EA / (EA + T + 2.0 * w * chord)
    for _ in range(200):  # T0 → ∞ as L0 → 0, decreasing: a left end on the taut branch, above T
        t_lo, d_lo, _, _ = at(lo)
        if t_lo > T and d_lo < 0.0:
            break
        lo *= 0.5
    hi = lo
    for _ in range(200):  # walk right until below T, or past the least tension
        hi *= 2.0
        t_hi, d_hi, _, _ = at(hi)
        if t_hi <= T or d_hi >= 0.0:
            break
    least, at_least = (t_lo, lo) if t_lo < t_hi else (t_hi, hi)
    polish = True
    for _ in range(300):  # bisect in log L0: left of the root (or of the least tension) → lo
        if t_hi <= T and polish and hi - lo <= 1e-6 * hi:  # a root bracketed: Newton from its right end
            polish = False
            _, _, H, V0 = at(hi)
            one = (np.array([span]), np.array([rise]), np.array([T]), *mats)
            phi, L, ok, _ = _tension_newton(*one, np.array([math.atan2(V0, H)]), np.array([hi]), tol, 20)
            if ok[0]:
                return float(phi[0]), float(L[0])
        if t_hi > T and d_hi > 0.0 > d_lo:  # the minimum bracketed: T below both tangents has no root
            cross = (t_hi - t_lo + d_lo * lo - d_hi * hi) / (d_lo - d_hi)
            bound = t_lo + d_lo * (cross - lo)  # where the tangents meet: below the least tension
            if lo < cross < hi and bound > T:
                return (least,)
        mid = math.sqrt(lo * hi)
        if not lo < mid < hi:
            break
        t_mid, d_mid, _, _ = at(mid)
        if t_mid < least:
            least, at_least = t_mid, mid
        if t_mid > T and d_mid < 0.0:
            lo, t_lo, d_lo = mid, t_mid, d_mid
        else:
            hi, t_hi, d_hi = mid, t_mid, d_mid
    if t_hi <= T:
        _, _, H, V0 = at(hi)
        return H, V0, hi
    if least <= T * (1.0 + FOLD_RTOL):
        _, _, H, V0 = at(at_least)
        return H, V0, at_least
    return (least,)


def solve_catenary_tension(
    span: ArrayLike,
    rise: ArrayLike,
    tension: ArrayLike,
    w: ArrayLike,
    EA: ArrayLike,
    end: str = "platform",
    guess: tuple[ArrayLike, ArrayLike] | None = None,
    tol: float = LENGTH_TOL,
    on_failure: str = "raise",
) -> CatenaryForces:
    """Cables between the given ends whose tension magnitude at ``end`` (platform | frame) is ``tension``.

    Unknowns: the tension's angle φ above the horizontal at that end and the unstretched length L0
    (``H = T cos φ``; ``V0 = T sin φ`` at the platform end, ``V0 = T sin φ − w L0`` at the frame end).
    Newton on Irvine's two equations, started from ``guess`` = (φ, L0) or the straight elastic cable along
    the chord, then a bracketing search for the cables it leaves (module docstring). The taut branch is
    found; where no catenary has that tension at that end, raises :class:`CatenaryError`, or with
    ``on_failure="nan"`` returns NaN for those cables (H, V0 and L0).
    """
    if end not in ("platform", "frame"):
        raise ValueError(f"end must be 'platform' or 'frame' (got {end!r})")
    if on_failure not in ("raise", "nan"):
        raise ValueError(f"on_failure must be 'raise' or 'nan' (got {on_failure!r})")
    span, rise, T, w, EA = _arrays(span, rise, tension, w, EA)
    if not (np.all(T > 0.0) and np.all(w > 0.0) and np.all(EA > 0.0)):
        raise ValueError("tension, w and EA must be > 0")
    if not (np.all(span >= 0.0) and np.all(np.isfinite(span)) and np.all(np.isfinite(rise))
            and np.all(np.isfinite(T)) and np.all(np.isfinite(w)) and np.all(np.isfinite(EA))):
        raise ValueError("span must be >= 0, and every input finite")
    if np.any((span == 0.0) & (rise == 0.0)):
        raise ValueError("a cable's two ends coincide")
    frame_end = end == "frame"
    z = -rise if frame_end else rise  # the frame-end problem is the mirrored cable's platform-end one
    phi, L0 = np.zeros_like(span), np.zeros_like(span)
    ok = np.zeros(span.shape, dtype=bool)
    fold: dict[int, tuple[float, ...]] = {}  # (H, V0, L0) of cables found by bracketing, as they are
    least: dict[int, float] = {}  # the least tension found, where T is below it
    vertical = span == 0.0
    if np.any(vertical):
        V, L = _rod_for_tension(z[vertical], T[vertical], w[vertical], EA[vertical])
        phi[vertical], L0[vertical] = np.where(V > 0.0, 0.5 * np.pi, -0.5 * np.pi), L
        ok[vertical] = np.isfinite(L)
        for i in np.flatnonzero(vertical & ~ok).tolist():  # hanging below the platform: it must hold the whole cable
            u = -float(z[i])
            least[i] = float(EA[i]) * (math.sqrt(1.0 + 2.0 * float(w[i]) * u / float(EA[i])) - 1.0)
    iterations = 0
    todo = np.flatnonzero(~vertical)
    if todo.size:
        s, zz, t, ww, ea = span[todo], z[todo], T[todo], w[todo], EA[todo]
        chord = np.hypot(s, zz)
        p0, l0 = np.arctan2(zz, s), chord * ea / (ea + t)
        if guess is not None:
            gp, gl = (np.broadcast_to(np.asarray(g, dtype=float), span.shape)[todo] for g in guess)
            valid = np.isfinite(gp) & np.isfinite(gl) & (gl > 0.0) & (np.abs(gp) <= 0.5 * np.pi)
            p0, l0 = np.where(valid, -gp if frame_end else gp, p0), np.where(valid, gl, l0)
        p, L, conv, iterations = _tension_newton(s, zz, t, ww, ea, p0, l0, tol, 20)
        # Keep only answers on the taut branch (the end tension falls as cable is paid out).
        sh = _shape(t * np.cos(p), t * np.sin(p), L, ww, ea)
        with np.errstate(invalid="ignore", divide="ignore"):
            conv &= ~(_tension_slope(sh, t * np.cos(p), t * np.sin(p)) > 0.0)
        phi[todo], L0[todo], ok[todo] = p, L, conv
        for j in np.flatnonzero(~conv):
            i = int(todo[j])
            found = _bracket(float(span[i]), float(z[i]), float(T[i]), float(w[i]), float(EA[i]), tol)
            if len(found) == 1:
                least[i] = found[0]
                continue
            ok[i] = True
            if len(found) == 2:
                phi[i], L0[i] = found
            else:
                fold[i] = found
    if not np.all(ok) and on_failure == "raise":
        bad = np.flatnonzero(~ok)
        where = "frame" if frame_end else "platform"
        detail = "; ".join(f"{i}: {T[i]:.6g} N, the least is {least[i]:.6g} N" for i in sorted(least))
        raise CatenaryError(f"catenary: did not converge for cable(s) {bad.tolist()}: no catenary between "
                            f"these ends has that tension at its {where} end" + (f" ({detail})" if detail else ""))
    H = np.where(vertical, 0.0, T * np.cos(phi))
    V = T * np.sin(phi)
    for i, (h, v, length) in fold.items():
        H[i], V[i], L0[i] = h, v, length
    V0 = -V - w * L0 if frame_end else V  # mirrored back: the mirrored cable's V0 is −V1
    H, V0, L0 = (np.where(ok, x, np.nan) for x in (H, V0, L0))
    return CatenaryForces(H, V0, L0, w, iterations)
