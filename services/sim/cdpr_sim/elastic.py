"""Elastic cables: straight, massless, axially elastic and damped, wound on winches. No I/O.

Force law (cable i, chord length l, its rate l̇, unstretched length l0 and its rate l̇0 set by the winch)
--------------------------------------------------------------------------------------------------------
    k = EA / l0                                   (N/m: a longer cable is softer)
    f = max(0, k (l − l0) + c (l̇ − l̇0))   while l > l0,      f = 0 while l ≤ l0 (slack)

``EA`` (N) is the axial stiffness (Young's modulus × metallic area), ``c`` (N·s/m) the damping of the
stretch rate (with the winch still, ``c·l̇``). The force ``f d_i`` acts on the platform along the chord,
towards the frame; the winch's drum feels the same f. A cable that would push (f < 0 while taut, when
it shortens fast) pulls nothing. The static stretch of a cable holding f is ``l − l0 = f l0 / EA``.

Domain: every chord length l ≥ 0 and unstretched length l0 > 0 (:func:`elastic_tensions` refuses
l0 ≤ 0). Slack and taut again: the force is 0 exactly while l ≤ l0 and grows continuously from 0 past
it (the damping term only acts while taut, and never pushes). Hooke's law is linear at any strain: no
yield, no rupture (a steel rope yields near 1 % strain, breaks near 2–3 %: keep tensions below
~0.01 EA for the numbers to mean something). As l0 → 0 the stiffness EA/l0 has no bound; in lengths
mode :class:`~cdpr_sim.winch.WinchSim` evaluates the law at no less than its ``min_length`` and counts
the steps where it had to (``fallbacks``).

Winches, the two command modes (tensions: ideal torque-controlled winch, the applied tension is the
command, ``l0 = l·EA/(EA + f)``; lengths: PID-driven drums whose angle sets l0) and the sub-stepped
integration are :class:`cdpr_sim.winch.WinchSim`'s. With the shipped defaults (``EA`` = 1 MN, about a
4 mm steel wire rope, ``c`` = 200 N·s/m, the default :class:`~cdpr.config.scenario.WinchSpec`) and CAROCA at
15 kg, the fastest modes are the drum on its cable (√(k r²/J + kp/J) ≈ 1.0·10³ rad/s) and the platform on
its eight cables (≈ 370 rad/s, the stiffest direction of ``W diag(k) Wᵀ`` through M); their bound
≈ 1.1·10³ rad/s makes :func:`~cdpr_sim.winch.substeps_for` pick 4 sub-steps at dt = 1 ms (h = 0.25 ms,
ω h ≈ 0.27, explicit damping (c r² + kd + b) h / J ≈ 0.38): stable and accurate. A single step of 1 ms
(ω dt ≈ 1.1, damping 1.5) would sit close to the explicit scheme's limits.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from cdpr.config.scenario import ElasticSpec
from cdpr.mechanics.catenary import unstretched_lengths
from cdpr.mechanics.rotation import Array
from cdpr_sim.winch import CableForces, Geometry, WinchSim


def elastic_tensions(lengths: ArrayLike, rates: ArrayLike, l0: ArrayLike, l0_rates: ArrayLike, EA: float,
                     damping: float) -> Array:
    """Tensions (N) of straight elastic cables: ``max(0, EA/l0 (l − l0) + c (l̇ − l̇0))``, 0 when slack.

    Unstretched lengths must be > 0 (a cable of no length has no stiffness to speak of): ValueError.
    """
    l0 = np.asarray(l0, dtype=float)
    if not np.all(l0 > 0.0):
        raise ValueError(f"unstretched lengths must be > 0 (got {l0.min()} m)")
    stretch = np.asarray(lengths, dtype=float) - l0
    f = (EA / l0) * stretch + damping * (np.asarray(rates, dtype=float) - np.asarray(l0_rates, dtype=float))
    return np.where(stretch > 0.0, np.maximum(f, 0.0), 0.0)


class ElasticSim(WinchSim):
    """The platform of ``robot`` on straight elastic cables (``params``), wound on winches (``winch``).

    ``command``: ``"tensions"`` or ``"lengths"``; see :class:`cdpr_sim.winch.WinchSim` for the rest.
    """

    params_type = ElasticSpec
    params: ElasticSpec

    def _law(self, g: Geometry, l0: Array, l0_rate: Array) -> CableForces:
        f = elastic_tensions(g.lengths, g.rates, l0, l0_rate, self.params.EA, self.params.damping)
        return CableForces(f[:, None] * g.directions, f, f)

    def _law_for_tension(self, g: Geometry, tensions: Array) -> tuple[CableForces, Array]:
        f = np.asarray(tensions, dtype=float)
        return CableForces(f[:, None] * g.directions, f, f), unstretched_lengths(g.lengths, f, self.params.EA)

    def _stiffness(self, lengths: Array) -> Array:
        return self.params.EA / np.asarray(lengths, dtype=float)

    def _damping(self) -> float:
        return self.params.damping
