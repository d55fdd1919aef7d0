"""Rule-based language labels of a sample: the commentary and the communication sentence.

For every active CAV at a sample tick, from the expert's decision and the privileged snapshot:

* **commentary** ``"{route action}. {speed action}{reason}.{post comment}"``, e.g. ``"Stay on the route.
  Come to a stop for the red light."`` (templates and thresholds: ``docs/data.md``, "Language labels");
* **communication**: when the *critical object* is hidden from the CAV's own camera but seen by another
  CAV's camera, ``"CAV k can see the <object>, which is hidden from our camera."``; that CAV is the
  ``partner_label`` (the communication partner the model should name for the next step).

The critical object is, in this order: the object behind the expert's speed reason
(``decision.object_row``: the corridor leader, the walker, the obstacle or the predicted collision); the
actor the expert's path is shifted around or yields to (``decision.detour_row``, while the CAV has not
passed it: :func:`current_detour_rows`); else the first actor in the planned path's corridor (the 40 m kept
in the decision, half the CAV's width + ``CORRIDOR_MARGIN``).

Objects are named by kind, colour and rough direction in the CAV's frame. The snapshot carries no actor
type, so the type is the one of the actor's kind nearest in extent, and the colour is the paint the camera
gives it (``cmudrive.sensors._mesh.actor_paints``: a per-id car paint, the clothes of walkers and riders,
fixed colours of ambulances, police cars, cones and signs) -- the colour the model sees in its image, which
the actor types' ``colour`` (used by SUMO's GUI only) is not.

Vectorised over CAVs where it is cheap (speed bands, the path's lane matching, critical objects,
partners, walkers, object types and colours); the strings are put together per CAV. About 0.1 ms per CAV
with 16 CAVs, 0.3-0.6 ms with one or two (a fixed ~0.5 ms of small numpy calls).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from cmudrive.agents.corridor import first_in_corridor
from cmudrive.agents.expert import ExpertDecision, Reason
from cmudrive.agents.expert.detour import DetourReason
from cmudrive.maps import RoadMap
from cmudrive.maps.model import LaneKind
from cmudrive.sensors._mesh import actor_paints
from cmudrive.sensors.visibility import Visibility
from cmudrive.sim.actor_types import ACTOR_TYPES
from cmudrive.sim.snapshot import ActorKind, Snapshot

# thresholds
TURN_REACH = 20  # [m = path points] a junction entered this close ahead makes the route action a turn
TURN_ANGLE = np.radians(45.0)  # heading change through the junction that counts as a turn
U_TURN_ANGLE = np.radians(150.0)
LANE_CHANGE_REACH = 20  # [m = path points] a path on a neighbour lane this close ahead: lane change
PATH_LANE_DISTANCE = 3.0  # [m] path points farther from every lane centre are not matched to a lane
OBJECT_REACH = 40.0  # [m] an object farther than this (bumper gap) is not given as the reason
STOPPED = 0.2  # [m/s] slower counts as standing
SPEED_BAND = 0.5  # [m/s] target speed within this of the current speed: keep the speed
WALKER_REACH = 15.0  # [m] walkers this close (centre to centre) ...
WALKER_SPEED = 0.5  # [m/s] ... and faster than this add a caution
CORRIDOR_MARGIN = 0.5  # [m] added to half the CAV's width for the critical object in the planned path
CORRIDOR_REACH = 50.0  # [m]


@dataclass(frozen=True)
class LanguageInputs:
    """What one sample tick's labels are made from (``n`` active CAVs in ``decision.cav_index`` order)."""

    snap: Snapshot  # the sample tick's snapshot
    decision: ExpertDecision  # the expert's decision at that tick
    cav_rows: np.ndarray  # (n,) snapshot rows of those CAVs
    visibility: Visibility  # cameras in decision.cav_index order
    future_target_speed: np.ndarray  # (n, 5) [m/s] expert target speed at t+5, ..., t+25 (NaN once ended)
    num_cavs: int
    road_map: RoadMap


@dataclass(frozen=True)
class Language:
    """The language labels of one CAV at one sample tick."""

    commentary: str
    communication: str  # "" when none
    partner_label: int  # CAV index that can see the critical object, -1 none
    critical_row: int  # snapshot row of the critical object, -1 none
    route_action: str  # short codes for dataset statistics (ROUTE_TEXT, SPEED_TEXT keys)
    speed_action: str
    reason: str  # Reason name in lower case, "" when none is given


# ------------------------------------------------------------------ wording (our own)
ROUTE_TEXT = {
    "follow": "Stay on the route",
    "turn_left": "Turn left at the junction ahead",
    "turn_right": "Turn right at the junction ahead",
    "u_turn": "Make a U-turn at the junction ahead",
    "lane_left": "Move over to the lane on the left",
    "lane_right": "Move over to the lane on the right",
}
SPEED_TEXT = {
    "stopped": "Stay stopped",
    "stop": "Come to a stop",
    "keep": "Keep the current speed",
    "accelerate": "Speed up",
    "decelerate": "Slow down",
}
# noun of each actor type; people and riders are described by their clothes ("the cyclist in red")
TYPE_NOUN = {
    "cav": "car",
    "car": "car",
    "van": "van",
    "truck": "truck",
    "bus": "bus",
    "motorcycle": "motorcyclist",
    "bicycle": "cyclist",
    "pedestrian": "pedestrian",
    "ambulance": "ambulance",
    "police": "police car",
    "parked_car": "parked car",
    "cone": "traffic cone",
    "warning_sign": "warning sign",
    "car_door": "open car door",
    "advertisement": "advertising board",
    "vending_machine": "vending machine",
    "container": "container",
}
WEARS = frozenset({"motorcycle", "bicycle", "pedestrian"})
# named reference colours (RGB in [0, 1]); an actor gets the nearest name
COLOUR_NAMES = {
    "white": (0.92, 0.92, 0.92),
    "black": (0.08, 0.08, 0.09),
    "silver": (0.68, 0.70, 0.72),
    "grey": (0.42, 0.43, 0.45),
    "red": (0.75, 0.10, 0.10),
    "blue": (0.15, 0.28, 0.66),
    "dark blue": (0.07, 0.10, 0.28),
    "green": (0.18, 0.48, 0.26),
    "yellow": (0.92, 0.78, 0.15),
    "brown": (0.40, 0.25, 0.15),
    "orange": (0.93, 0.47, 0.10),
    "light blue": (0.45, 0.65, 0.85),
}
_COLOUR_RGB = np.array(list(COLOUR_NAMES.values()))
_COLOUR_LIST = list(COLOUR_NAMES)
_TYPE_NAMES = list(ACTOR_TYPES)
# ego-frame direction sectors: (upper bound of |bearing| [deg], text on the left, text on the right)
DIRECTIONS = ((20.0, "ahead", "ahead"), (70.0, "ahead on the left", "ahead on the right"))
DIRECTIONS_SIDE = (120.0, "on the left", "on the right")
OBJECT_REASONS = frozenset(
    {Reason.LEADING_VEHICLE, Reason.BICYCLE, Reason.PEDESTRIAN, Reason.OBSTACLE, Reason.FORECAST}
)


def describe(inputs: LanguageInputs) -> list[Language]:
    """The labels of every active CAV, in ``decision.cav_index`` order."""
    d, snap = inputs.decision, inputs.snap
    rows = np.asarray(inputs.cav_rows, np.int64)
    n = len(rows)
    if n == 0:
        return []
    speed = speed_actions(np.maximum(snap.speed[rows], 0.0), inputs.future_target_speed, d.target_speed)
    route = route_actions(inputs.road_map, d.path)
    detour_row = current_detour_rows(snap, d, rows)
    critical = critical_rows(snap, d, rows, detour_row)
    partner = partners(inputs.visibility, d.cav_index, critical, snap, rows, inputs.num_cavs)
    walker = nearest_walkers(snap, rows)
    names = _Names(snap, rows, np.concatenate([d.object_row, detour_row, critical, walker]))
    out = []
    for a in range(n):
        detour = _detour_action(names, a, int(d.detour_reason[a]), int(detour_row[a]))
        route_code, route_text = detour if detour else (str(route[a]), ROUTE_TEXT[str(route[a])])
        reason_code, reason_text = _reason(names, d, a, str(speed[a]))
        post = ""
        w = int(walker[a])
        if w >= 0 and not (int(d.object_row[a]) == w and reason_text):
            post = f" Watch out for {names.of(a, w)}."
        commentary = f"{route_text}. {SPEED_TEXT[str(speed[a])]}{reason_text}.{post}"
        k, c = int(partner[a]), int(critical[a])
        communication = (
            f"CAV {k} can see {names.of(a, c)}, which is hidden from our camera." if k >= 0 else ""
        )
        out.append(Language(commentary, communication, k, c, route_code, str(speed[a]), reason_code))
    return out


# ------------------------------------------------------------------ speed
def speed_actions(speed: np.ndarray, future_target: np.ndarray, target_now: np.ndarray) -> np.ndarray:
    """(n,) SPEED_TEXT key from the current speed (n,) [m/s] vs the mean expert target speed over the next
    samples (n, F) [m/s] (NaN once the CAV ended; all NaN: the current target speed ``target_now``).

    Both below STOPPED: stay stopped; the target below it: stop; standing with a target above it, or a
    target more than SPEED_BAND above the speed: accelerate; more than SPEED_BAND below: decelerate; else
    keep the speed."""
    future = np.asarray(future_target, np.float64)
    known = np.isfinite(future)
    count = known.sum(axis=1)
    mean = np.where(count > 0, np.where(known, future, 0.0).sum(axis=1) / np.maximum(count, 1), target_now)
    return np.select(
        [
            (mean < STOPPED) & (speed < STOPPED),
            mean < STOPPED,
            (mean > speed + SPEED_BAND) | (speed < STOPPED),  # standing and about to move: start
            mean < speed - SPEED_BAND,
        ],
        ["stopped", "stop", "accelerate", "decelerate"],
        "keep",
    )


# ------------------------------------------------------------------ route
@dataclass(frozen=True, eq=False)
class _Junctions:
    """What the route action needs of a map's junctions, computed once per map."""

    crossing: np.ndarray  # (J,) bool: more than two roads meet (not a bend or a one-to-one connection)
    entry_heading: np.ndarray  # (N,) [rad] internal lanes: heading at the end of their link's approach lane


@lru_cache(maxsize=4)
def _junctions(m: RoadMap) -> _Junctions:
    neighbours: list[set[int]] = [set() for _ in range(len(m.junction_ids))]
    for a, b in zip(m.edge_from_junction.tolist(), m.edge_to_junction.tolist(), strict=True):
        if a >= 0 and b >= 0 and a != b:
            neighbours[a].add(b)
            neighbours[b].add(a)
    crossing = np.array([len(nb) > 2 for nb in neighbours], bool)
    entry = np.full(m.num_lanes, np.nan)
    for src, via in zip(m.link_from.tolist(), m.link_via.tolist(), strict=True):
        if via < 0 or m.lane_internal[src]:
            continue
        line = m.polyline(src)
        d = line[-1] - line[-2]
        lane = via
        while lane >= 0 and m.lane_internal[lane] and np.isnan(entry[lane]):  # the link's internal chain
            entry[lane] = np.arctan2(d[1], d[0])
            nxt = [int(x) for x in m.successors(lane) if m.lane_internal[x]]
            lane = nxt[0] if nxt else -1
    return _Junctions(crossing, entry)


def route_actions(road_map: RoadMap, path: np.ndarray) -> np.ndarray:
    """(n,) ROUTE_TEXT key from the planned paths (n, H, 2) [m, 1 m apart, starting at the CAV].

    The path points are matched to the map's driving lanes (heading-filtered). A point on an internal lane
    of a junction where more than two roads meet, within ``TURN_REACH`` m, makes a turn when the path's
    heading changes by more than ``TURN_ANGLE`` through the junction: from 2 m before it (inside it: from
    the approach lane's end) to 2 m after it (or the path's end); left, right or, beyond
    ``U_TURN_ANGLE``, a U-turn. Else a point within ``LANE_CHANGE_REACH`` m on another lane of the CAV's
    edge is a lane change. The geometry, not the link's SUMO direction, decides the turn: at a junction's
    entry the internal lanes of all directions overlap and a single point cannot tell them apart. A bend
    modelled as a junction of two roads (imported towns) is followed, not turned."""
    path = np.asarray(path, np.float64)
    n, h = path.shape[:2]
    out = np.full(n, "follow", dtype=object)
    if h < 2:
        return out.astype(str)
    info = _junctions(road_map)
    reach = min(max(TURN_REACH, LANE_CHANGE_REACH) + 1, h)
    seg = np.diff(path, axis=1)  # (n, H-1, 2)
    heading = np.unwrap(np.arctan2(seg[..., 1], seg[..., 0]), axis=1)  # (n, H-1)
    heading = np.concatenate([heading, heading[:, -1:]], axis=1)  # (n, H)
    pts = path[:, :reach].reshape(-1, 2)
    proj = road_map.index.nearest_lane(
        pts, heading[:, :reach].reshape(-1), kinds=(LaneKind.DRIVING,), max_distance=PATH_LANE_DISTANCE
    )
    lane = proj.lane.reshape(n, reach).astype(np.int64)
    found = lane >= 0
    safe = np.maximum(lane, 0)
    junction = road_map.lane_junction[safe]
    internal = found & road_map.lane_internal[safe] & (junction >= 0)
    internal &= info.crossing[np.maximum(junction, 0)]
    for a in range(n):
        inside = np.flatnonzero(internal[a, : TURN_REACH + 1])
        if len(inside):
            first = int(inside[0])
            after = np.flatnonzero(~internal[a, first:] & found[a, first:])
            k1 = min(first + int(after[0]) + 2, h - 1) if len(after) else h - 1
            start = info.entry_heading[lane[a, 0]] if first == 0 else np.nan
            if np.isfinite(start):  # already in the junction: from where it entered
                turn = float(np.angle(np.exp(1j * (heading[a, k1] - start))))
            else:
                turn = float(heading[a, k1] - heading[a, max(first - 2, 0)])
            if abs(turn) > U_TURN_ANGLE:
                out[a] = "u_turn"
            elif abs(turn) > TURN_ANGLE:
                out[a] = "turn_left" if turn > 0.0 else "turn_right"
            continue
        if not found[a, 0]:
            continue
        here = int(lane[a, 0])
        edge, index = road_map.lane_edge[here], int(road_map.lane_index[here])
        ahead = lane[a, 1 : LANE_CHANGE_REACH + 1]
        ahead = ahead[(ahead >= 0) & (ahead != here)]
        same_edge = ahead[road_map.lane_edge[ahead] == edge]
        if len(same_edge):
            out[a] = "lane_left" if int(road_map.lane_index[same_edge[0]]) > index else "lane_right"
    return out.astype(str)


# ------------------------------------------------------------------ objects
def current_detour_rows(snap: Snapshot, d: ExpertDecision, rows: np.ndarray) -> np.ndarray:
    """(n,) ``decision.detour_row``, or -1 where the shift no longer goes around that actor: the CAV has
    passed it (its centre behind the CAV's rear bumper) while the shift is held to ramp back, or, for an
    invading vehicle, it does not come the other way (heading within 120 deg of the CAV's: crossing
    traffic the planner took for an invader where the route turns). An emergency vehicle, behind by
    nature, is kept."""
    r = np.asarray(d.detour_row, np.int64)
    rr = np.maximum(r, 0)
    c, s = np.cos(snap.yaw[rows]), np.sin(snap.yaw[rows])
    lon = (snap.x[rr] - snap.x[rows]) * c + (snap.y[rr] - snap.y[rows]) * s
    passed = lon < -0.5 * snap.length[rows]
    why = np.asarray(d.detour_reason)
    relative = np.abs(np.angle(np.exp(1j * (snap.yaw[rr] - snap.yaw[rows]))))
    not_oncoming = (why == DetourReason.INVADING) & (relative < np.radians(120.0))
    keep = (r >= 0) & ((~passed & ~not_oncoming) | (why == DetourReason.EMERGENCY))
    return np.where(keep, r, -1)


def critical_rows(snap: Snapshot, d: ExpertDecision, rows: np.ndarray, detour_row: np.ndarray) -> np.ndarray:
    """(n,) snapshot row of each CAV's critical object (see the module docstring), -1 none;
    ``detour_row`` from :func:`current_detour_rows`."""
    crit = np.where(d.object_row >= 0, d.object_row, detour_row).astype(np.int64)
    todo = np.flatnonzero(crit < 0)
    if len(todo) and len(d.path[0]) > 1:
        skip = snap.other_level(rows[todo])  # not a car on a bridge over the CAV's road
        skip[:, ~snap.valid] = True
        _, hit_row = first_in_corridor(
            np.ascontiguousarray(d.path[todo], np.float64),
            rows[todo],
            0.5 * snap.width[rows[todo]] + CORRIDOR_MARGIN,
            snap.x,
            snap.y,
            snap.yaw,
            snap.length,
            snap.width,
            skip,
            CORRIDOR_REACH,
        )
        crit[todo] = hit_row
    return crit


def partners(
    visibility: Visibility,
    cav_index: np.ndarray,
    critical: np.ndarray,
    snap: Snapshot,
    rows: np.ndarray,
    num_cavs: int,
) -> np.ndarray:
    """(n,) CAV index that sees each CAV's critical object when the CAV's own camera does not, -1 none.
    Several: the CAV whose centre is nearest to the object (ties: the lower index)."""
    n = len(rows)
    out = np.full(n, -1, np.int64)
    has = np.flatnonzero(critical >= 0)
    if len(has) == 0:
        return out
    cav_index = np.asarray(cav_index, np.int64)
    others = visibility.seen_by_others(cav_index, num_cavs)[has, critical[has]]  # (m, num_cavs)
    # only active CAVs have cameras; their distance to the object
    cav_xy = np.full((num_cavs, 2), np.inf)
    cav_xy[cav_index] = np.stack([snap.x[rows], snap.y[rows]], axis=1)
    obj = np.stack([snap.x[critical[has]], snap.y[critical[has]]], axis=1)  # (m, 2)
    dist = np.hypot(cav_xy[None, :, 0] - obj[:, None, 0], cav_xy[None, :, 1] - obj[:, None, 1])
    dist = np.where(others, dist, np.inf)
    best = np.argmin(dist, axis=1)  # the first minimum: the lower index on ties
    ok = np.isfinite(dist[np.arange(len(has)), best])
    out[has[ok]] = best[ok]
    return out


def nearest_walkers(snap: Snapshot, rows: np.ndarray) -> np.ndarray:
    """(n,) row of the nearest walker within WALKER_REACH m of each CAV, moving faster than WALKER_SPEED and
    not behind it (bearing within DIRECTIONS_SIDE's 120 deg of the heading), -1 none."""
    walkers = np.flatnonzero(
        snap.valid & (snap.kind == ActorKind.PEDESTRIAN) & (np.abs(snap.speed) > WALKER_SPEED)
    )
    out = np.full(len(rows), -1, np.int64)
    if len(walkers) == 0:
        return out
    dx = snap.x[walkers][None, :] - snap.x[rows][:, None]  # (n, W)
    dy = snap.y[walkers][None, :] - snap.y[rows][:, None]
    c, s = np.cos(snap.yaw[rows])[:, None], np.sin(snap.yaw[rows])[:, None]
    bearing = np.degrees(np.abs(np.arctan2(-dx * s + dy * c, dx * c + dy * s)))
    dist = np.where(bearing <= DIRECTIONS_SIDE[0], np.hypot(dx, dy), np.inf)  # not behind the CAV
    best = np.argmin(dist, axis=1)
    near = dist[np.arange(len(rows)), best] <= WALKER_REACH
    out[near] = walkers[best[near]]
    return out


def colour_names(rgb: np.ndarray) -> list[str]:
    """The nearest COLOUR_NAMES name of each (m, 3) RGB in [0, 1]."""
    rgb = np.asarray(rgb, np.float64).reshape(-1, 3)
    d2 = ((rgb[:, None, :] - _COLOUR_RGB[None, :, :]) ** 2).sum(axis=-1)
    return [_COLOUR_LIST[k] for k in np.argmin(d2, axis=1)]


def direction(dx: float, dy: float, yaw: float) -> str:
    """Rough direction of an offset (dx, dy) [m, map frame] seen from a vehicle heading ``yaw`` [rad]."""
    lon = dx * np.cos(yaw) + dy * np.sin(yaw)
    lat = -dx * np.sin(yaw) + dy * np.cos(yaw)
    bearing = float(np.degrees(np.arctan2(lat, lon)))
    for limit, left, right in (*DIRECTIONS, DIRECTIONS_SIDE):
        if abs(bearing) <= limit:
            return left if bearing > 0.0 else right
    return "behind"


class _Names:
    """Descriptions ("the red car ahead on the left") of snapshot rows as seen from each CAV, with the type
    and colour of each row looked up once."""

    def __init__(self, snap: Snapshot, rows: np.ndarray, named: np.ndarray) -> None:
        """``named``: every row that may be described (others are looked up on demand)."""
        self.snap, self.rows = snap, rows
        self._cache: dict[int, tuple[str, str]] = {}
        self._look_up(np.unique(named[named >= 0]))

    def _look_up(self, rows: np.ndarray) -> None:
        if len(rows) == 0:
            return
        tidx, paint, clothes = actor_paints(self.snap, rows)
        names = [_TYPE_NAMES[int(t)] for t in tidx]
        wears = np.array([name in WEARS for name in names])
        colours = colour_names(np.where(wears[:, None], clothes, paint))
        self._cache.update(zip(rows.tolist(), zip(names, colours, strict=True), strict=True))

    def type_name(self, row: int) -> str:
        return self._type_colour(row)[0]

    def _type_colour(self, row: int) -> tuple[str, str]:
        if row not in self._cache:
            self._look_up(np.array([row]))
        return self._cache[row]

    def thing(self, row: int) -> str:
        """'the red car', 'the pedestrian in blue' (no direction)."""
        name, colour = self._type_colour(row)
        noun = TYPE_NOUN.get(name, "object")
        return f"the {noun} in {colour}" if name in WEARS else f"the {colour} {noun}"

    def where(self, a: int, row: int) -> str:
        s, me = self.snap, int(self.rows[a])
        return direction(float(s.x[row] - s.x[me]), float(s.y[row] - s.y[me]), float(s.yaw[me]))

    def of(self, a: int, row: int) -> str:
        """The object at ``row`` with its direction from CAV ``a``."""
        return f"{self.thing(row)} {self.where(a, row)}"


def _detour_action(names: _Names, a: int, why: int, row: int) -> tuple[str, str] | None:
    """Route action code and text when the path is shifted around something (or waits to be)."""
    if why in (DetourReason.NONE, DetourReason.BLOCKED) or row < 0:
        return None
    s = names.snap
    if why == DetourReason.EMERGENCY:
        return "detour_emergency", f"Make way for {names.of(a, row)}"
    if why == DetourReason.INVADING:
        return "detour_invading", f"Keep to the right, away from {names.of(a, row)} over the centre line"
    name, where = names.type_name(row), names.where(a, row)
    if name in ("cone", "warning_sign"):
        code, text = "construction", f"Go around the construction zone {where}"
    elif name == "car_door":
        code, text = "door", f"Keep clear of the open car door {where}"
    elif s.kind[row] == ActorKind.EMERGENCY and not s.siren[row]:
        code, text = "accident", f"Go around the accident {where}"
    elif s.kind[row] == ActorKind.BICYCLE:
        code, text = "bicycles", f"Pass the cyclists at the side of the road {where}"
    elif (
        s.kind[row] in (ActorKind.CAR, ActorKind.VAN, ActorKind.TRUCK, ActorKind.BUS) or name == "parked_car"
    ):
        code, text = "parked", f"Go around {names.thing(row)} parked {where}"
    else:
        code, text = "obstacle", f"Go around {names.of(a, row)}"
    if why == DetourReason.ONCOMING_LANE:
        text += " through the oncoming lane"
    return f"detour_{code}", text


def _reason(names: _Names, d: ExpertDecision, a: int, speed: str) -> tuple[str, str]:
    """Reason code and the text appended to the speed action ('' when none is given)."""
    why = Reason(int(d.reason[a]))
    if why == Reason.NONE or speed == "accelerate":
        return "", ""
    row = int(d.object_row[a])
    code = why.name.lower()
    if speed == "keep":  # keeping the speed: only a vehicle followed is worth saying
        if why in (Reason.LEADING_VEHICLE, Reason.BICYCLE) and row >= 0 and d.distance[a] <= OBJECT_REACH:
            return code, f" behind {names.of(a, row)}"
        return "", ""
    fixed = {
        Reason.ROAD: " for the road ahead",
        Reason.RED_LIGHT: " for the red light",
        Reason.YELLOW_LIGHT: " for the yellow light",
        Reason.STOP_SIGN: " at the stop sign",
        Reason.YIELD: " to give way at the junction",
    }
    if why in fixed:
        return code, fixed[why]
    if why == Reason.DETOUR_WAIT:
        obstacle = int(d.detour_row[a])
        what = f" {names.thing(obstacle)}" if obstacle >= 0 else " the obstacle"
        return code, f" until the other lane is clear to pass{what}"
    if row < 0 or not d.distance[a] <= OBJECT_REACH:
        return "", ""
    if why == Reason.FORECAST:
        return code, f" to avoid a collision with {names.of(a, row)}"
    if why in (Reason.LEADING_VEHICLE, Reason.BICYCLE):
        return code, f" behind {names.of(a, row)}"
    return code, f" for {names.of(a, row)}"


__all__ = [
    "Language",
    "LanguageInputs",
    "critical_rows",
    "current_detour_rows",
    "describe",
    "partners",
    "route_actions",
    "speed_actions",
]
