"""Validate a route file without running it: ``cmudrive routes check FILE``.

Every route is read (the reader's rules: ids, CAV count and ids, ASCII numbers, coordinate and seed
ranges, weather, scenario types), its town looked up (beside the file, ``--town-dir``, committed towns),
and every CAV's waypoints planned into its dense route under the evaluator's bounds (10 m to 20 km, no
loops from back-and-forth waypoints). Scenario trigger points must lie within ``TRIGGER_TOLERANCE``
(the scenarios' activation distance, the one number the evaluator uses too) of CAV 0's route, and every
scenario must place on the map as the evaluator builds it (parameters parsed and in range, every actor's
place found: ``place_scenarios``; the scenario classes need no running world for that). One bad route
does not hide the others: each gets its own line. A route that can run is then held to the placement
rules of ``route_rules`` (room after the trigger, CAVs clear of the scenario's actors, ...): a broken rule
is reported by route and rule, and the route still runs.

``cmudrive eval`` runs the same checks on every route before the first one starts (:func:`route_problems`,
``runner.run_evaluation``): a map is loaded once per town and dropped after that town's routes, so the
check costs a map load per town (from the map cache) and a route planning per route.

The work is linear in the waypoints (one lane snap and one lane-graph search per waypoint, ~0.3 ms), and
the reader bounds them (``routes.MAX_FILE_BYTES``, ``MAX_FILE_WAYPOINTS``, ``MAX_WAYPOINTS``), so a check
answers in seconds; CAVs whose dense routes start on top of each other are refused by
``RouteSpec.dense_routes`` (``routes.start_conflicts``), which the evaluator plans with too.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from cmudrive.bench.route_rules import RuleViolation, rule_violations
from cmudrive.bench.route_spec import TRIGGER_TOLERANCE
from cmudrive.bench.routes import RouteSpec, read_routes
from cmudrive.maps import MapError, RoadMap, Route, RouteError, load_map

if TYPE_CHECKING:
    from cmudrive.bench.scenarios.base import Scenario


@dataclass(frozen=True)
class RouteCheck:
    route_id: str
    problem: str | None  # None: the route can run
    num_cavs: int = 0
    lengths: tuple[float, ...] = ()  # [m] each CAV's dense route
    rules: tuple[RuleViolation, ...] = ()  # placement rules it breaks (it still runs: ``route_rules``)


def check_route(spec: RouteSpec, maps: dict[Path, RoadMap], rules: bool = True) -> RouteCheck:
    """Whether the route can run; with ``rules``, also the placement rules it breaks (``route_rules``:
    ``routes check`` reports them, ``eval`` does not need them)."""
    try:
        path = spec.town_path()
        if path not in maps:
            maps[path] = load_map(path)
        routes = spec.dense_routes(maps[path])
    except (MapError, RouteError) as exc:
        return RouteCheck(spec.id, str(exc), len(spec.cavs))
    for scenario in spec.scenarios:
        x, y, _ = scenario.map_trigger()
        gap = float(np.min(np.hypot(routes[0].xy[:, 0] - x, routes[0].xy[:, 1] - y)))
        if gap > TRIGGER_TOLERANCE:
            return RouteCheck(
                spec.id,
                f"route {spec.id!r}, scenario {scenario.name!r}: trigger point is {gap:.1f} m from CAV 0's "
                f"route (at most {TRIGGER_TOLERANCE:g} m)",
                len(spec.cavs),
            )
    from cmudrive.bench.scenarios.params import ScenarioError

    try:
        placed = build_placed(spec, maps[path], routes)
    except ScenarioError as exc:
        return RouteCheck(spec.id, str(exc), len(spec.cavs))
    broken = tuple(rule_violations(routes, placed)) if rules else ()
    return RouteCheck(spec.id, None, len(spec.cavs), tuple(r.length for r in routes), broken)


def place_scenarios(spec: RouteSpec, road_map: RoadMap, routes: list[Route]) -> str | None:
    """None when every scenario places on the map, else the ``ScenarioError`` message (see
    :func:`build_placed`)."""
    from cmudrive.bench.scenarios.params import ScenarioError

    try:
        build_placed(spec, road_map, routes)
    except ScenarioError as exc:
        return str(exc)
    return None


def build_placed(spec: RouteSpec, road_map: RoadMap, routes: list[Route]) -> list[Scenario]:
    """The route's scenarios with behaviour here, placed on the map: each class built as the evaluator
    builds it, without a world (placement reads only the map and the CAV routes; the world is used from
    instantiation on). Raises ``ScenarioError`` naming the problem. Types without behaviour yet have
    nothing to place."""
    from cmudrive.bench.scenarios.base import ScenarioConfig, ScenarioContext
    from cmudrive.bench.scenarios.manager import REGISTRY

    rng = np.random.default_rng([spec.seed, 2])  # the evaluator's scenario stream (build_scenarios)
    absent: Any = None  # no world and no criteria: placement must not touch them
    ctx = ScenarioContext(spec.id, absent, road_map, routes, absent, rng, ScenarioConfig())
    return [REGISTRY[sc.type](sc, ctx) for sc in spec.scenarios if sc.type in REGISTRY]


def route_problems(specs: Sequence[RouteSpec]) -> dict[str, str]:
    """Route id -> why it cannot run, for every route of ``specs`` that cannot (``check_route``'s rules);
    the routes are taken town by town, each town's map dropped after its routes (bounded memory)."""
    problems: dict[str, str] = {}
    maps: dict[Path, RoadMap] = {}
    town = None
    for spec in sorted(specs, key=lambda s: (s.town, s.town_dirs)):
        if (spec.town, spec.town_dirs) != town:
            maps.clear()
            town = (spec.town, spec.town_dirs)
        try:
            problem = check_route(spec, maps, rules=False).problem
        except Exception as exc:  # a file no reader foresaw: the route cannot run, the run goes on checking
            problem = f"cannot be checked: {type(exc).__name__}: {exc}"
        if problem is not None:
            problems[spec.id] = problem if spec.id in problem else f"route {spec.id}: {problem}"
    return problems


def check_route_file(path: str | Path, town_dirs: Sequence[str] = ()) -> list[RouteCheck]:
    """One :class:`RouteCheck` per route of the file, in file order (unreadable routes included)."""
    specs, invalid = read_routes(path, strict=False)
    bad = {rid: message for rid, message in invalid}
    maps: dict[Path, RoadMap] = {}
    checked = {s.id: check_route(replace(s, town_dirs=s.town_dirs + tuple(town_dirs)), maps) for s in specs}
    out = [checked[s.id] for s in specs] + [RouteCheck(rid, msg) for rid, msg in bad.items()]
    return out


__all__ = [
    "TRIGGER_TOLERANCE",
    "RouteCheck",
    "build_placed",
    "check_route",
    "check_route_file",
    "place_scenarios",
    "route_problems",
]
