"""Agents that drive CAVs. For now: the privileged lane-following autopilot used by the simulator demo."""

from cmudrive.agents.autopilot import LaneFollowingAutopilot

__all__ = ["LaneFollowingAutopilot"]
