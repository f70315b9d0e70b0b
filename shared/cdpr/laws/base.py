"""What a control law declares (:class:`Law`) and what its core does (:class:`LawCore`). Pure: no I/O.

A law's core answers state k with the tensions (or, for length output, the unstretched lengths) of step k. What
it needs besides the state is its ``inputs``: ``setpoints`` (the trajectory's setpoint of the same step) and/or
``camera`` (the frames of a camera of the scenario). States, setpoints and frames are the protocol's messages
(:mod:`cdpr.protocol`), read here through the attributes the laws use (:class:`StateLike`, …).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Literal, Protocol

from pydantic import BaseModel, ConfigDict

from cdpr.mechanics.rotation import Array
from cdpr.mechanics.tda import TdaResult

Input = Literal["setpoints", "camera"]


class StateLike(Protocol):
    @property
    def step(self) -> int: ...
    @property
    def t(self) -> float: ...
    @property
    def pose(self) -> Sequence[float]: ...
    @property
    def twist(self) -> Sequence[float]: ...


class SetpointLike(Protocol):
    @property
    def step(self) -> int: ...
    @property
    def pose(self) -> Sequence[float]: ...
    @property
    def twist(self) -> Sequence[float]: ...
    @property
    def accel(self) -> Sequence[float]: ...


class FrameLike(Protocol):
    @property
    def camera(self) -> str: ...
    @property
    def step(self) -> int: ...
    @property
    def ids(self) -> Sequence[str]: ...
    @property
    def pixels(self) -> Sequence[float]: ...
    @property
    def depth(self) -> Sequence[float]: ...


class LawSpec(BaseModel):
    """The base of a law's section of the scenario's controller (``controller.<law>``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class LawCore(Protocol):
    """One law's step object: :meth:`command` answers state k (``setpoint``: step k's, None for a law without
    setpoints; ``residual``: a wrench on the controlled rows added to the law's, a learned policy's); the same
    inputs in the same order give the same outputs."""

    def command(self, state: StateLike, setpoint: SetpointLike | None,
                residual: Array | None = None) -> tuple[TdaResult, Array | None]: ...

    def reset(self) -> None:
        """Forget what earlier answers left (the distribution's warm start): a new episode."""


class FrameLaw(LawCore, Protocol):
    """A law with ``camera`` among its inputs: the node hands it every frame of :attr:`camera` and answers state k
    once the frame :meth:`frame_needed` names (the newest out by step k) is in."""

    @property
    def camera_name(self) -> str: ...
    @property
    def frame_step(self) -> int: ...
    def on_frame(self, frame: FrameLike) -> None: ...
    def frame_needed(self, step: int) -> int | None: ...


@dataclass(frozen=True)
class Law:
    """One control law, declared once (its module in :mod:`cdpr.laws`, a row of ``LAWS``).

    ``name``: the scenario's ``controller.law``; ``build(scenario)``: its core for a
    :class:`cdpr.config.scenario.Scenario`; ``inputs``: what it needs besides ``sim/state``; ``section``: its
    entry ``controller.<name>`` (None: it has none); ``check(section, spec)``: a ValueError (one line) for a
    scenario (:class:`cdpr.config.scenario.ScenarioSpec`) the law cannot run; ``summary(core)``: a line for the
    controller's log at the end."""

    name: str
    doc: str
    build: Callable[[Any], LawCore]
    inputs: tuple[Input, ...] = ("setpoints",)
    section: type[LawSpec] | None = None
    check: Callable[[Any, Any], None] = lambda section, spec: None
    summary: Callable[[Any], str] = lambda core: ""


def warm_up(core: LawCore, state: StateLike, setpoint: SetpointLike, rounds: int = 3) -> None:
    """Answer (state, setpoint) a few times, then forget it (:meth:`LawCore.reset`): the first answers of a process
    pay for lazy imports and first-call set-ups (several ms), which a realtime session would otherwise see as late
    ticks. Changes nothing the next answers depend on."""
    for _ in range(rounds):
        core.command(state, setpoint)
    core.reset()
