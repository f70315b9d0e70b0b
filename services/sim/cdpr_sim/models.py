"""The scenario's cable model, chosen: the module above the models (:mod:`cdpr_sim.core` is below them).

Every model has the interface of :class:`~cdpr_sim.core.SimModel`.
"""

from __future__ import annotations

from cdpr.config.scenario import Scenario
from cdpr_sim.core import PlatformSim, SimModel
from cdpr_sim.elastic import ElasticSim
from cdpr_sim.sag import SagSim
from cdpr_sim.ups import UpsSim


def make_sim(scenario: Scenario) -> SimModel:
    """The physics of the scenario's cable model."""
    if scenario.cable_model == "ups":
        return UpsSim(scenario.robot, scenario.dt, scenario.initial_position, scenario.initial_rotation)
    if scenario.cable_model in ("elastic", "sag"):  # winch-driven cables: tension or length commands
        model = ElasticSim if scenario.cable_model == "elastic" else SagSim
        return model.from_scenario(scenario)
    return PlatformSim(scenario.robot, scenario.dt, scenario.initial_position, scenario.initial_rotation)
