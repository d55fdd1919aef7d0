"""Validate a route file without running it: ``cmudrive routes check FILE``.

Every route is read (the reader's rules: ids, CAV count and ids, ASCII numbers, coordinate and seed
ranges, weather, scenario types), its town looked up (beside the file, ``--town-dir``, committed towns),
and every CAV's waypoints planned into its dense route under the evaluator's bounds (10 m to 20 km, no
loops from back-and-forth waypoints). Scenario trigger points must lie on CAV 0's route. One bad route
does not hide the others: each gets its own line.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from cmudrive.bench.routes import RouteSpec, read_routes
from cmudrive.maps import MapError, RoadMap, RouteError, load_map

TRIGGER_TOLERANCE = 5.0  # [m] a scenario's trigger point may lie this far from CAV 0's dense route


@dataclass(frozen=True)
class RouteCheck:
    route_id: str
    problem: str | None  # None: the route can run
    num_cavs: int = 0
    lengths: tuple[float, ...] = ()  # [m] each CAV's dense route


def check_route(spec: RouteSpec, maps: dict[Path, RoadMap]) -> RouteCheck:
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
                f"route (at most {TRIGGER_TOLERANCE:.0f} m)",
                len(spec.cavs),
            )
    return RouteCheck(spec.id, None, len(spec.cavs), tuple(r.length for r in routes))


def check_route_file(path: str | Path, town_dirs: Sequence[str] = ()) -> list[RouteCheck]:
    """One :class:`RouteCheck` per route of the file, in file order (unreadable routes included)."""
    specs, invalid = read_routes(path, strict=False)
    bad = {rid: message for rid, message in invalid}
    maps: dict[Path, RoadMap] = {}
    checked = {s.id: check_route(replace(s, town_dirs=s.town_dirs + tuple(town_dirs)), maps) for s in specs}
    out = [checked[s.id] for s in specs] + [RouteCheck(rid, msg) for rid, msg in bad.items()]
    return out


__all__ = ["RouteCheck", "check_route", "check_route_file"]
