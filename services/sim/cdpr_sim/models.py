"""The scenario's cable model, chosen: the module above the models (:mod:`cdpr_sim.core` is below them).

Every model has the interface of :class:`~cdpr_sim.core.SimModel`.
"""

from __future__ import annotations

from typing import Protocol

from cdpr.config.scenario import Scenario
from cdpr_sim.core import PlatformSim, SimModel
from cdpr_sim.elastic import ElasticSim
from cdpr_sim.sag import SagSim
from cdpr_sim.ups import UpsSim


class _FromScenario(Protocol):
    def from_scenario(self, scenario: Scenario) -> SimModel: ...


# The sim's class of each cable model of cdpr.config.scenario.CABLE_MODELS (tests/test_cable_models.py: the same
# names): a new cable model is its module, its row there (and its parameters' section), and its row here.
SIM_MODELS: dict[str, _FromScenario] = {
    "ideal": PlatformSim,
    "ups": UpsSim,
    "elastic": ElasticSim,
    "sag": SagSim,
}


def make_sim(scenario: Scenario) -> SimModel:
    """The physics of the scenario's cable model."""
    return SIM_MODELS[scenario.cable_model].from_scenario(scenario)
