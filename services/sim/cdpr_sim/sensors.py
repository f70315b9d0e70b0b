"""The sim's sensors: each kind of :data:`cdpr.sensors.SENSOR_KINDS` the scenario configures, read from the sim's
ground truth once per step, on its own schedule (rate, latency, dropout). No I/O.

Determinism: the numbers of kind K's reading of step k come from ``numpy.random.PCG64(numpy.random.SeedSequence([seed,
k]))`` advanced by ``K.stream · 2⁶⁴`` (:func:`draws`) — first ``K.draws(spec, m)`` standard normals, then (with a
dropout) one uniform that loses the reading when below the dropout — so a reading is a pure function of the seed,
the kind, the step and the truth: the same on a resend, in another run, whatever the other sensors (each kind's
numbers start 2⁶⁴ draws away from any other's). :class:`Draws` gives the same numbers, cheaper: the step's
generator state computed once for every kind (:func:`cdpr_sim.cameras.pcg64_state`) and one PCG64 reused.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from msgspec import UNSET

from cdpr.config.scenario import SensorsBase
from cdpr.mechanics.robot import Robot
from cdpr.mechanics.rotation import Array
from cdpr.protocol import Sensors
from cdpr.sensors import SENSOR_COLUMNS, SensorKind, Truth, latency_steps, period
from cdpr_sim.cameras import pcg64_state
from cdpr_sim.core import SimModel

_INDEX = {c.name: i for i, c in enumerate(SENSOR_COLUMNS)}


def draws(seed: int, kind: SensorKind, step: int, n: int, dropout: float) -> tuple[Array, bool]:
    """Kind ``kind``'s numbers for its reading of ``step``: n standard normals, and whether the reading is lost
    (the reference: :class:`Draws` gives the same)."""
    bits = np.random.PCG64(np.random.SeedSequence([seed, step]))
    bits.advance(kind.stream << 64)
    rng = np.random.Generator(bits)
    normals = rng.standard_normal(n)
    return normals, bool(dropout > 0.0 and rng.random() < dropout)


class Draws:
    """:func:`draws` for the sim's loop: one PCG64 reused, set to the state ``SeedSequence([seed, step])`` gives it
    (:func:`cdpr_sim.cameras.pcg64_state`, once a step for every kind), then advanced to the kind's numbers."""

    def __init__(self) -> None:
        self._bits = np.random.PCG64()
        self._rng = np.random.Generator(self._bits)
        self._key: tuple[int, int] | None = None
        self._state: Any = {}

    def __call__(self, seed: int, kind: SensorKind, step: int, n: int, dropout: float) -> tuple[Array, bool]:
        if self._key != (seed, step):
            state, inc = pcg64_state((seed, step))
            self._key = (seed, step)
            self._state = {"bit_generator": "PCG64", "state": {"state": state, "inc": inc}, "has_uint32": 0,
                           "uinteger": 0}
        self._bits.state = self._state
        self._bits.advance(kind.stream << 64)
        normals = self._rng.standard_normal(n)
        return normals, bool(dropout > 0.0 and self._rng.random() < dropout)


def measure(kind: SensorKind, spec: Any, truth: Truth, seed: int, m: int,
            draw: Any = draws) -> tuple[Array, ...] | None:
    """Kind ``kind``'s reading of ``truth.step`` (one array per channel), or None when it is lost."""
    normals, lost = draw(seed, kind, truth.step, kind.draws(spec, m), spec.dropout)
    return None if lost else kind.measure(truth, spec, normals)


@dataclass(frozen=True)
class _Sensor:
    kind: SensorKind
    spec: Any  # its scenario entry (sim.sensors.<kind>)
    period: int  # steps between readings
    latency: int  # steps from a reading's measurement to its delivery
    slots: tuple[int, ...]  # its channels' places among SENSOR_COLUMNS


class SensorSuite:
    """The sensors of one sim (owned by the sim node): the truth from the sim, one message per step.

    :meth:`read` takes the sim's current state (and its winches' ``encoder_lengths()`` and
    ``load_cell_tensions()``), keeps the previous step's twist for the IMU's mean acceleration and the readings
    still on their way (latency), and returns the same message again for a step already read (a resend).
    """

    def __init__(self, spec: SensorsBase, robot: Robot, dt: float) -> None:
        self.seed = spec.seed
        self.m = robot.m
        self.dt = float(dt)
        self.com_offset = np.array(robot.com_offset, dtype=float)
        self.encoder_offsets = np.array(robot.encoder_offsets, dtype=float)  # what the encoders read beyond
        self.sensors = tuple(_Sensor(kind, entry, period(entry, dt), latency_steps(entry, dt),
                                     tuple(_INDEX[c.name] for c in kind.channels)) for kind, entry in spec.kinds())
        self.previous: tuple[int, Array] | None = None  # (step, twist) of the last new step read (a sim's snapshot)
        self.pending: dict[int, list[tuple[int, tuple[tuple[float, ...], ...]]]] = {}  # step → (sensor, values)
        self._last: Sensors | None = None
        self._draw = Draws()

    def truth(self, sim: SimModel, state: Any = None) -> Truth:
        """What the sensors measure now (``state``: ``sim.state()``, if the caller has it)."""
        state = sim.state() if state is None else state
        twist = np.asarray(state.twist, dtype=float)
        prev = self.previous
        if prev is not None and prev[0] == state.step - 1:
            acceleration = (twist[:3] - prev[1][:3]) / self.dt
        else:
            acceleration = np.zeros(3)
        return Truth(state.step, state.t, np.asarray(state.position, dtype=float), state.rotation, twist,
                     acceleration, sim.encoder_lengths() + self.encoder_offsets, sim.load_cell_tensions(),
                     self.com_offset)

    def read(self, sim: SimModel) -> Sensors:
        state = sim.state()
        if self._last is not None and self._last.step == state.step:
            return self._last
        return self.take(self.truth(sim, state))

    def take(self, truth: Truth) -> Sensors:
        """The message of ``truth.step`` (a new step): the readings measured now and delivered now, and those
        measured earlier whose latency ends now."""
        k = truth.step
        for j, s in enumerate(self.sensors):
            if k % s.period:
                continue
            reading = measure(s.kind, s.spec, truth, self.seed, self.m, self._draw)
            if reading is not None:
                self.pending.setdefault(k + s.latency, []).append((j, tuple(tuple(v.tolist()) for v in reading)))
        channels: list[Any] = [UNSET] * len(SENSOR_COLUMNS)
        for j, values in self.pending.pop(k, ()):
            for slot, v in zip(self.sensors[j].slots, values, strict=True):
                channels[slot] = v
        for late in [d for d in self.pending if d < k]:  # a gap in the steps: never delivered
            del self.pending[late]
        self.previous = (k, truth.twist)
        self._last = Sensors(k, truth.t, *channels)
        return self._last

    def snapshot(self) -> dict[str, Any]:
        """What a restarted sim needs to read on from here (the resume snapshot's ``sensors_*`` fields)."""
        prev = self.previous
        out: dict[str, Any] = {"sensors_previous": None if prev is None else [prev[0], prev[1].tolist()]}
        if self.pending:
            out["sensors_pending"] = [[step, j, [list(v) for v in values]]
                                      for step, items in sorted(self.pending.items()) for j, values in items]
        last = self._last
        if last is not None and prev is not None and last.step == prev[0]:  # the message of the snapshot's step
            out["sensors_last"] = {"step": last.step, "t": last.t, **{k: list(v) for k, v in last.readings.items()}}
        return out

    def restore(self, snapshot: dict[str, Any]) -> None:
        previous = snapshot.get("sensors_previous")
        self.previous = None if previous is None else (int(previous[0]), np.array(previous[1], dtype=float))
        self.pending = {}
        for step, j, values in snapshot.get("sensors_pending", ()):
            self.pending.setdefault(int(step), []).append((int(j), tuple(tuple(map(float, v)) for v in values)))
        last = snapshot.get("sensors_last")  # the snapshot step's message: read again as it was, not measured again
        self._last = None if last is None else Sensors(int(last["step"]), float(last["t"]), **{
            k: tuple(map(float, v)) for k, v in last.items() if k not in ("step", "t")})

