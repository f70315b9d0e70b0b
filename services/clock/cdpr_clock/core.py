"""The clock's logic, free of I/O: which steps may be granted now, and the statistics.

Step k is *complete* when the sim has published its state k+1; the clock hears of it through the sim's
telemetry blocks. Step k (k > 0; tick 0 starts the run) may be granted once the sim has reached step
k − ``lookahead``: one tick grants every step up to that limit (a window: one message for many steps). In
``fast`` mode a tick that reaches the limit asks the sim for a report once it is done (``flush``), so the
clock never waits for a block that is not due. The sim never integrates step k before a tick grants it.
While paused, nothing is issued.

Realtime (``realtime``): the sim keeps the wall clock, not the clock service. After the handshake the clock
grants windows of at least :data:`FREE_AHEAD` seconds of steps ahead, marked ``paced`` (and ``free`` with
``--sync free``); the sim integrates each step at its own deadline, ``dt`` apart from the first paced
grant — in lock-step once its command has come too (the deadlines restart after a pause or a stall: no
burst to catch up) — and reports how late each one started (:meth:`ClockCore.on_lateness`): the step is
on time when it started within ``dt`` of its deadline, late beyond. No message per step besides the
state and the command: realtime costs what fast mode costs.

The first step is a handshake: tick 0 grants step 0 alone (with a report), and nothing more is granted
until the sim's state 1 shows that the whole loop is connected: the sim heard the clock, the
controller heard the sim and the trajectory, the sim heard the controller. Zenoh delivers a
publication only to the subscribers its session already knows of, and a peer that has just joined may
learn of the others' subscribers a few milliseconds after the clock saw every liveliness token; until
state 1 arrives the node repeats tick 0 at short intervals (:meth:`handshake_repeat_due`).
In realtime mode the deadlines start with the first paced grant, sent as state 1 arrives; the run's
real-time factor is measured from there.

Free-running realtime (``free``, ``--sync free``): the same windows, marked ``free`` too: the sim no longer
waits for commands (the newest it holds acts). The command ages and the watchdog's steps of free-running and
of a command latency come from the states (:meth:`ClockCore.on_ages`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

FREE_AHEAD = 0.25  # s of steps granted ahead of the sim's last state in realtime (at least)


@dataclass
class ClockCore:
    total_steps: int
    dt: float
    realtime: bool = False
    lookahead: int = 100
    free: bool = False  # free-running realtime (module docstring)
    issued: int = -1  # highest tick issued
    reached: int = -1  # highest step whose state has been received
    paused: bool = True  # until every expected participant is there
    started_at: float | None = None  # wall time of tick 0
    last_progress: float = 0.0
    resends: int = 0
    late_ticks: int = 0
    paused_time: float = 0.0
    _paused_since: float | None = field(default=None, repr=False)
    handshake_repeats: int = 0  # tick 0 repeated while waiting for state 1
    lateness: list[float] = field(default_factory=list)
    _on_time: int = field(default=0, repr=False)  # steps started within dt of their deadline
    _latest: float = field(default=-math.inf, repr=False)  # the largest lateness
    _percentiles: dict[str, float] = field(default_factory=dict, repr=False)  # see stats()
    _percentiles_of: int = field(default=0, repr=False)  # how many ticks they were computed from
    ages: dict[int, int] = field(default_factory=dict)  # command age (steps) -> how many steps had it
    watchdog_steps: int = 0  # steps on which the sim's watchdog policy acted
    window: list[tuple[float, bool]] = field(default_factory=list, repr=False)  # (time, late) of the last second
    peak: float = field(default=-math.inf, repr=False)  # the largest lateness since take_peak()
    paced_from: float | None = None  # realtime: the arrival of state 1 (the wall clock's rate from there)

    def __post_init__(self) -> None:
        if self.free:
            self.realtime = True
        if self.realtime:
            self.lookahead = max(self.lookahead, math.ceil(FREE_AHEAD / self.dt))

    @property
    def finished(self) -> bool:
        return self.reached >= self.total_steps

    def next_grant(self, now: float) -> tuple[int, int, bool] | None:
        """``(first, until, flush)`` of the tick to issue now, if any (call repeatedly until None)."""
        k = self.issued + 1
        if self.paused or k >= self.total_steps:
            return None
        if k > 0 and self.reached < max(1, k - self.lookahead):
            return None
        if k == 0:
            return 0, 0, True  # the handshake (module docstring)
        until = max(k, min(self.total_steps - 1, self.reached + self.lookahead))
        return k, until, until >= self.reached + self.lookahead and not self.realtime

    def issue(self, k: int, now: float, until: int | None = None) -> None:
        """Record the grant of steps ``k`` … ``until`` (default: ``k``) at ``now``."""
        if self.started_at is None:
            self.started_at = now
            self.last_progress = now
        self.issued = k if until is None else until

    def _record(self, late: float, now: float) -> None:
        self.lateness.append(late)
        if late > self.dt:
            self.late_ticks += 1
        if late * 1e3 <= self.dt * 1e3:  # (in ms, as stats() reports it)
            self._on_time += 1
        self._latest = max(self._latest, late)
        self.peak = max(self.peak, late)
        self.window.append((now, late > self.dt))

    def take_peak(self) -> float:
        """The largest lateness recorded since the last call (s; -inf: none)."""
        peak, self.peak = self.peak, -math.inf
        return peak

    def behind(self, now: float) -> float:
        """How far the loop is behind the wall clock now (s), as far as the clock can tell between two reports
        of the sim's lateness: how long the sim has not been heard of, beyond a telemetry block's period."""
        if self.started_at is None or self.paused or self.finished or not self.realtime:
            return 0.0
        return now - self.last_progress - 0.25 if self.reached >= 1 else 0.0

    def on_lateness(self, lateness: list[float] | tuple[float, ...], now: float) -> None:
        """Realtime: how late the sim started each of a block's steps (s)."""
        for late in lateness:
            self._record(late, now)

    def on_ages(self, ages: list[int], watchdog: int) -> None:
        """The command ages of a block's steps, and how many of them ran on the watchdog's policy."""
        counts = self.ages
        for age in ages:
            counts[age] = counts.get(age, 0) + 1
        self.watchdog_steps += watchdog

    def late_share(self, now: float, span: float = 1.0) -> tuple[float, int]:
        """The share of the steps reported in the last ``span`` seconds that were late, and how many there
        were."""
        window = self.window
        cut = 0
        while cut < len(window) and window[cut][0] < now - span:
            cut += 1
        del window[:cut]
        n = len(window)
        return (sum(late for _, late in window) / n if n else 0.0), n

    def on_state(self, k: int, now: float) -> bool:
        """Record state k; True if it is news (progress)."""
        if k <= self.reached:
            return False
        if self.reached < 1 <= k and self.realtime:
            self.paced_from = now  # the handshake is over: the paced grant goes out now
        self.reached = k
        self.last_progress = now
        return True

    @property
    def handshaking(self) -> bool:
        """Tick 0 issued, state 1 not received yet."""
        return self.issued >= 0 and self.reached < 1

    def handshake_repeat_due(self, first: float = 0.05, most: float = 1.0) -> float | None:
        """During the handshake, when tick 0 is to be repeated: ``first`` seconds after the last grant
        or repeat, doubling with every repeat up to ``most`` (None: not handshaking)."""
        if not self.handshaking or self.paused:
            return None
        return self.last_progress + min(most, first * 2.0**self.handshake_repeats)

    def pause(self, now: float) -> None:
        if not self.paused:
            self.paused = True
            self._paused_since = now

    def resume(self, now: float) -> tuple[int, int] | None:
        """Leave the pause; returns the grant to issue again (steps begun but not complete)."""
        if not self.paused:
            return None
        self.paused = False
        if self._paused_since is not None:
            self.paused_time += now - self._paused_since
            self._paused_since = None
        self.last_progress = now
        return self.pending()

    def pending(self) -> tuple[int, int] | None:
        """The granted steps not complete yet, ``(first, last)``: what a resend repeats (None: nothing)."""
        first = max(self.reached, 0)
        return (first, self.issued) if self.issued >= first else None

    def stats(self, now: float, exact: bool = True) -> dict[str, float | int]:
        """The run's statistics at ``now``. In realtime mode, with ``exact=False`` (the once-a-second
        status), the lateness percentiles are recomputed only when the steps reported since the last
        time are half as many again: sorting a minute of steps takes milliseconds, and while the clock
        sorts it grants nothing. The counts, the maximum and the on-time fraction are always exact."""
        wall = 0.0 if self.started_at is None else now - self.started_at - self.paused_time
        if self._paused_since is not None:
            wall -= now - self._paused_since
        steps = max(self.reached, 0)
        paced_wall, paced_steps = wall, steps  # realtime: from state 1 (the handshake's round trips left out)
        if self.paced_from is not None and self.started_at is not None:
            paced_wall -= self.paced_from - self.started_at
            paced_steps -= 1
        out: dict[str, float | int] = {
            "steps": steps,
            "sim_time": steps * self.dt,
            "wall_time": wall,
            "rate": steps / wall if wall > 0 else 0.0,
            "rtf": (paced_steps * self.dt / paced_wall if paced_wall > 0 else 0.0) if self.realtime else
                   (steps * self.dt / wall if wall > 0 else 0.0),
            "late_ticks": self.late_ticks,
            "resends": self.resends,
            "handshake_repeats": self.handshake_repeats,
            "paused_time": self.paused_time,
        }
        n = len(self.lateness)
        if n:
            if exact or n >= 1.5 * self._percentiles_of:
                lat = np.asarray(self.lateness) * 1e3
                p50, p99, p999 = (float(x) for x in np.percentile(lat, [50, 99, 99.9]))
                self._percentiles = {"lateness_p50_ms": p50, "lateness_p99_ms": p99, "lateness_p999_ms": p999}
                self._percentiles_of = n
            out.update(self._percentiles, lateness_max_ms=self._latest * 1e3,
                       on_time_fraction=self._on_time / n)
        if self.ages:
            out.update(_age_stats(self.ages), watchdog_steps=self.watchdog_steps)
        return out


def _age_stats(counts: dict[int, int]) -> dict[str, int]:
    """The median, 99th percentile and largest command age, in steps, from the count of each age: the
    smallest age that many steps did not exceed (numpy's ``inverted_cdf`` percentile, as cdpr report)."""
    ages = sorted(counts)
    cumulative = np.cumsum([counts[a] for a in ages])
    total = int(cumulative[-1])
    p50, p99 = (ages[int(np.searchsorted(cumulative, q * total))] for q in (0.5, 0.99))
    return {"command_age_p50": p50, "command_age_p99": p99, "command_age_max": ages[-1]}
