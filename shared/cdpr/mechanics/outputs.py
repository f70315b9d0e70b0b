"""What a controller commands each step: cable tensions (N), or unstretched cable lengths (m) for
winch-driven cables (the sim's winch drives then hold them) — the ``tensions``/``lengths`` field of
``controller/command``. No numpy here: the wire protocol imports it, and a remote controller's start-up with it."""

from __future__ import annotations

from typing import Literal, get_args

CommandKind = Literal["tensions", "lengths"]
COMMAND_KINDS: tuple[CommandKind, ...] = get_args(CommandKind)
