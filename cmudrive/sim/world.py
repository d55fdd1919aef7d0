"""The embedded world: SUMO traffic plus our CAVs, scenario actors and props, one tick at a time.

One tick (``World.tick(controls)``, dt = 0.05 s):

1. validate the CAV controls (NaN/inf -> :class:`ControlError` naming the CAV; out of range -> clipped);
2. integrate the CAVs with the kinematic bicycle model (friction from the weather);
3. push CAVs and kinematic scenario actors into SUMO (``moveToXY(keepRoute=0)`` + ``setSpeed``) so that
   SUMO traffic follows, yields to and overtakes them;
4. step SUMO (background traffic, pedestrians, lights);
5. background activity keeps traffic dense around the CAVs (every ``update_period`` ticks);
6. read the snapshot (CAVs first, then our layer's actors, then SUMO's) and check oriented-box
   collisions between all actors (pairs of two pedestrians excepted: SUMO's pedestrian model lets
   walkers brush past each other in crowds, which is not a driving event).

After a collision (documented policy): CAVs keep their kinematic state (there is no impulse model; the
criteria score the contact), and a SUMO vehicle or pedestrian that touched a CAV, a scenario actor or a
prop stops where it is, hazard lights on, for ``COLLISION_HOLD`` seconds, then drives on; this keeps
SUMO traffic from driving through what it hit.

The world owns one libsumo simulation; use it as a context manager (or call ``close``), one at a time.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from time import perf_counter
from typing import Protocol

import numba
import numpy as np

from cmudrive.maps import RoadMap, Route, actor_elevation, load_map, resolve_map_path
from cmudrive.sim.actor_types import ACTOR_TYPES, actor_type
from cmudrive.sim.background_commands import BackgroundCommands
from cmudrive.sim.collisions import CollisionEvents, detect_collisions
from cmudrive.sim.dynamics import CavState, Controls, VehicleParams, step_bicycle, validate_controls
from cmudrive.sim.snapshot import SIGNAL_BLINKER_EMERGENCY, SIGNAL_BRAKELIGHT, ActorKind, Role, Snapshot
from cmudrive.sim.sumo import SUMO_STEP, SumoArrays, SumoSession, remove_from_sumo, start_sumo
from cmudrive.sim.traffic_lights import TrafficLights
from cmudrive.sim.weather import Weather, get_weather

TICK_PHASES = ("cavs", "sumo_step", "background", "snapshot", "collisions")  # World.timing keys [s]
OFF_ROAD_RETURN = 3.0  # [m] a CAV out of SUMO (it was off the road) re-enters this close to a driving lane
COLLISION_HOLD = 5.0  # [s] a SUMO actor that hit something waits this long before driving on
MAX_YAW_TO_LANE = np.radians(15.0)  # [rad] a SUMO vehicle on a normal lane points at most this far off it
BRAKE_LIGHT_THRESHOLD = 0.05  # brake input above which a CAV shows brake lights
_PEDESTRIAN = int(ActorKind.PEDESTRIAN)  # plain ints in the per-tick code: enum attribute lookups are slow
_BACKGROUND = int(Role.BACKGROUND)
_BRAKELIGHT = np.int32(SIGNAL_BRAKELIGHT)


class Background(BackgroundCommands, Protocol):
    """A world's background activity as the world sees it: :meth:`World.tick` calls ``update`` after every
    SUMO step, and scenarios give it commands. :class:`~cmudrive.sim.background.BackgroundActivity` is one;
    this protocol is what keeps ``world`` from importing ``background`` (which reads the world)."""

    def update(self, world: World) -> None: ...


@dataclass(frozen=True)
class WorldConfig:
    """What a world is built from. ``town`` is a committed town name or a .net.xml path."""

    town: str | Path
    seed: int = 0
    weather: str = "ClearNoon"
    cav_params: VehicleParams = field(default_factory=VehicleParams)
    log_file: Path | None = None  # SUMO's warnings go here when set


@dataclass
class LayerActors:
    """Actors our layer moves (scenario kinematic actors and props), arrays over ``n`` actors."""

    ids: list[str] = field(default_factory=list)
    type_names: list[str] = field(default_factory=list)
    role: list[int] = field(default_factory=list)
    in_sumo: list[bool] = field(default_factory=list)
    x: np.ndarray = field(default_factory=lambda: np.zeros(0))
    y: np.ndarray = field(default_factory=lambda: np.zeros(0))
    yaw: np.ndarray = field(default_factory=lambda: np.zeros(0))
    speed: np.ndarray = field(default_factory=lambda: np.zeros(0))


@dataclass(frozen=True)
class _FixedColumns:
    """Snapshot columns that only change when actors come or go; see ``World._fixed_columns``."""

    key: tuple[bytes, tuple[str, ...], tuple[str, ...], tuple[int, ...], int]
    # active CAVs, layer actor ids, types and roles, SumoArrays.columns_version
    ids: np.ndarray
    kind: np.ndarray
    role: np.ndarray
    length: np.ndarray
    width: np.ndarray
    valid: np.ndarray
    sumo_row: dict[str, int]  # SUMO actor id -> its row among SUMO's actors


@numba.njit(cache=True)
def _turn_towards_lane(
    x: np.ndarray,
    y: np.ndarray,
    yaw: np.ndarray,
    length: np.ndarray,
    lane: np.ndarray,
    lane_pos: np.ndarray,
    kind: np.ndarray,
    lane_internal: np.ndarray,
    lane_pt_ptr: np.ndarray,
    lane_length: np.ndarray,
    key_offset: np.ndarray,
    key: np.ndarray,
    seg_heading: np.ndarray,
    max_off: float,
) -> None:
    """In place: turn the boxes of vehicles (not pedestrians) on normal (non-internal) lanes about their
    front-bumper centre until they point at most ``max_off`` [rad] off their lane's heading at
    ``lane_pos``; yaw wrapped to [-pi, pi). The lane's segment at ``lane_pos`` is found as in
    ``LaneIndex.heading_at`` (``key``, ``key_offset`` and ``seg_heading`` are the index's)."""
    for i in range(x.shape[0]):
        on = lane[i]
        if on < 0 or kind[i] == _PEDESTRIAN or lane_internal[on]:
            continue
        q = key_offset[on] + min(max(lane_pos[i], 0.0), lane_length[on])
        seg = np.searchsorted(key, q, side="right") - 1
        seg = min(max(seg, lane_pt_ptr[on]), lane_pt_ptr[on + 1] - 2)
        heading = seg_heading[seg]
        half_len = 0.5 * length[i]
        deviation = (yaw[i] - heading + np.pi) % (2.0 * np.pi) - np.pi
        bounded = heading + min(max(deviation, -max_off), max_off)
        front_x = x[i] + half_len * np.cos(yaw[i])
        front_y = y[i] + half_len * np.sin(yaw[i])
        x[i] = front_x - half_len * np.cos(bounded)
        y[i] = front_y - half_len * np.sin(bounded)
        yaw[i] = (bounded + np.pi) % (2.0 * np.pi) - np.pi


class World:
    """SUMO world + CAVs. Add CAVs (``add_cav``) before the first ``tick``."""

    def __init__(self, config: WorldConfig, road_map: RoadMap | None = None) -> None:
        self.config = config
        self.map = road_map if road_map is not None else load_map(config.town)
        self.weather: Weather = get_weather(config.weather)
        self.dt = SUMO_STEP
        self.rng = np.random.default_rng(config.seed)
        self.sumo: SumoSession = start_sumo(
            resolve_map_path(config.town), config.seed, self.weather.friction, config.log_file
        )
        try:
            self.lights = TrafficLights(self.map)
            self.lights.cap_green()
        except Exception:
            self.sumo.close()
            raise
        self.step_count = 0
        self.cav_ids: list[str] = []
        self.cav_active = np.zeros(0, bool)
        self.cav_state = CavState(*(np.zeros(0) for _ in range(6)))
        self.cav_clipped = np.zeros(0, np.int64)  # per CAV: ticks with clipped controls
        self._cav_brake = np.zeros(0)
        self._cav_off_road = np.zeros(0, bool)  # no driving lane within MATCH_RADIUS at the last push
        self._cav_in_sumo: set[str] = set()
        self._cav_left_sumo: set[int] = set()  # CAVs taken out of SUMO because they were off the road
        self._cav_edges: dict[str, list[str]] = {}
        self.layer = LayerActors()
        self.collisions: CollisionEvents = detect_collisions(self._empty_snapshot())
        self._held: dict[str, tuple[float, float]] = {}  # SUMO actor -> (hold ends [s], speed to restore)
        self.background: Background | None = None  # keeps traffic around the CAVs when set
        self.last_snapshot: Snapshot | None = None
        self._fixed: _FixedColumns | None = None  # see _fixed_columns
        # wall-clock seconds spent per tick phase, summed over ticks (and the tick count): for profiling
        self.timing: dict[str, float] = dict.fromkeys((*TICK_PHASES, "ticks"), 0.0)

    # ------------------------------------------------------------------ lifecycle
    def __enter__(self) -> World:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self.sumo.close()

    @property
    def time(self) -> float:
        return self.step_count * self.dt

    # ------------------------------------------------------------------ CAVs
    def add_cav(self, route: Route, speed: float = 0.0) -> str:
        """Place a new CAV at the start of ``route`` (its pose and heading), at ``speed`` [m/s]."""
        cav_id = f"cav{len(self.cav_ids)}"
        edges = self._route_edges(route)
        x0, y0 = route.xy[0]
        st = self.cav_state
        self.cav_state = CavState(
            x=np.append(st.x, x0),
            y=np.append(st.y, y0),
            yaw=np.append(st.yaw, route.heading[0]),
            speed=np.append(st.speed, speed),
            steer_angle=np.append(st.steer_angle, 0.0),
            accel=np.append(st.accel, 0.0),
        )
        self.cav_ids.append(cav_id)
        self.cav_active = np.append(self.cav_active, True)
        self.cav_clipped = np.append(self.cav_clipped, 0)
        self._cav_brake = np.append(self._cav_brake, 0.0)
        self._cav_off_road = np.append(self._cav_off_road, False)
        self._cav_edges[cav_id] = edges
        self._insert_cav(len(self.cav_ids) - 1)
        return cav_id

    def remove_cav(self, index: int) -> None:
        """The CAV leaves the world (finished or failed); its last state is kept, inactive."""
        if not self.cav_active[index]:
            return
        self.cav_active[index] = False
        cav_id = self.cav_ids[index]
        self._cav_left_sumo.discard(index)
        if cav_id in self._cav_in_sumo:
            remove_from_sumo(cav_id)
            self._cav_in_sumo.discard(cav_id)

    def _route_edges(self, route: Route) -> list[str]:
        """The SUMO edges of a route, from its planned lane path (its 1 m points can skip short edges); a
        route inside one junction (InterDrive's shortest) gets the edge its last lane leads to."""
        path = list(route.path)
        while all(self.map.lane_internal[path]) and len(self.map.successors(path[-1])) and len(path) < 64:
            path.append(int(self.map.successors(path[-1])[0]))
        names = self.map.edge_ids[self.map.lane_edge[path]]
        edges: list[str] = []
        for name in names.tolist():
            if not name.startswith(":") and (not edges or edges[-1] != name):
                edges.append(name)
        return edges

    def _insert_cav(self, i: int) -> None:
        """(Re-)insert CAV ``i`` into SUMO at its current pose."""
        import libsumo

        cav_id = self.cav_ids[i]
        edges = self._cav_edges[cav_id]
        st = self.cav_state
        proj = self.map.index.nearest_lane(np.array([[st.x[i], st.y[i]]]), heading=st.yaw[i])
        lane = int(proj.lane[0])
        if lane >= 0 and not self.map.lane_internal[lane]:
            here = str(self.map.edge_ids[self.map.lane_edge[lane]])
            if here in edges:
                edges = edges[edges.index(here) :]
            else:
                edges = [here]
        route_id = f"route:{cav_id}:{self.step_count}"
        libsumo.route.add(route_id, edges)
        libsumo.vehicle.add(cav_id, route_id, typeID="cav", depart="now", departSpeed="0")
        libsumo.vehicle.setSpeedMode(cav_id, 0)
        libsumo.vehicle.setLaneChangeMode(cav_id, 0)
        self._cav_in_sumo.add(cav_id)
        self._push_cavs(np.array([i]))

    def _push_cavs(self, rows: np.ndarray) -> None:
        """Push the CAVs at ``rows`` (sorted indices) into SUMO.

        A CAV off the road (no lane of its class within MATCH_RADIUS) leaves SUMO, and comes back once a
        driving lane of our map is within OFF_ROAD_RETURN of it. SUMO can only put such a CAV on the
        nearest lane, up to 100 m away with its lateral offset clamped: a phantom that blocks SUMO
        traffic where the CAV is not, and with the sublane model a state that libsumo 1.28 can crash on
        many steps later (a segfault in its lane changer once a bicycle came up behind a CAV that had
        stood 6 m off its lane for minutes on a Town03 shoulder; the same SUMO state with the CAV
        removed and added again ran on; docs/simulator.md). Our collision check sees the CAV wherever
        it is, so SUMO traffic that hits it off the road is still a collision."""
        if self._cav_left_sumo:  # rare: nothing to look at in the common tick
            rows = self._return_to_sumo(rows)
        st = self.cav_state
        pick: slice | np.ndarray
        ids, pick = self.cav_ids, slice(None)  # every CAV (the common case): views, no copies
        if len(rows) != len(self.cav_ids):
            ids, pick = [self.cav_ids[i] for i in rows], rows
        if not ids:
            return
        length = np.full(len(ids), ACTOR_TYPES["cav"].length)
        off_road = self.sumo.move_vehicles(ids, st.x[pick], st.y[pick], st.yaw[pick], st.speed[pick], length)
        self._cav_off_road[pick] = off_road
        for k in np.flatnonzero(off_road).tolist():
            remove_from_sumo(ids[k])
            self._cav_in_sumo.discard(ids[k])
            self._cav_left_sumo.add(k if isinstance(pick, slice) else int(rows[k]))

    def _return_to_sumo(self, rows: np.ndarray) -> np.ndarray:
        """Re-insert the CAVs at ``rows`` that are out of SUMO and back near a driving lane; returns the
        rows still to push (in SUMO, not just inserted: an insertion pushes its CAV)."""
        out = np.isin(rows, list(self._cav_left_sumo))
        st = self.cav_state
        back = (
            self.map.index.nearest_lane(
                np.stack([st.x[rows[out]], st.y[rows[out]]], axis=1), max_distance=OFF_ROAD_RETURN
            ).lane
            >= 0
        )
        for i in rows[out][back].tolist():
            self._cav_left_sumo.discard(i)
            self._insert_cav(i)
        return rows[~out]

    # ------------------------------------------------------------------ scenario actors and props
    def add_layer_actor(
        self,
        actor_id: str,
        type_name: str,
        x: float,
        y: float,
        yaw: float,
        speed: float = 0.0,
        role: Role = Role.SCENARIO,
    ) -> None:
        """An actor our layer moves (``set_layer_pose``); pushed into SUMO when it stands on a driving lane,
        so that traffic stops behind or drives around it (props: stopped vehicles SUMO overtakes)."""
        t = actor_type(type_name)
        on_road = bool(self.map.index.on_driving_lane(np.array([[x, y]]))[0])
        in_sumo = on_road and t.kind not in (ActorKind.PEDESTRIAN,)
        L = self.layer
        L.ids.append(actor_id)
        L.type_names.append(type_name)
        L.role.append(int(role))
        L.in_sumo.append(in_sumo)
        L.x, L.y = np.append(L.x, x), np.append(L.y, y)
        L.yaw, L.speed = np.append(L.yaw, yaw), np.append(L.speed, speed)
        if in_sumo:
            import libsumo

            proj = self.map.index.nearest_lane(np.array([[x, y]]), heading=yaw)
            edge = str(self.map.edge_ids[self.map.lane_edge[max(int(proj.lane[0]), 0)]])
            libsumo.route.add(f"route:{actor_id}", [edge])
            sumo_type = type_name
            if not _allowed(edge, t.vclass):  # a scenario bicycle on a car-only road
                sumo_type = _ignoring_type(type_name)
            libsumo.vehicle.add(
                actor_id, f"route:{actor_id}", typeID=sumo_type, depart="now", departSpeed="0"
            )
            libsumo.vehicle.setSpeedMode(actor_id, 0)
            libsumo.vehicle.setLaneChangeMode(actor_id, 0)
            self.sumo.move_vehicles(
                [actor_id],
                np.array([x]),
                np.array([y]),
                np.array([yaw]),
                np.array([speed]),
                np.array([t.length]),
            )

    def set_layer_pose(self, actor_id: str, x: float, y: float, yaw: float, speed: float) -> None:
        i = self.layer.ids.index(actor_id)
        self.layer.x[i], self.layer.y[i], self.layer.yaw[i], self.layer.speed[i] = x, y, yaw, speed

    def remove_layer_actor(self, actor_id: str) -> None:
        L = self.layer
        i = L.ids.index(actor_id)
        if L.in_sumo[i]:
            remove_from_sumo(actor_id)
        keep = np.arange(len(L.ids)) != i
        for name in ("ids", "type_names", "role", "in_sumo"):
            values = getattr(L, name)
            setattr(L, name, [v for v, k in zip(values, keep, strict=True) if k])
        L.x, L.y, L.yaw, L.speed = L.x[keep], L.y[keep], L.yaw[keep], L.speed[keep]

    # ------------------------------------------------------------------ the tick
    def tick(self, controls: Controls) -> Snapshot:
        """Advance the world by one step with controls for the *active* CAVs, in CAV order."""
        clock = self.timing
        t0 = perf_counter()
        active = np.flatnonzero(self.cav_active)
        every = len(active) == len(self.cav_ids)  # the common case: slices, no copies
        check = validate_controls(controls, self.cav_ids if every else [self.cav_ids[i] for i in active])
        self.cav_clipped[slice(None) if every else active] += check.clipped
        self._advance_cavs(active, check.controls)
        self._push_layer()
        self.lights.update()
        t1 = perf_counter()
        arrived = self.sumo.step()
        if not arrived.isdisjoint(self._cav_in_sumo):
            self._reinsert_arrived_cavs(active, arrived)
        self.step_count += 1
        t2 = perf_counter()
        if self.background is not None:
            self.background.update(self)
        self._release_holds()
        t3 = perf_counter()
        snap = self.snapshot()
        t4 = perf_counter()
        events = detect_collisions(snap)
        if len(events):
            # pedestrians brushing past each other in a crowd are not a driving event
            keep = (events.kind_a != _PEDESTRIAN) | (events.kind_b != _PEDESTRIAN)
            if not keep.all():
                events = events.select(keep)
            self.collisions = events
            self._hold_sumo_actors_after_collisions(snap)
        else:
            self.collisions = events
        self.last_snapshot = snap
        t5 = perf_counter()
        for phase, dt in zip(TICK_PHASES, (t1 - t0, t2 - t1, t3 - t2, t4 - t3, t5 - t4), strict=True):
            clock[phase] += dt
        clock["ticks"] += 1
        return snap

    def _advance_cavs(self, active: np.ndarray, controls: Controls) -> None:
        if len(active) == 0:
            return
        st = self.cav_state
        params, friction = self.config.cav_params, self.weather.friction
        if len(active) == len(self.cav_ids):  # the common case: no copies of the state
            self.cav_state = step_bicycle(st, controls, params, self.dt, friction)
            self._cav_brake[:] = controls.brake
        else:
            sub = CavState(*(getattr(st, f)[active] for f in CavState.__dataclass_fields__))
            new = step_bicycle(sub, controls, params, self.dt, friction)
            for f in CavState.__dataclass_fields__:
                getattr(st, f)[active] = getattr(new, f)
            self._cav_brake[active] = controls.brake
        self._push_cavs(active)

    def _push_layer(self) -> None:
        L = self.layer
        rows = [i for i, flag in enumerate(L.in_sumo) if flag]
        if rows:
            length = np.array([ACTOR_TYPES[L.type_names[i]].length for i in rows])
            self.sumo.move_vehicles(
                [L.ids[i] for i in rows], L.x[rows], L.y[rows], L.yaw[rows], L.speed[rows], length
            )

    def _reinsert_arrived_cavs(self, active: np.ndarray, arrived: set[str]) -> None:
        """SUMO removes a vehicle at the end of its route; a CAV lives on until the evaluator ends it."""
        for i in active.tolist():
            if self.cav_ids[i] in arrived:
                self._cav_in_sumo.discard(self.cav_ids[i])
                self._insert_cav(i)

    # ------------------------------------------------------------------ snapshot
    def snapshot(self) -> Snapshot:
        """Every actor now: active CAVs, then our layer's actors, then SUMO's, in insertion order."""
        m = self.map
        st = self.cav_state
        cav = np.flatnonzero(self.cav_active)
        every = len(cav) == len(self.cav_ids)  # the common case: views and the id list, no copies
        cav_ids = self.cav_ids if every else [self.cav_ids[i] for i in cav]
        rows = slice(None) if every else cav
        L = self.layer
        layer_lane = (
            m.index.nearest_lane(np.stack([L.x, L.y], axis=1), max_distance=2.0).lane
            if L.ids
            else np.zeros(0, np.int32)
        )
        sumo = self.sumo.read(m._lane_lookup, extra=cav_ids)
        self._straighten(sumo)
        # a CAV's lane is where SUMO mapped it (heading-aware, within MATCH_RADIUS); off the road: -1
        cav_lane = np.where(self._cav_off_road[rows], np.int32(-1), sumo.extra_lane)
        fixed = self._fixed_columns(cav, cav_ids, sumo)
        n_c, n_l = len(cav), len(L.ids)
        x = np.concatenate([st.x[rows], L.x, sumo.x])
        y = np.concatenate([st.y[rows], L.y, sumo.y])
        lane = np.concatenate([cav_lane, layer_lane, sumo.lane]).astype(np.int32, copy=False)
        cav_signals = np.where(self._cav_brake[rows] > BRAKE_LIGHT_THRESHOLD, _BRAKELIGHT, np.int32(0))
        signals = np.concatenate([cav_signals, np.zeros(n_l, np.int32), sumo.signals])
        if self._held:  # SUMO actors waiting after a collision show hazard lights
            row = fixed.sumo_row
            held = [n_c + n_l + row[a] for a in self._held if a in row]
            signals[held] |= SIGNAL_BLINKER_EMERGENCY
        return Snapshot(
            step=self.step_count,
            time=self.time,
            ids=fixed.ids,
            kind=fixed.kind,
            role=fixed.role,
            x=x,
            y=y,
            yaw=np.concatenate([st.yaw[rows], L.yaw, sumo.yaw]),
            speed=np.concatenate([st.speed[rows], L.speed, sumo.speed]),
            accel=np.concatenate([st.accel[rows], np.zeros(n_l), sumo.accel]),
            length=fixed.length,
            width=fixed.width,
            lane=lane,
            z=actor_elevation(m, lane, x, y),
            signals=signals,
            valid=fixed.valid,
            tls_state=self.lights.read(),
        )

    def _fixed_columns(self, cav: np.ndarray, cav_ids: list[str], sumo: SumoArrays) -> _FixedColumns:
        """The snapshot columns that change only when actors come or go (ids, kind, role, extents,
        validity): rebuilt then, shared read-only by the snapshots in between."""
        L = self.layer
        key = (cav.tobytes(), tuple(L.ids), tuple(L.type_names), tuple(L.role), sumo.columns_version)
        if self._fixed is not None and self._fixed.key == key:
            return self._fixed
        cav_type = ACTOR_TYPES["cav"]
        layer_types = [ACTOR_TYPES[n] for n in L.type_names]
        n_c = len(cav)
        columns = {
            "ids": np.array(cav_ids + L.ids + sumo.ids, dtype=str),
            "kind": np.concatenate(
                [np.full(n_c, cav_type.kind), [t.kind for t in layer_types], sumo.kind]
            ).astype(np.int8),
            "role": np.concatenate([np.full(n_c, Role.CAV), L.role, sumo.role]).astype(np.int8),
            "length": np.concatenate(
                [np.full(n_c, cav_type.length), [t.length for t in layer_types], sumo.length]
            ).astype(np.float64),
            "width": np.concatenate(
                [np.full(n_c, cav_type.width), [t.width for t in layer_types], sumo.width]
            ).astype(np.float64),
        }
        columns["valid"] = np.ones(len(columns["ids"]), bool)
        for array in columns.values():
            array.flags.writeable = False
        sumo_row = {a: i for i, a in enumerate(sumo.ids)}
        self._fixed = _FixedColumns(key=key, sumo_row=sumo_row, **columns)
        return self._fixed

    def _straighten(self, sumo: SumoArrays) -> None:
        """In place: SUMO's vehicles on normal lanes point at most MAX_YAW_TO_LANE off the lane direction.
        SUMO's sublane model reports a vehicle's angle including its last lateral move, which leaves a
        vehicle that stopped mid-manoeuvre at up to ~35 degrees to its lane (its box overlapping its
        neighbours'); the box turns about the front bumper, SUMO's own reference point."""
        m, index = self.map, self.map.index
        _turn_towards_lane(
            sumo.x,
            sumo.y,
            sumo.yaw,
            sumo.length,
            sumo.lane,
            sumo.lane_pos,
            sumo.kind,
            m.lane_internal,
            m.lane_pt_ptr,
            m.lane_length,
            index._key_offset,
            index._key,
            index.seg_heading,
            MAX_YAW_TO_LANE,
        )

    def _empty_snapshot(self) -> Snapshot:
        return Snapshot.from_rows(0, 0.0, np.zeros(0, dtype=str), x=np.zeros(0), y=np.zeros(0))

    # ------------------------------------------------------------------ collision aftermath
    def is_held(self, actor_id: str) -> bool:
        """``actor_id`` is a SUMO actor waiting out its ``COLLISION_HOLD`` after a collision."""
        return actor_id in self._held

    def _hold_sumo_actors_after_collisions(self, snap: Snapshot) -> None:
        import libsumo

        ev = self.collisions
        for a, b in zip(ev.a.tolist(), ev.b.tolist(), strict=True):
            for me, other in ((a, b), (b, a)):
                actor = str(snap.ids[me])
                info = self.sumo.actors.get(actor)
                if info is None or snap.role[other] == _BACKGROUND or actor in self._held:
                    continue
                if info.is_person:  # a person's "speed" is its walking speed: keep it to restore it
                    self._held[actor] = (self.time + COLLISION_HOLD, libsumo.person.getMaxSpeed(actor))
                    libsumo.person.setSpeed(actor, 0.0)
                else:
                    self._held[actor] = (self.time + COLLISION_HOLD, -1.0)  # -1: SUMO's car-following
                    libsumo.vehicle.setSpeed(actor, 0.0)

    def _release_holds(self) -> None:
        import libsumo

        for actor, (until, speed) in list(self._held.items()):
            if self.time < until:
                continue
            del self._held[actor]
            info = self.sumo.actors.get(actor)
            if info is None:
                continue
            (libsumo.person if info.is_person else libsumo.vehicle).setSpeed(actor, speed)


def _allowed(edge: str, vclass: str) -> bool:
    """Some lane of ``edge`` lets ``vclass`` drive on it."""
    import libsumo

    lanes = libsumo.edge.getLaneNumber(edge)
    for k in range(lanes):
        lane = f"{edge}_{k}"
        allowed = libsumo.lane.getAllowed(lane)
        disallowed = libsumo.lane.getDisallowed(lane)
        if (not allowed or vclass in allowed) and vclass not in disallowed:
            return True
    return False


def _ignoring_type(type_name: str) -> str:
    """A copy of a vehicle type with SUMO's vClass "ignoring" (allowed on every lane), made once."""
    import libsumo

    name = f"{type_name}@ignoring"
    if name not in libsumo.vehicletype.getIDList():
        libsumo.vehicletype.copy(type_name, name)
        libsumo.vehicletype.setVehicleClass(name, "ignoring")
    return name
