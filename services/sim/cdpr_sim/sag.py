"""Sagging cables: heavy, elastic cables hanging as Irvine's elastic catenary, wound on winches. No I/O.

Force law (cable i between its frame point a_i and its platform point t + R b_i)
--------------------------------------------------------------------------------
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

Newton is warm-started from the previous solution, and retried from a cold start if that fails. Should
it still fail (a tension too small to lift the cable's own weight has no catenary), the step uses the
straight elastic cable's force for every cable and counts it in :attr:`SagSim.fallbacks`. The winches
start holding the platform with at least twice each cable's weight (see ``WinchSim._holding``).
Winch drives, modes, sub-steps: :class:`cdpr_sim.winch.WinchSim`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from cdpr.config.scenario import SimSpec
from cdpr.mechanics.catenary import (
    CatenaryError,
    CatenaryForces,
    cable_planes,
    platform_forces,
    solve_catenary,
    solve_catenary_tension,
)
from cdpr.mechanics.robot import GRAVITY
from cdpr.mechanics.rotation import Array
from cdpr_sim.elastic import elastic_tensions, unstretched_lengths
from cdpr_sim.winch import CableForces, Geometry, WinchSim

G = float(-GRAVITY[2])


@dataclass(frozen=True)
class SagParams:
    """Cable mass per length (kg/m), axial stiffness EA (N), damping (N·s/m), where tension is commanded."""

    mass_per_length: float = 0.1
    EA: float = 1.0e6
    damping: float = 200.0
    tension_at: Literal["platform", "frame"] = "platform"

    def __post_init__(self) -> None:
        if not (math.isfinite(self.mass_per_length) and self.mass_per_length > 0.0):
            raise ValueError(f"mass_per_length must be a positive finite number of kg/m "
                             f"(got {self.mass_per_length})")
        if not (math.isfinite(self.EA) and self.EA > 0.0):
            raise ValueError(f"EA must be a positive finite number of N (got {self.EA})")
        if not (math.isfinite(self.damping) and self.damping >= 0.0):
            raise ValueError(f"damping must be a finite number >= 0 N·s/m (got {self.damping})")
        if self.tension_at not in ("platform", "frame"):
            raise ValueError(f"tension_at must be 'platform' or 'frame' (got {self.tension_at!r})")

    @property
    def weight_per_length(self) -> float:
        """w, N/m."""
        return self.mass_per_length * G


class SagSim(WinchSim):
    """The platform of ``robot`` on sagging elastic cables (``params``), wound on winches (``winch``).

    ``command``: ``"tensions"`` or ``"lengths"``; see :class:`cdpr_sim.winch.WinchSim` for the rest.
    """

    params_type = SagParams
    params: SagParams
    fallbacks = 0  # (sub-)steps where the catenary was not solved and straight cables were used
    _warm: tuple[Array, Array] | None = None  # (H, V0) of the last lengths-mode solve
    _warm_tension: tuple[Array, Array] | None = None  # (φ, L0) of the last tensions-mode solve

    def reset(self, position: ArrayLike | None = None, rotation: ArrayLike | None = None,
              twist: ArrayLike | None = None) -> None:
        self._warm = self._warm_tension = None
        self.fallbacks = 0
        super().reset(position, rotation, twist)

    def _damping_forces(self, g: Geometry, pull: Array, l0_rate: Array) -> Array:
        """c (l̇ − l̇0) along the chord, never more negative than the catenary's pull along it."""
        along = np.einsum("ij,ij->i", pull, g.directions)
        return np.maximum(self.params.damping * (g.rates - l0_rate), -np.maximum(along, 0.0))

    def _straight(self, g: Geometry, l0: Array, l0_rate: Array) -> CableForces:
        f = elastic_tensions(g.lengths, g.rates, l0, l0_rate, self.params.EA, self.params.damping)
        return CableForces(f[:, None] * g.directions, f, f)

    def _law(self, g: Geometry, l0: Array, l0_rate: Array) -> CableForces:
        p = self.params
        span, rise, e_h = cable_planes(self._a, g.points)
        try:
            try:
                sol = solve_catenary(span, rise, l0, p.weight_per_length, p.EA, guess=self._warm)
            except CatenaryError:
                if self._warm is None:
                    raise
                sol = solve_catenary(span, rise, l0, p.weight_per_length, p.EA)  # again, from a cold start
        except CatenaryError:
            self.fallbacks += 1
            self._warm = None
            return self._straight(g, l0, l0_rate)
        self._warm = (sol.horizontal, sol.vertical_platform)
        return self._forces(g, sol, e_h, l0_rate)

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
        span, rise, e_h = cable_planes(self._a[taut], g.points[taut])
        warm = self._warm_tension
        try:
            try:
                sol = solve_catenary_tension(span, rise, f[taut], p.weight_per_length, p.EA, end=p.tension_at,
                                             guess=None if warm is None else (warm[0][taut], warm[1][taut]))
            except CatenaryError:
                if warm is None:
                    raise
                sol = solve_catenary_tension(span, rise, f[taut], p.weight_per_length, p.EA, end=p.tension_at)
        except CatenaryError:
            self.fallbacks += 1
            self._warm_tension = None
            return CableForces(f[:, None] * g.directions, f, f), l0
        forces[taut] = platform_forces(sol, e_h)
        platform[taut] = sol.tension_platform
        frame[taut] = sol.tension_frame
        l0[taut] = sol.unstretched_length
        at_frame = p.tension_at == "frame"
        phi = np.arctan2(sol.vertical_frame if at_frame else sol.vertical_platform, sol.horizontal)
        # Warm start for the next step: this step's angle and l0 (the chord's for slack cables).
        phi_all = np.arctan2(g.directions[:, 2], np.hypot(g.directions[:, 0], g.directions[:, 1]))
        phi_all[taut] = phi
        self._warm_tension = (phi_all, l0.copy())
        return CableForces(forces, platform, frame), l0

    @staticmethod
    def _params(spec: SimSpec) -> SagParams:
        return SagParams(**spec.sag.model_dump())

    def _holding_floor(self, g: Geometry) -> Array:
        """At the start each cable holds at least twice its own weight along the chord (sag ≲ 1/16 of it)."""
        return np.maximum(self.robot.tmin, 2.0 * self.params.weight_per_length * g.lengths)

    def _stiffness(self, lengths: Array) -> Array:
        return self.params.EA / np.asarray(lengths, dtype=float)

    def _damping(self) -> float:
        return self.params.damping
