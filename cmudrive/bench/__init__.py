"""CMU-Drive the benchmark: route files, criteria, metrics, the evaluation loop, results and reports.

Typical use::

    cmudrive eval --routes smoke --agent cmudrive.agents.pid:PidAgent --out out/eval --workers 2
    cmudrive eval --routes cmudrive44 --routes-subset 0-5 --out out/first6
    cmudrive report out/eval out/eval-seed1 -o out/report   # an HTML page comparing runs
    cmudrive export out/eval --format leaderboard --per route   # leaderboard / Bench2Drive files

or in Python: ``read_routes`` -> ``run_evaluation(routes, agent, out, LocalExecutor(2))``.
"""

from cmudrive.bench.callbacks import RouteCallback, RouteStart, Step
from cmudrive.bench.criteria import CriteriaConfig, RouteCriteria
from cmudrive.bench.evaluator import EvalConfig, RouteInputError, evaluate_route
from cmudrive.bench.export import export_leaderboard
from cmudrive.bench.leaderboard import ExportError, LeaderboardExport
from cmudrive.bench.metrics import ABILITIES, route_result, route_scores, summarize, v2v_totals
from cmudrive.bench.progress import RunProgress
from cmudrive.bench.records import INFRACTION_KEYS, PENALTIES, CavResult, Infraction, RouteResult
from cmudrive.bench.route_sets import (
    ROUTE_SET_PURPOSES,
    RouteSelectionError,
    resolve_routes,
    route_set_names,
    select_subset,
)
from cmudrive.bench.routes import (
    ActorSpec,
    BackgroundSpec,
    CavSpec,
    RouteSpec,
    RouteSpecError,
    ScenarioSpec,
    read_routes,
    route_ids,
    write_routes,
)
from cmudrive.bench.runner import LocalExecutor, RayExecutor, run_evaluation
from cmudrive.bench.scenario_types import SCENARIO_TYPES

__all__ = [
    "ABILITIES",
    "INFRACTION_KEYS",
    "PENALTIES",
    "ROUTE_SET_PURPOSES",
    "SCENARIO_TYPES",
    "ActorSpec",
    "BackgroundSpec",
    "CavResult",
    "CavSpec",
    "CriteriaConfig",
    "EvalConfig",
    "ExportError",
    "Infraction",
    "LeaderboardExport",
    "LocalExecutor",
    "RayExecutor",
    "RouteCallback",
    "RouteCriteria",
    "RouteInputError",
    "RouteResult",
    "RouteSelectionError",
    "RouteSpec",
    "RouteSpecError",
    "RouteStart",
    "RunProgress",
    "ScenarioSpec",
    "Step",
    "evaluate_route",
    "export_leaderboard",
    "read_routes",
    "resolve_routes",
    "route_ids",
    "route_result",
    "route_scores",
    "route_set_names",
    "run_evaluation",
    "select_subset",
    "summarize",
    "v2v_totals",
    "write_routes",
]
