"""The elastic catenary solvers over the whole geometry space, against physics that does not depend on them.

Every generated cable — chords from 1 mm to 1 km, any direction with vertical (span exactly 0) and
near-vertical ones (1e-14 … 0.1 rad off) drawn on purpose, very taut (strain up to 10 %) to very slack
(20 times the chord), light (0.1 g/m) to heavy (100 kg/m) ropes, EA from 100 N to 10 GN — is solved,
and the answer checked against a direct numerical integration of the cable's equilibrium ODE: each
element carries its weight (dT/ds = w ẑ, so the horizontal force is the same at both ends and the
vertical ones differ by the cable's weight: T(s) = (H, V0 + w s)) and stretches by Hooke's law
(d(x, z)/ds = T (1/|T| + 1/EA), integrated by adaptive Gauss–Kronrod quadrature: scipy ``quad``).
The spring limit as the weight goes to zero is checked against ``T = EA (chord − L0)/L0`` along the
chord. The physical domain: the cable's own weight strains it by at most 10 % (EA ≥ 10 w L0).
"""

from __future__ import annotations

import itertools
import math
import warnings
from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.integrate import IntegrationWarning, quad

from cdpr.mechanics.catenary import (
    LENGTH_TOL,
    CatenaryError,
    hanging_rod,
    solve_catenary,
    solve_catenary_tension,
)

EXAMPLES = 2000
PROPERTY = settings(max_examples=EXAMPLES, deadline=None, database=None, derandomize=True,
                    suppress_health_check=list(HealthCheck))
G = 9.81
ROUNDING = 8.0 * float(np.finfo(float).eps)  # of a difference of two numbers of this size


@dataclass(frozen=True)
class Cable:
    span: float
    rise: float
    L0: float
    w: float
    EA: float

    @property
    def chord(self) -> float:
        return math.hypot(self.span, self.rise)


@st.composite
def cables(draw: st.DrawFn, taut: bool | None = None, min_strain: float = 1e-10) -> Cable:
    chord = 10.0 ** draw(st.floats(-3.0, 3.0))
    kind = draw(st.sampled_from(["any", "vertical up", "vertical down", "near-vertical up",
                                 "near-vertical down", "near-horizontal"]))
    off = 10.0 ** draw(st.floats(-14.0, -1.0))  # rad from the vertical
    angle = {"any": draw(st.floats(0.0, math.pi)), "vertical up": 0.0, "vertical down": math.pi,
             "near-vertical up": off, "near-vertical down": math.pi - off,
             "near-horizontal": 0.5 * math.pi + draw(st.floats(-1e-3, 1e-3))}[kind]
    span = 0.0 if kind.startswith("vertical") else chord * math.sin(angle)
    rise = chord * math.cos(angle)
    chord = math.hypot(span, rise)
    if taut if taut is not None else draw(st.booleans()):
        L0 = chord / (1.0 + 10.0 ** draw(st.floats(math.log10(min_strain), -1.0)))
    else:
        L0 = chord * (1.0 + 10.0 ** draw(st.floats(-10.0, 1.3)))
    w = 10.0 ** draw(st.floats(-4.0, 3.0))
    EA = max(10.0 ** draw(st.floats(2.0, 10.0)), 10.0 * w * L0)
    return Cable(span, rise, L0, w, EA)


def integrate_cable(H: float, V0: float, L0: float, w: float, EA: float) -> tuple[float, float, float, float]:
    """``(x, z, Tx, Tz)`` at s = L0 of the cable starting at the origin with tension (H, V0).

    In units of L0 and of the larger end tension: the tension equation dT/ds = w ẑ integrates exactly to
    T(u) = (h, v0 + weight u); the position equations d(x, z)/du = T (1/|T| + stretch) are integrated by
    adaptive quadrature (scipy ``quad``: QUADPACK's Gauss–Kronrod, to 1e-14 absolute, 1e-12 relative; a
    warning that it did not get there is an error), split where the vertical tension changes sign (the kink
    of |T| when H is ~0) and, about that fold, at widths h/weight · 4^k (|T| turns over a few h/weight: an
    adaptive rule sampling only coarser points would not see it)."""
    F = max(math.hypot(H, V0), math.hypot(H, V0 + w * L0))
    stretch, weight = F / EA, w * L0 / F
    h, v0 = H / F, V0 / F
    fold = -v0 / weight
    width = h / weight
    knots = [0.0, *([fold] if 0.0 < fold < 1.0 else []), 1.0]
    x = z = 0.0
    for a, b in itertools.pairwise(knots):
        side = 1.0 if a >= fold else -1.0  # a vertical cable at its fold: it leaves upwards on the far side

        def dx(u: float) -> float:
            T = math.hypot(h, v0 + weight * u)
            return h / T + h * stretch if T else 0.0

        def dz(u: float, side: float = side) -> float:
            v = v0 + weight * u
            T = math.hypot(h, v)
            return v / T + v * stretch if T else side

        points: list[float] = []
        d = width
        while 0.0 < d < 2.0:
            points += [p for p in (fold - d, fold + d) if a < p < b]
            d *= 4.0
        rule = {"epsabs": 1e-14, "epsrel": 1e-12, "limit": 400, "points": sorted(points) or None}
        with warnings.catch_warnings():
            warnings.simplefilter("error", IntegrationWarning)
            x += quad(dx, a, b, **rule)[0]
            z += quad(dz, a, b, **rule)[0]
    return x * L0, z * L0, h * F, (v0 + weight) * F


def check_against_the_ode(c: Cable, H: float, V0: float, V1: float, L0: float) -> tuple[float, float]:
    """The integrated cable from the platform end with (H, V0) must reach the frame end with (H, V1).

    Returns the end-point error (m) and the end-force error (N)."""
    x, z, Tx, Tz = integrate_cable(H, V0, L0, c.w, c.EA)
    largest = max(math.hypot(H, V0), math.hypot(H, V1))
    position_error = math.hypot(x - c.span, z - c.rise)
    force_error = math.hypot(Tx - H, Tz - V1)
    scale = L0 * (1.0 + largest / c.EA) + c.chord
    assert position_error <= 2.0 * LENGTH_TOL + 1e-9 * scale, (position_error, scale)
    assert force_error <= 1e-9 * largest, (force_error, largest)
    return position_error, force_error


@PROPERTY
@given(cables())
def test_solve_catenary_agrees_with_the_integrated_cable(c: Cable) -> None:
    sol = solve_catenary(c.span, c.rise, c.L0, c.w, c.EA)
    H, V0, V1 = float(sol.horizontal[0]), float(sol.vertical_platform[0]), float(sol.vertical_frame[0])
    assert H >= 0.0
    assert (H == 0.0) == (c.span == 0.0)  # a vertical cable has no horizontal force, any other one has
    weight = V1 - V0  # the frame end also carries the cable's weight
    assert weight == pytest.approx(c.w * c.L0, rel=1e-12, abs=ROUNDING * abs(V0))
    check_against_the_ode(c, H, V0, V1, c.L0)


@PROPERTY
@given(cables(), st.sampled_from(["platform", "frame"]))
def test_solve_catenary_tension_agrees_with_the_integrated_cable(c: Cable, end: str) -> None:
    """A tension one real cable between these ends has at ``end`` is solved for the shortest such cable."""
    real = solve_catenary(c.span, c.rise, c.L0, c.w, c.EA)
    T = float((real.tension_platform if end == "platform" else real.tension_frame)[0])
    if not T > 0.0:  # a vertical cable folded exactly at this end holds nothing there
        assert c.span == 0.0
        return
    sol = solve_catenary_tension(c.span, c.rise, T, c.w, c.EA, end=end)
    H, V0, V1 = float(sol.horizontal[0]), float(sol.vertical_platform[0]), float(sol.vertical_frame[0])
    L0 = float(sol.unstretched_length[0])
    held = float((sol.tension_platform if end == "platform" else sol.tension_frame)[0])
    assert held == pytest.approx(T, rel=1e-8)
    weight = V1 - V0
    assert weight == pytest.approx(c.w * L0, rel=1e-12, abs=ROUNDING * abs(V0))
    assert L0 <= c.L0 * (1.0 + 1e-9) + 2.0 * LENGTH_TOL  # the taut branch: no shorter cable has this tension
    check_against_the_ode(c, H, V0, V1, L0)


@settings(max_examples=300, deadline=None, database=None, derandomize=True,
          suppress_health_check=list(HealthCheck))
@given(cables(taut=True, min_strain=1e-6), st.floats(-8.0, -2.0))
def test_weightless_cables_are_springs(c: Cable, log_eps: float) -> None:
    """As w → 0 a taut cable is the straight spring T = EA (chord − L0)/L0 along the chord: with w set
    so that the weight is ε of the tension (and its sag a fraction ≲ ε²/24 of the stretch), both end
    forces are within ε/2 of the spring's (plus rounding), and exactly the spring's for w = 1e-300."""
    T = c.EA * (c.chord - c.L0) / c.L0
    direction = np.array([c.span, c.rise]) / c.chord
    eps = 10.0 ** log_eps
    for w, bound in ((eps * T / c.L0 * min(1.0, math.sqrt(T / c.EA)), eps), (1e-300, 0.0)):
        sol = solve_catenary(c.span, c.rise, c.L0, w, c.EA)
        for V in (sol.vertical_platform, sol.vertical_frame):
            force = np.array([sol.horizontal[0], V[0]])
            assert np.linalg.norm(force - T * direction) <= (0.5 * bound + 1e-8) * T
        back = solve_catenary_tension(c.span, c.rise, T, w, c.EA)
        assert back.unstretched_length[0] == pytest.approx(c.L0, rel=bound + 1e-8)


@pytest.mark.parametrize("off", [0.0, 1e-14, 1e-10, 1e-6, 1.745e-4, 1e-2])  # rad; 1.745e-4 rad = 0.01°
def test_near_vertical_stiff_cables_at_low_tension(off: float) -> None:
    """The issue's case: 1 m of the sag scenario's rope (0.05 kg/m, EA 1 MN) holding ~9.75 N, within
    0.01° of the vertical; and the forces re-solved at the length the tension solver returned."""
    w, EA = 0.05 * G, 1e6
    span, rise = math.sin(off), math.cos(off)
    c = Cable(span, rise, 1.0, w, EA)
    for end in ("platform", "frame"):
        sol = solve_catenary_tension(span, rise, 9.75, w, EA, end=end)
        L0 = float(sol.unstretched_length[0])
        again = solve_catenary(span, rise, L0, w, EA)
        assert again.horizontal[0] == pytest.approx(sol.horizontal[0], rel=1e-6, abs=1e-9)
        assert again.vertical_platform[0] == pytest.approx(sol.vertical_platform[0], rel=1e-9)
        # the weight is not dropped: the ends differ by w L0 (0.49 N, 5 % of the tension)
        assert again.vertical_frame[0] - again.vertical_platform[0] == pytest.approx(w * L0, rel=1e-12)
        check_against_the_ode(Cable(span, rise, L0, w, EA), float(again.horizontal[0]),
                              float(again.vertical_platform[0]), float(again.vertical_frame[0]), L0)
    sol = solve_catenary(span, rise, 1.0 - 1e-5, w, EA)  # a length a winch holds
    check_against_the_ode(c, float(sol.horizontal[0]), float(sol.vertical_platform[0]),
                          float(sol.vertical_frame[0]), 1.0 - 1e-5)


def test_hanging_rod() -> None:
    """Vertical cables by Hooke's law by hand: stretched up, hanging down, folded into a U."""
    w, EA, L0 = 2.0, 1e4, 3.0
    # up: the bottom end pulled down by 10 N; the top carries that and the 6 N of cable
    rise = L0 + (10.0 * L0 + w * L0 * L0 / 2.0) / EA
    assert hanging_rod(rise, L0, w, EA) == pytest.approx([10.0], rel=1e-9)
    # down: the platform above holds the cable and 4 N more pulling down at the frame end
    V0 = -(4.0 + w * L0)
    rise = -L0 + (V0 * L0 + w * L0 * L0 / 2.0) / EA
    assert hanging_rod(rise, L0, w, EA) == pytest.approx([V0], rel=1e-9)
    # a U with both ends at the same height: each end holds half the cable
    assert hanging_rod(0.0, L0, w, EA) == pytest.approx([-w * L0 / 2.0], rel=1e-12)


def test_no_catenary_below_the_least_tension() -> None:
    """The frame end of a cable 4 m above the platform lifts at least the weight of a cable that long
    (w·rise); less has no catenary, which the error says, with the least tension found."""
    w = 10.0
    with pytest.raises(CatenaryError, match=r"no catenary between these ends.*the least is"):
        solve_catenary_tension(2.0, 4.0, 30.0, w, 1e5, end="frame")
    with pytest.raises(CatenaryError, match="no catenary"):
        solve_catenary_tension(0.0, 4.0, 30.0, w, 1e5, end="frame")  # vertical: ≥ w·rise = 40 N
    assert solve_catenary_tension(0.0, 4.0, 41.0, w, 1e5, end="frame").tension_frame[0] == pytest.approx(41.0)
    with pytest.raises(ValueError, match="coincide"):
        solve_catenary_tension(0.0, 0.0, 1.0, w, 1e5)
    with pytest.raises(ValueError, match="span must be >= 0"):
        solve_catenary(-1.0, 1.0, 2.0, w, 1e5)
