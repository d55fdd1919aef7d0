"""Scenario behaviour: the Bench2Drive scenario types on the road (``docs/scenarios.md``).

One module per family (``obstacles``), the life cycle in ``base``, shared behaviours in ``behaviours``,
placement along lanes in ``placement``, parameters and their errors in ``params``, and the per-route
``manager`` that the evaluator steps before every world tick.
"""

from cmudrive.bench.scenarios.base import RouteProgress, Scenario, ScenarioConfig, ScenarioContext
from cmudrive.bench.scenarios.manager import REGISTRY, ScenarioManager, build_scenarios, plan_scenarios
from cmudrive.bench.scenarios.params import Param, ScenarioError
from cmudrive.bench.scenarios.plan import PlanItem, PlanPath, PlanPoint

__all__ = [
    "REGISTRY",
    "Param",
    "PlanItem",
    "PlanPath",
    "PlanPoint",
    "RouteProgress",
    "Scenario",
    "ScenarioConfig",
    "ScenarioContext",
    "ScenarioError",
    "ScenarioManager",
    "build_scenarios",
    "plan_scenarios",
]
