"""Road maps: SUMO networks as flat arrays, lane queries, route planning, towns and imports.

Typical use::

    from cmudrive.maps import load_map, RoutePlanner
    road_map = load_map("grid")                       # a committed town, or a path to a .net.xml
    proj = road_map.index.nearest_lane(points_xy)     # vectorised nearest lane + Frenet (s, d)
    route = RoutePlanner(road_map).plan(start_xy, goal_xy, start_heading=0.0)
    scenery = load_scenery(road_map)                  # buildings, poles, guardrails as oriented boxes
"""

from cmudrive.maps.cache import assets_dir, available_towns, load_map, load_scenery, resolve_map_path
from cmudrive.maps.elevation import LEVEL_CLEARANCE, actor_elevation, other_level
from cmudrive.maps.errors import MapError, NetconvertError, RouteError
from cmudrive.maps.index import LaneIndex, LaneProjection, wrap_angle
from cmudrive.maps.loader import read_sumo_net
from cmudrive.maps.model import JunctionKind, LaneKind, RoadMap, StopKind, TurnDir
from cmudrive.maps.routing import LanePos, RoadOption, Route, RoutePlanner, densify
from cmudrive.maps.scenery import SceneryKind, StaticScenery

__all__ = [
    "LEVEL_CLEARANCE",
    "JunctionKind",
    "LaneIndex",
    "LaneKind",
    "LanePos",
    "LaneProjection",
    "MapError",
    "NetconvertError",
    "RoadMap",
    "RoadOption",
    "Route",
    "RouteError",
    "RoutePlanner",
    "SceneryKind",
    "StaticScenery",
    "StopKind",
    "TurnDir",
    "actor_elevation",
    "assets_dir",
    "available_towns",
    "densify",
    "load_map",
    "load_scenery",
    "other_level",
    "read_sumo_net",
    "resolve_map_path",
    "wrap_angle",
]
