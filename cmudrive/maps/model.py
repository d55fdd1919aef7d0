"""The road map as flat numpy arrays: lanes, lane graph, junctions, right of way, traffic lights, stop lines.

A :class:`RoadMap` is built once from a SUMO network (``loader.read_sumo_net``) and cached as ``.npz``
(``cache.load_map``). Everything is an array over lanes, links, junctions, ... so that criteria, sensors
and the simulator can work vectorised; variable-length data (polylines, successor lists, polygons,
traffic-light phases) is stored in CSR form: ``*_ptr`` arrays of length ``n + 1`` index into a flat array,
so the items of row ``i`` are ``flat[ptr[i]:ptr[i + 1]]``.

Frame: SUMO's network frame (x east, y north, metres; right-handed, yaw counter-clockwise from +x in
radians). CARLA's world frame is the mirror image in y (see ``cmudrive.maps.coords``).

Glossary (SUMO terms): an *edge* is a road section in one direction holding parallel *lanes*, index 0 the
rightmost; a *junction* joins edges and contains *internal lanes* (the paths through it); a *link* (a SUMO
connection) leads from an incoming lane through one or more internal lanes to an outgoing lane and carries
the right-of-way state, the traffic-light signal index and the turn direction.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from enum import IntEnum
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from cmudrive.maps.index import LaneIndex

NO_INDEX = -1  # marks "none" in every integer index array


class LaneKind(IntEnum):
    """What a lane is for. Driving lanes are those that allow passenger cars."""

    DRIVING = 0
    SIDEWALK = 1  # pedestrians only
    BIKE = 2  # bicycles (and possibly pedestrians), no cars
    PARKING = 3  # lane type "parking": parked cars, not for through traffic
    SHOULDER = 4  # shoulder, emergency-only, or anything else not open to cars
    CROSSING = 5  # pedestrian crossing over a junction's road (SUMO edge function "crossing")
    WALKINGAREA = 6  # pedestrian area at a junction corner (its polyline is a closed polygon)


class JunctionKind(IntEnum):
    """Control of a junction, from SUMO's junction ``type``."""

    TRAFFIC_LIGHT = 0  # traffic_light, traffic_light_right_on_red, traffic_light_unregulated
    PRIORITY = 1  # priority road; minor roads yield
    ALLWAY_STOP = 2  # everyone stops, first come first served
    PRIORITY_STOP = 3  # minor roads stop, then yield
    RIGHT_BEFORE_LEFT = 4  # right_before_left and left_before_right
    DEAD_END = 5  # dead_end and fringe nodes
    OTHER = 6  # internal, zipper, rail crossings, district, unregulated, ...


SUMO_JUNCTION_KINDS: dict[str, JunctionKind] = {
    "traffic_light": JunctionKind.TRAFFIC_LIGHT,
    "traffic_light_right_on_red": JunctionKind.TRAFFIC_LIGHT,
    "traffic_light_unregulated": JunctionKind.TRAFFIC_LIGHT,
    "priority": JunctionKind.PRIORITY,
    "allway_stop": JunctionKind.ALLWAY_STOP,
    "priority_stop": JunctionKind.PRIORITY_STOP,
    "right_before_left": JunctionKind.RIGHT_BEFORE_LEFT,
    "left_before_right": JunctionKind.RIGHT_BEFORE_LEFT,
    "dead_end": JunctionKind.DEAD_END,
}


class TurnDir(IntEnum):
    """Turn direction of a link (SUMO connection ``dir``)."""

    STRAIGHT = 0  # "s"
    LEFT = 1  # "l"
    RIGHT = 2  # "r"
    PARTLY_LEFT = 3  # "L"
    PARTLY_RIGHT = 4  # "R"
    TURN = 5  # "t", a U-turn
    INVALID = 6  # "invalid" (pedestrian links)


# rank of each turn from right to left: the order in which the parts of a stop line are laid out from its
# right end (BEV) and traffic-light heads sit in a row (camera mesh), right turns rightmost
TURN_ORDER: dict[TurnDir, int] = {
    TurnDir.RIGHT: 0,
    TurnDir.PARTLY_RIGHT: 1,
    TurnDir.STRAIGHT: 2,
    TurnDir.PARTLY_LEFT: 3,
    TurnDir.LEFT: 4,
    TurnDir.TURN: 5,
    TurnDir.INVALID: 6,
}

SUMO_TURN_DIRS: dict[str, TurnDir] = {
    "s": TurnDir.STRAIGHT,
    "l": TurnDir.LEFT,
    "r": TurnDir.RIGHT,
    "L": TurnDir.PARTLY_LEFT,
    "R": TurnDir.PARTLY_RIGHT,
    "t": TurnDir.TURN,
}


class StopKind(IntEnum):
    """What a stop line belongs to."""

    TRAFFIC_LIGHT = 0
    STOP_SIGN = 1  # priority_stop minor approach (link state "s")
    ALLWAY_STOP = 2  # all-way stop approach (link state "w")


@dataclass(frozen=True, eq=False)
class RoadMap:
    """A road network as arrays. ``N`` lanes, ``P`` polyline points, ``L`` links, ``J`` junctions,
    ``T`` traffic lights, ``K`` stop lines, ``E`` edges. Index arrays use ``-1`` for "none"."""

    name: str  # town or file stem
    source_sha256: str  # content hash of the .net.xml this map was built from

    # --- edges (E) ---
    edge_ids: np.ndarray  # (E,) str
    edge_from_junction: np.ndarray  # (E,) int32, junction index
    edge_to_junction: np.ndarray  # (E,) int32

    # --- lanes (N) ---
    lane_ids: np.ndarray  # (N,) str, SUMO lane ids ("edge_index"; internal lanes start with ":")
    lane_kind: np.ndarray  # (N,) int8, LaneKind
    lane_edge: np.ndarray  # (N,) int32, index into edge_ids
    lane_index: np.ndarray  # (N,) int8, position in its edge, 0 = rightmost
    lane_internal: np.ndarray  # (N,) bool, inside a junction (SUMO internal lane, crossing, walking area)
    lane_junction: np.ndarray  # (N,) int32, the junction an internal lane belongs to, else -1
    lane_width: np.ndarray  # (N,) float64 [m]
    lane_speed: np.ndarray  # (N,) float64 speed limit [m/s]
    lane_length: np.ndarray  # (N,) float64 length of the polyline [m]
    lane_pt_ptr: np.ndarray  # (N+1,) int64, CSR into pt_xy / pt_s
    pt_xy: np.ndarray  # (P, 2) float64 centreline points [m]
    pt_s: np.ndarray  # (P,) float64 arc length of each point along its lane [m], 0 at the lane start
    pt_z: np.ndarray  # (P,) float64 elevation of each point [m] (0 where the network has no z)

    # --- lane graph ---
    succ_ptr: np.ndarray  # (N+1,) int64, CSR into succ_lane / succ_link
    succ_lane: np.ndarray  # (S,) int32 successor lane (an internal lane, or the outgoing lane)
    succ_link: np.ndarray  # (S,) int32 the link this step belongs to
    pred_ptr: np.ndarray  # (N+1,) int64, CSR into pred_lane
    pred_lane: np.ndarray  # (S,) int32
    lane_left: np.ndarray  # (N,) int32 same-direction neighbour on the left, else -1
    lane_right: np.ndarray  # (N,) int32 same-direction neighbour on the right, else -1
    lane_opposite: np.ndarray  # (N,) int32 opposite-direction lane directly to the left (two-way roads)

    # --- links (L): SUMO connections between lanes ---
    link_from: np.ndarray  # (L,) int32 incoming lane (normal or internal)
    link_to: np.ndarray  # (L,) int32 outgoing lane
    link_via: np.ndarray  # (L,) int32 first internal lane used, else -1
    link_dir: np.ndarray  # (L,) int8 TurnDir
    link_state: (
        np.ndarray
    )  # (L,) str1, SUMO right-of-way state: M major, m minor, s stop, w allway, = equal, ...
    link_junction: np.ndarray  # (L,) int32 junction index, -1 when unknown
    link_junction_index: np.ndarray  # (L,) int32 request index within the junction, -1 for internal links
    link_tls: np.ndarray  # (L,) int32 traffic light index, -1 when not signalised
    link_tls_index: np.ndarray  # (L,) int32 signal index in the light's state string, -1 when none
    # right of way, CSR over links: link i must yield to yield_link[yield_ptr[i]:yield_ptr[i+1]]
    yield_ptr: np.ndarray  # (L+1,) int64
    yield_link: np.ndarray  # (Y,) int32
    foe_ptr: np.ndarray  # (L+1,) int64, links whose paths conflict with link i
    foe_link: np.ndarray  # (F,) int32

    # --- junctions (J) ---
    junction_ids: np.ndarray  # (J,) str
    junction_kind: np.ndarray  # (J,) int8 JunctionKind
    junction_xy: np.ndarray  # (J, 2) float64 centre [m]
    junction_shape_ptr: np.ndarray  # (J+1,) int64, CSR into junction_shape_xy
    junction_shape_xy: np.ndarray  # (Q, 2) float64 outline polygon [m]
    junction_tls: np.ndarray  # (J,) int32 controlling traffic light, else -1

    # --- traffic lights (T) ---
    tls_ids: np.ndarray  # (T,) str
    tls_program: np.ndarray  # (T,) str program id (the one SUMO runs by default)
    tls_offset: np.ndarray  # (T,) float64 [s]
    tls_phase_ptr: np.ndarray  # (T+1,) int64, CSR into phase_*
    phase_duration: np.ndarray  # (H,) float64 [s]
    phase_state: np.ndarray  # (H,) str, one char per signal index (SUMO: r y g G s u o O)

    # --- stop lines (K): where vehicles stop for a light or a sign ---
    stop_lane: np.ndarray  # (K,) int32 incoming lane; the line lies at its end
    stop_kind: np.ndarray  # (K,) int8 StopKind
    stop_junction: np.ndarray  # (K,) int32
    stop_tls: np.ndarray  # (K,) int32 traffic light, -1 for signs
    stop_xy: np.ndarray  # (K, 2, 2) float64 the line's end points, right end first [m]

    # --- boundary ---
    bounds: np.ndarray  # (4,) float64 xmin, ymin, xmax, ymax [m]

    # ------------------------------------------------------------------ accessors
    @property
    def num_lanes(self) -> int:
        return int(self.lane_ids.shape[0])

    @cached_property
    def _lane_lookup(self) -> dict[str, int]:
        return {str(lane_id): i for i, lane_id in enumerate(self.lane_ids)}

    @cached_property
    def _junction_lookup(self) -> dict[str, int]:
        return {str(j): i for i, j in enumerate(self.junction_ids)}

    @cached_property
    def _tls_lookup(self) -> dict[str, int]:
        return {str(t): i for i, t in enumerate(self.tls_ids)}

    def lane(self, lane_id: str) -> int:
        """Index of a lane by its SUMO id (KeyError names the lane and the map)."""
        try:
            return self._lane_lookup[lane_id]
        except KeyError:
            raise KeyError(f"lane {lane_id!r} is not in map {self.name!r}") from None

    def junction(self, junction_id: str) -> int:
        try:
            return self._junction_lookup[junction_id]
        except KeyError:
            raise KeyError(f"junction {junction_id!r} is not in map {self.name!r}") from None

    def tls(self, tls_id: str) -> int:
        try:
            return self._tls_lookup[tls_id]
        except KeyError:
            raise KeyError(f"traffic light {tls_id!r} is not in map {self.name!r}") from None

    def polyline(self, lane: int) -> np.ndarray:
        """(n, 2) centreline of a lane [m]."""
        return self.pt_xy[self.lane_pt_ptr[lane] : self.lane_pt_ptr[lane + 1]]

    def polyline_s(self, lane: int) -> np.ndarray:
        """(n,) arc length of the centreline points of a lane [m]."""
        return self.pt_s[self.lane_pt_ptr[lane] : self.lane_pt_ptr[lane + 1]]

    @cached_property
    def has_elevation(self) -> bool:
        """Whether some lane leaves the ground plane (CARLA's Town03-05 bridges and ramps)."""
        return bool(np.any(np.abs(self.pt_z) > 0.5))

    def successors(self, lane: int) -> np.ndarray:
        return self.succ_lane[self.succ_ptr[lane] : self.succ_ptr[lane + 1]]

    def successor_links(self, lane: int) -> np.ndarray:
        return self.succ_link[self.succ_ptr[lane] : self.succ_ptr[lane + 1]]

    def predecessors(self, lane: int) -> np.ndarray:
        return self.pred_lane[self.pred_ptr[lane] : self.pred_ptr[lane + 1]]

    def junction_shape(self, junction: int) -> np.ndarray:
        return self.junction_shape_xy[
            self.junction_shape_ptr[junction] : self.junction_shape_ptr[junction + 1]
        ]

    def tls_phases(self, tls: int) -> tuple[np.ndarray, np.ndarray]:
        """(durations [s], state strings) of a traffic light's default program."""
        sl = slice(self.tls_phase_ptr[tls], self.tls_phase_ptr[tls + 1])
        return self.phase_duration[sl], self.phase_state[sl]

    def yields_to(self, link: int) -> np.ndarray:
        """Links that ``link`` must give way to (SUMO's junction ``response``)."""
        return self.yield_link[self.yield_ptr[link] : self.yield_ptr[link + 1]]

    def foes(self, link: int) -> np.ndarray:
        return self.foe_link[self.foe_ptr[link] : self.foe_ptr[link + 1]]

    @property
    def driving(self) -> np.ndarray:
        """(N,) bool mask of driving lanes (normal and internal)."""
        return self.lane_kind == LaneKind.DRIVING

    @cached_property
    def junction_is_join(self) -> np.ndarray:
        """(J,) bool: the junction only joins roads end to end, each driving edge into it going straight on
        onto exactly one edge out of it that no other edge enters (SUMO puts such a node where two
        OpenDRIVE roads meet, named ``A.B``, where a road gains or loses a lane, a turn pocket, and at a
        mid-block crosswalk; a corner where the road turns is not one). CARLA's map has no junction
        there, so the scenarios, which look for "the next junction" as upstream does, pass over them."""
        f, t = self.link_from, self.link_to
        ok = ~self.lane_internal[f] & ~self.lane_internal[t] & self.driving[f] & self.driving[t]
        ok &= self.link_junction >= 0
        out = np.ones(len(self.junction_kind), bool)
        pairs: dict[int, set[tuple[int, int]]] = {}
        for link in np.flatnonzero(ok).tolist():
            j = int(self.link_junction[link])
            pairs.setdefault(j, set()).add((int(self.lane_edge[f[link]]), int(self.lane_edge[t[link]])))
            if int(self.link_dir[link]) not in (TurnDir.STRAIGHT, TurnDir.PARTLY_LEFT, TurnDir.PARTLY_RIGHT):
                out[j] = False  # a U-turn, or a corner where the road turns: a junction to CARLA as well
        for j, pj in pairs.items():
            froms, tos = {a for a, _ in pj}, {b for _, b in pj}
            out[j] &= len(pj) == len(froms) == len(tos)
        return out

    @cached_property
    def index(self) -> LaneIndex:
        """Spatial index for nearest-lane and Frenet queries (built on first use, ~tens of ms)."""
        from cmudrive.maps.index import LaneIndex

        return LaneIndex(self)

    def summary(self) -> dict[str, float | int]:
        """Headline numbers of the map: lane kilometres by kind, junctions by control, lights, stops."""
        normal = ~self.lane_internal
        out: dict[str, float | int] = {}
        for kind in (LaneKind.DRIVING, LaneKind.SIDEWALK, LaneKind.BIKE, LaneKind.PARKING):
            sel = normal & (self.lane_kind == kind)
            out[f"{kind.name.lower()}_km"] = round(float(self.lane_length[sel].sum()) / 1000.0, 2)
        out["crossings"] = int(np.count_nonzero(self.lane_kind == LaneKind.CROSSING))
        for jk in (
            JunctionKind.TRAFFIC_LIGHT,
            JunctionKind.PRIORITY,
            JunctionKind.ALLWAY_STOP,
            JunctionKind.PRIORITY_STOP,
            JunctionKind.RIGHT_BEFORE_LEFT,
        ):
            out[f"junctions_{jk.name.lower()}"] = int(np.count_nonzero(self.junction_kind == jk))
        out["traffic_lights"] = len(self.tls_ids)
        out["stop_lines"] = len(self.stop_lane)
        return out

    # ------------------------------------------------------------------ serialisation
    def arrays(self) -> dict[str, np.ndarray]:
        """All array fields, for saving; the inverse is :meth:`from_arrays`."""
        out: dict[str, np.ndarray] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            out[f.name] = value if isinstance(value, np.ndarray) else np.asarray(value)
        return out

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> RoadMap:
        kwargs: dict[str, object] = {}
        for f in fields(cls):
            value = arrays[f.name]
            kwargs[f.name] = str(value) if f.name in ("name", "source_sha256") else value
        return cls(**kwargs)  # type: ignore[arg-type]
