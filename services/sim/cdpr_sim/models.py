"""The scenario's cable model, chosen: the module above the models (:mod:`cdpr_sim.core` is below them).

Every model has the interface of :class:`~cdpr_sim.core.SimModel` and a ``from_scenario`` class method.
"""

from __future__ import annotations

import importlib
from typing import Protocol, cast

from cdpr.config.scenario import Scenario
from cdpr_sim.core import SimModel


class _FromScenario(Protocol):
    def from_scenario(self, scenario: Scenario) -> SimModel: ...


# The sim's class of each cable model of cdpr.config.scenario.CABLE_MODELS (tests/test_cable_models.py: the same
# names), as "module:class" (only the scenario's model is imported: a sim's start-up does not pay for the
# others): a new cable model is its module, its row there (and its parameters' section), and its row here.
SIM_MODELS: dict[str, str] = {
    "ideal": "cdpr_sim.core:PlatformSim",
    "ups": "cdpr_sim.ups:UpsSim",
    "elastic": "cdpr_sim.elastic:ElasticSim",
    "sag": "cdpr_sim.sag:SagSim",
}


def sim_class(cable_model: str) -> _FromScenario:
    """The sim's class for ``cable_model`` (a name of SIM_MODELS), imported."""
    module, _, name = SIM_MODELS[cable_model].partition(":")
    return cast(_FromScenario, getattr(importlib.import_module(module), name))


def make_sim(scenario: Scenario) -> SimModel:
    """The physics of the scenario's cable model."""
    return sim_class(scenario.cable_model).from_scenario(scenario)
