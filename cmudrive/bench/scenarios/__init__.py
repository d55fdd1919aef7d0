"""Scenario behaviour: the Bench2Drive scenario types on the road (``docs/scenarios.md``).

One module per family (``obstacles``), the life cycle in ``base``, shared behaviours in ``behaviours``,
placement along lanes in ``placement``, parameters and their errors in ``params``, and the per-route
``manager`` that the evaluator steps before every world tick.
"""

from cmudrive.bench.scenarios.base import RouteProgress, Scenario, ScenarioConfig, ScenarioContext
from cmudrive.bench.scenarios.manager import REGISTRY, ScenarioManager, build_scenarios
from cmudrive.bench.scenarios.params import Param, ScenarioError

__all__ = [
    "REGISTRY",
    "Param",
    "RouteProgress",
    "Scenario",
    "ScenarioConfig",
    "ScenarioContext",
    "ScenarioError",
    "ScenarioManager",
    "build_scenarios",
]
