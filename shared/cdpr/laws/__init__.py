"""The control laws, declared once: each law is its module (its core, its section of the scenario's controller,
its inputs) and a row of :data:`LAWS`. From this table follow the scenario's ``controller.law`` and its sections,
the controller node (what it subscribes to, its step: ``cdpr_controller``), and the learning environment's base
law (:mod:`cdpr.gym`). A new law: a module like :mod:`cdpr.laws.ibvs` and its row below (docs/laws.md, "Adding a
law").
"""

from __future__ import annotations

from cdpr.laws import feedback_linearisation, ibvs
from cdpr.laws.base import FrameLaw, Law, LawCore, LawSpec

LAWS: dict[str, Law] = {law.name: law for law in (
    feedback_linearisation.LAW,
    ibvs.LAW,
)}

__all__ = ["LAWS", "FrameLaw", "Law", "LawCore", "LawSpec"]
