"""Sagging cables: heavy, elastic cables hanging as Irvine's elastic catenary, wound on winches. No I/O.

Force law (cable i between its frame point a_i and its platform point t + R b_i)
--------------------------------------------------------------------------------
Over an exit pulley the catenary hangs from the pulley's tangent point T_i (for the straight cable's
geometry, :mod:`cdpr.mechanics.pulley`) and the cable on the wheel, r β, lies on it: l0 less that length
hangs.

The cable hangs in the vertical plane through its ends as an elastic catenary (:mod:`cdpr.mechanics.catenary`)
of weight per length ``w = mass_per_length·g`` and axial stiffness ``EA``, quasi-statically: the cable's
own inertia is neglected (its mass is a few percent of the platform's), its shape is solved afresh at
every (sub-)step, warm-started from the previous one. It pulls the platform with ``H ê_h + V0 ẑ`` —
along the catenary's tangent at the platform end, which points below the chord — and the winch with
the frame-end tension ``√(H² + V1²)``, larger by about the cable's weight. A damping force
``c (l̇ − l̇0)`` along the chord (the stretch rate's, as in the elastic model) is added, limited so that
the cable never pushes.

* ``lengths`` mode: the winch's drum sets the unstretched length l0; :func:`cdpr.mechanics.catenary.solve_catenary`
  gives (H, V0).
* ``tensions`` mode: the ideal tension-controlled winch holds the commanded tension at the end named by
  ``tension_at`` (``platform``, the default: the platform-end tension is the command; ``frame``: the
  tension where the cable leaves the winch is); :func:`cdpr.mechanics.catenary.solve_catenary_tension` gives the
  angle and l0. A commanded tension of 0 leaves the cable hanging from the frame: no force.

The solvers are warm-started from the previous solution (they start again from a cold start where
that does not converge). Their domain (docs/cable-models.md): in ``lengths`` mode every geometry — the
catenary given L0 always has exactly one solution, vertical and near-vertical cables included; in
``tensions`` mode every tension at least the least one a cable between those ends can have at that end
(at the frame end, about the weight of the cable it lifts). Outside it (a commanded frame-end tension too
small to lift the cable's own weight has no catenary), *that* cable is taken as the straight elastic
cable with the commanded tension; the step is counted in :attr:`WinchSim.fallbacks` with the solver's
message in ``fallback_reason`` (the sim node counts and logs it). The winches start holding the
platform with at least twice each cable's weight (see ``WinchSim._holding``).
Winch drives, modes, sub-steps: :class:`cdpr_sim.winch.WinchSim`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from cdpr.config.scenario import SagSpec
from cdpr.mechanics.catenary import (
    CatenaryError,
    CatenaryForces,
    cable_planes,
    platform_forces,
    solve_catenary,
    solve_catenary_tension,
    unstretched_lengths,
)
from cdpr.mechanics.rotation import Array
from cdpr_sim.elastic import elastic_tensions
from cdpr_sim.winch import CableForces, Geometry, WinchSim


class SagSim(WinchSim):
    """The platform of ``robot`` on sagging elastic cables (``params``), wound on winches (``winch``).

    ``command``: ``"tensions"`` or ``"lengths"``; see :class:`cdpr_sim.winch.WinchSim` for the rest.
    """

    params_type = SagSpec
    params: SagSpec
    _warm: tuple[Array, Array] | None = None  # (H, V0) of the last lengths-mode solve
    _warm_tension: tuple[Array, Array] | None = None  # (φ, L0) of the last tensions-mode solve

    def reset(self, position: ArrayLike | None = None, rotation: ArrayLike | None = None,
              twist: ArrayLike | None = None) -> None:
        self._warm = self._warm_tension = None
        super().reset(position, rotation, twist)

    def snapshot(self) -> dict[str, Any]:
        """The winch model's, and the catenary solver's warm starts (they decide the last bits of a solve)."""
        warm = [None if w is None else [x.tolist() for x in w] for w in (self._warm, self._warm_tension)]
        return {**super().snapshot(), "warm": warm[0], "warm_tension": warm[1]}

    def restore(self, snapshot: dict[str, Any]) -> None:
        super().restore(snapshot)
        try:
            warm = [None if w is None else (np.array(w[0], dtype=float), np.array(w[1], dtype=float))
                    for w in (snapshot["warm"], snapshot["warm_tension"])]
        except (KeyError, TypeError, IndexError):
            raise ValueError("not a snapshot of the sag model (no warm starts)") from None
        self._warm, self._warm_tension = warm[0], warm[1]

    def _damping_forces(self, g: Geometry, pull: Array, l0_rate: Array) -> Array:
        """c (l̇ − l̇0) along the chord, never more negative than the catenary's pull along it."""
        along = np.einsum("ij,ij->i", pull, g.directions)
        return np.maximum(self.params.damping * (g.rates - l0_rate), -np.maximum(along, 0.0))

    def _straight(self, g: Geometry, l0: Array, l0_rate: Array) -> CableForces:
        f = elastic_tensions(g.lengths, g.rates, l0, l0_rate, self.params.EA, self.params.damping)
        return CableForces(f[:, None] * g.directions, f, f)

    def _law(self, g: Geometry, l0: Array, l0_rate: Array) -> CableForces:
        p = self.params
        span, rise, e_h = cable_planes(g.anchors, g.points)
        l0 = np.asarray(l0, dtype=float) - g.wrapped  # the catenary hangs from the pulley (wrap: straight on it)
        try:
            sol = solve_catenary(span, rise, l0, p.weight_per_length, p.EA, guess=self._warm)
        except CatenaryError as exc:  # not expected in the domain (module docstring): cable by cable
            return self._law_each(g, l0, l0_rate, span, rise, e_h, str(exc))
        self._warm = (sol.horizontal, sol.vertical_platform)
        return self._forces(g, sol, e_h, l0_rate)

    def _law_each(self, g: Geometry, l0: Array, l0_rate: Array, span: Array, rise: Array, e_h: Array,
                  reason: str) -> CableForces:
        """:meth:`_law` one cable at a time: the cables without a catenary are straight elastic ones."""
        p = self.params
        m = self.robot.m
        H, V0 = np.full(m, np.nan), np.full(m, np.nan)
        for i in range(m):
            try:
                one = solve_catenary(span[i], rise[i], l0[i], p.weight_per_length, p.EA)
            except CatenaryError:
                continue
            H[i], V0[i] = one.horizontal[0], one.vertical_platform[0]
        solved = np.isfinite(H)
        self._fallback(reason)
        self._warm = (H, V0)  # (NaN: a cold start for those next time)
        straight = self._straight(g, l0 + g.wrapped, l0_rate)  # (l0 here is the catenary's, off the wheel)
        sol = CatenaryForces(np.where(solved, H, 0.0), np.where(solved, V0, 0.0), np.asarray(l0, dtype=float),
                             np.full(m, p.weight_per_length), 0)
        law = self._forces(g, sol, e_h, l0_rate)
        return CableForces(np.where(solved[:, None], law.forces, straight.forces),
                           np.where(solved, law.platform, straight.platform),
                           np.where(solved, law.frame, straight.frame))

    def _forces(self, g: Geometry, sol: CatenaryForces, e_h: Array, l0_rate: Array) -> CableForces:
        pull = platform_forces(sol, e_h)
        damp = self._damping_forces(g, pull, l0_rate)
        forces = pull + damp[:, None] * g.directions
        return CableForces(forces, np.sqrt(np.einsum("ij,ij->i", forces, forces)), sol.tension_frame + damp)

    def _law_for_tension(self, g: Geometry, tensions: Array) -> tuple[CableForces, Array]:
        p = self.params
        f = np.asarray(tensions, dtype=float)
        m = self.robot.m
        forces, platform, frame = np.zeros((m, 3)), np.zeros(m), np.zeros(m)
        l0 = unstretched_lengths(g.lengths, f, p.EA)  # a slack cable (f = 0) keeps its chord length
        taut = np.flatnonzero(f > 0.0)
        if taut.size == 0:
            return CableForces(forces, platform, frame), l0
        span, rise, e_h = cable_planes(g.anchors[taut], g.points[taut])
        warm = self._warm_tension
        sol = solve_catenary_tension(span, rise, f[taut], p.weight_per_length, p.EA, end=p.tension_at,
                                     guess=None if warm is None else (warm[0][taut], warm[1][taut]),
                                     on_failure="nan")
        at_frame = p.tension_at == "frame"
        # Warm start for the next step: this step's angle and l0 (the chord's for slack cables).
        phi_all = np.arctan2(g.directions[:, 2], np.hypot(g.directions[:, 0], g.directions[:, 1]))
        solved = np.isfinite(sol.horizontal)
        done = taut[solved]
        forces[done] = platform_forces(sol, e_h)[solved]
        platform[done] = sol.tension_platform[solved]
        frame[done] = sol.tension_frame[solved]
        l0[done] = sol.unstretched_length[solved] + g.wrapped[done]  # and the cable on the pulley's wheel
        vertical = sol.vertical_frame if at_frame else sol.vertical_platform
        phi_all[done] = np.arctan2(vertical, sol.horizontal)[solved]
        if not solved.all():  # outside the domain (module docstring): the straight elastic cable, that tension
            out = taut[~solved]
            forces[out] = f[out, None] * g.directions[out]
            platform[out] = frame[out] = f[out]
            self._fallback(f"no catenary has the commanded tension at the {p.tension_at} end of cable(s) "
                           f"{out.tolist()} ({', '.join(f'{x:.4g}' for x in f[out])} N): straight cable(s) used")
        self._warm_tension = (phi_all, l0 - g.wrapped)  # (the solver's, which hangs from the pulley)
        return CableForces(forces, platform, frame), l0

    def _holding_floor(self, g: Geometry) -> Array:
        """At the start each cable holds at least twice its own weight along the chord (sag ≲ 1/16 of it)."""
        return np.maximum(self.robot.tmin, 2.0 * self.params.weight_per_length * g.lengths)

    def _stiffness(self, lengths: Array) -> Array:
        return self.params.EA / np.asarray(lengths, dtype=float)

    def _damping(self) -> float:
        return self.params.damping
