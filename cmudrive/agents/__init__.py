"""Agents that drive CAVs: the batched agent interface and the rule-based agents, the PID smoke-test agent,
the demo autopilot and the privileged expert (``cmudrive.agents.expert``), and the occupancy safety brake
a learned agent may add (:class:`SafetyBrake`). The learned V2V-VLA agent lives
beside its model (``cmudrive.model.agent``); ``--agent`` names all four (``load_agent_class``).

Write your own agent by subclassing :class:`Agent` (see README, "Evaluate your own agent")."""

from cmudrive.agents.autopilot import AutopilotAgent, LaneFollowingAutopilot
from cmudrive.agents.base import (
    Agent,
    AgentSetupError,
    CavPlan,
    Observation,
    Observations,
    RouteSetup,
    check_observations,
    load_agent_class,
    sparse_plan,
)
from cmudrive.agents.pid import PidAgent
from cmudrive.agents.shield import SafetyBrake

__all__ = [
    "Agent",
    "AgentSetupError",
    "AutopilotAgent",
    "CavPlan",
    "LaneFollowingAutopilot",
    "Observation",
    "Observations",
    "PidAgent",
    "RouteSetup",
    "SafetyBrake",
    "check_observations",
    "load_agent_class",
    "sparse_plan",
]
