"""The privileged rule-based expert that drives every CAV of a route, in the spirit of PDM-Lite.

Modules: ``forecast`` (short-horizon rollouts and oriented-box conflicts), ``detour`` (lateral path shifts
around obstacles), ``agent`` (the :class:`ExpertAgent` that combines them with IDM, lights, stop signs and
the SimLingo controller).
"""

from cmudrive.agents.expert.agent import ExpertAgent, ExpertConfig, ExpertDecision
from cmudrive.agents.expert.rules import Reason

__all__ = ["ExpertAgent", "ExpertConfig", "ExpertDecision", "Reason"]
