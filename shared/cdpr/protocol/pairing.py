"""What a controller answers: state k, once setpoint k is there, exactly once (and again on a resend).

Setpoints come in blocks ahead of the loop (``trajectory/setpoints``), states one by one (``sim/state``).
:class:`Pairing` keeps the setpoints not used yet and the newest state still waiting for its setpoint,
and says which (state, setpoint) pair to answer now. A state that comes again after its answer (the
clock's resend) is answered again; a setpoint block never makes an answered step due again.
"""

from __future__ import annotations

from cdpr.protocol.messages import Setpoint, Setpoints, State


class Pairing:
    def __init__(self) -> None:
        self.setpoints: dict[int, Setpoint] = {}
        self.waiting: State | None = None  # the newest state whose setpoint has not come yet
        self.answered = -1  # the last step answered

    def on_state(self, state: State) -> tuple[State, Setpoint] | None:
        """State k arrived: the pair to answer now, if its setpoint is there."""
        setpoint = self.setpoints.get(state.step)
        if setpoint is None:
            self.waiting = state
            return None
        self.waiting = None
        return state, setpoint

    def on_setpoints(self, block: Setpoints) -> tuple[State, Setpoint] | None:
        """A block arrived: the waiting state's pair, if the block brought its setpoint."""
        self.setpoints.update((sp.step, sp) for sp in block.items)
        state = self.waiting
        if state is None or state.step <= self.answered:
            return None
        return self.on_state(state)

    def done(self, step: int) -> None:
        """Step ``step`` was answered: the setpoints before it are no longer needed (its own is kept, for a
        resend of its state)."""
        self.answered = max(self.answered, step)
        self.setpoints.pop(step - 1, None)
