"""Import single-ego Bench2Drive / CARLA Leaderboard 2.0 route files as our multi-CAV routes.

A Leaderboard 2.0 route holds one ego route (``<waypoints><position x y z/>``, CARLA world frame), a list
of ``<weathers>`` keyed by ``route_percentage`` and ``<scenarios>``. We keep the route id, the town, the
waypoints (as CAV 0) and the scenarios with their parameters as they are; the weather at the route start
(``route_percentage="0"``, else the first ``<weather>``) becomes the nearest of our presets through
``cmudrive.sim.weather.weather_from_carla``; with ``extra_cavs > 0``, ``add_cavs`` places CAVs 1..k by the
road topology. A route is skipped, with the reason, when its town is not a map we have, its waypoints,
weather or scenarios cannot be read, a scenario type is not one of the 44, or the extra CAVs do not fit.
Leaderboard 1.0 files (``<waypoint>`` elements directly under ``<route>``) are read the same way.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
import zlib
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from cmudrive.bench.authoring.route_gen import add_cavs
from cmudrive.bench.routes import (
    MAX_CAVS,
    CavSpec,
    RouteSpec,
    RouteSpecError,
    parse_xml,
    points_from_xml,
    route_id_problem,
    scenario_from_xml,
)
from cmudrive.maps import MapError, RoadMap, RouteError, available_towns, load_map
from cmudrive.maps.cache import NET_SUFFIX
from cmudrive.sim.weather import weather_from_carla

DEFAULT_WEATHER = "ClearNoon"  # a route without <weathers>: CARLA's default sky is a clear noon


@dataclass(frozen=True)
class ImportResult:
    """Routes converted, ``(route_id, reason)`` for every route left out, and ``(route_id, note)`` for what
    a kept route changed from its source (``interdrive.repair_keypoints``)."""

    routes: list[RouteSpec] = field(default_factory=list)
    skipped: list[tuple[str, str]] = field(default_factory=list)
    notes: list[tuple[str, str]] = field(default_factory=list)


def town_table(towns: Iterable[str] | None) -> dict[str, tuple[str, ...]]:
    """Town name as route files spell it -> the folders to look it up in before the committed towns (a
    network file ``nets/Town03.net.xml`` serves the routes of ``Town03``; they keep the name ``Town03``,
    so the written file can be moved: evaluate it with the network beside it or ``--town-dir nets``)."""
    table: dict[str, tuple[str, ...]] = {name: () for name in available_towns()}
    for town in towns or ():
        name = Path(town).name
        if name.endswith(NET_SUFFIX):
            table[name[: -len(NET_SUFFIX)]] = (str(Path(town).resolve().parent),)
        else:
            table[str(town)] = ()
    return table


def _start_weather(route: ET.Element) -> str:
    """Our preset for the route's first ``<weather>`` (route_percentage 0)."""
    weathers = route.findall("weathers/weather")
    if not weathers:
        return DEFAULT_WEATHER
    start = [w for w in weathers if _float(w.get("route_percentage", "0"), "route_percentage") == 0.0]
    elem = (start or weathers)[0]
    params = {k: _float(v, k) for k, v in elem.attrib.items()}
    try:
        return weather_from_carla(params).name
    except ValueError as exc:
        raise RouteSpecError(f"<weather>: {exc}") from None


def _float(raw: str, what: str) -> float:
    try:
        return float(raw)
    except ValueError:
        raise RouteSpecError(f"<weather>: non-numeric {what}={raw!r}") from None


def import_leaderboard_routes(
    path: str | Path, towns: Iterable[str] | None = None, extra_cavs: int = 0, seed: int = 0
) -> ImportResult:
    """Convert a Bench2Drive / Leaderboard 2.0 route file (see the module docstring).

    ``towns`` adds maps beyond the committed towns: a name (resolvable by ``load_map``) or a path to a
    ``.net.xml`` whose file name, less ``.net.xml``, is the CARLA town name (``nets/Town03.net.xml`` takes
    the routes of ``Town03``; they store that path as their town). Every route gets SUMO seed ``seed``;
    the extra CAVs of route ``rid`` are drawn from ``default_rng([seed, crc32(rid)])``, so a route's CAVs do
    not depend on the order of the file. A file that cannot be read at all raises RouteSpecError."""
    if not 0 <= extra_cavs <= MAX_CAVS - 1:
        raise ValueError(f"extra_cavs must be in 0..{MAX_CAVS - 1}, got {extra_cavs}")
    table = town_table(towns)
    root = parse_xml(path, "routes")
    result = ImportResult()
    maps: dict[str, RoadMap] = {}
    seen: set[str] = set()
    for k, elem in enumerate(root.findall("route"), start=1):
        raw_id = elem.get("id")
        rid = raw_id if raw_id and route_id_problem(raw_id) is None else f"#{k}"
        town = elem.get("town") or ""
        try:
            problem = route_id_problem(raw_id) if raw_id else None
            if problem:
                raise RouteSpecError(problem)
            if rid in seen:
                raise RouteSpecError("duplicate route id")
            seen.add(rid)
            if not town:
                raise RouteSpecError("missing town")
            if town not in table:
                raise RouteSpecError(f"town {town} is not available; available: {', '.join(sorted(table))}")
            block = elem.find("waypoints")
            points = points_from_xml(
                block.findall("position") if block is not None else elem.findall("waypoint"), cav_id=0
            )
            scenarios = tuple(
                scenario_from_xml(s, i) for i, s in enumerate(elem.findall("scenarios/scenario"))
            )
            spec = RouteSpec(
                rid, town, _start_weather(elem), seed, (CavSpec(0, points),), scenarios, town_dirs=table[town]
            )
            if extra_cavs:
                if spec.town not in maps:
                    maps[spec.town] = load_map(spec.town_path())
                rng = np.random.default_rng([seed, zlib.crc32(rid.encode())])
                spec = add_cavs(spec, 1 + extra_cavs, rng, road_map=maps[spec.town])
        except RouteSpecError as exc:
            result.skipped.append((rid, exc.detail))
            continue
        except (RouteError, MapError) as exc:
            result.skipped.append((rid, str(exc)))
            continue
        result.routes.append(spec)
    return result


__all__ = ["ImportResult", "import_leaderboard_routes", "town_table"]
