"""CMU-Drive the benchmark: route files, criteria, metrics, the evaluation loop, results and reports.

Typical use::

    cmudrive eval --routes smoke --agent cmudrive.agents.pid:PidAgent --out out/eval --workers 2
    cmudrive report out/eval -o out/report

or in Python: ``read_routes`` -> ``run_evaluation(routes, agent, out, LocalExecutor(2))``.
"""

from cmudrive.bench.criteria import CriteriaConfig, RouteCriteria
from cmudrive.bench.evaluator import EvalConfig, RouteInputError, evaluate_route
from cmudrive.bench.metrics import ABILITIES, route_result, route_scores, summarize
from cmudrive.bench.records import INFRACTION_KEYS, PENALTIES, CavResult, Infraction, RouteResult
from cmudrive.bench.routes import CavSpec, RouteSpec, RouteSpecError, ScenarioSpec, read_routes, write_routes
from cmudrive.bench.runner import LocalExecutor, RayExecutor, run_evaluation
from cmudrive.bench.scenario_types import SCENARIO_TYPES

__all__ = [
    "ABILITIES",
    "INFRACTION_KEYS",
    "PENALTIES",
    "SCENARIO_TYPES",
    "CavResult",
    "CavSpec",
    "CriteriaConfig",
    "EvalConfig",
    "Infraction",
    "LocalExecutor",
    "RayExecutor",
    "RouteCriteria",
    "RouteInputError",
    "RouteResult",
    "RouteSpec",
    "RouteSpecError",
    "ScenarioSpec",
    "evaluate_route",
    "read_routes",
    "route_result",
    "route_scores",
    "run_evaluation",
    "summarize",
    "write_routes",
]
