"""Gymnasium environments over the session's own cores (extra ``.[gym]``; docs/learning.md).

Importing this package registers them::

    import gymnasium as gym
    import cdpr.gym  # noqa: F401  (or gym.make("cdpr.gym:cdpr/Track-v0", ...), which imports it)

    env = gym.make("cdpr/Track-v0", scenario="caroca_15kg", action="residual")            # local mode
    env = gym.make("cdpr/Track-v0", scenario="caroca_15kg", connect="tcp/10.0.0.5:7447")  # a session's controller

``cdpr/Track-v0`` tracks the scenario's trajectory; ``action`` is ``residual`` (a wrench added to the
feedback-linearisation law's), ``wrench`` or ``tensions``. The episode is the scenario's duration
(truncated there), or less when the platform leaves the workspace (terminated).
"""

from __future__ import annotations

from gymnasium.envs.registration import register, registry

ENV_ID = "cdpr/Track-v0"

if ENV_ID not in registry:
    register(id=ENV_ID, entry_point="cdpr.gym.env:TrackEnv", disable_env_checker=False)

__all__ = ["ENV_ID"]
