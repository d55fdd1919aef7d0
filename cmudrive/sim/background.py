"""Background activity: keeps SUMO traffic and pedestrians dense around the CAVs, and the BA commands.

What is kept where, and why:

- **Density targets.** About ``vehicles`` background vehicles within ``radius`` of any active CAV and
  ``pedestrians`` background pedestrians within ``pedestrian_radius``. Only the neighbourhood of the
  CAVs matters to the benchmark (sensors see ~100 m, V2V a little more), so traffic is kept there and
  nowhere else: SUMO never simulates a whole town full of cars that no CAV will meet.
- **Initial fill** (:meth:`BackgroundActivity.populate`, once, after the CAVs are added): anywhere within
  the radii except within ``fill_clearance`` of a CAV, so the first frames already show traffic.
- **Later spawns happen out of sight**, at least ``spawn_min_distance`` from every active CAV (so in front
  of, beside and behind a CAV alike), at most ``max_spawns_per_update`` per update. Actors must not pop
  into existence where a camera could see them.
- **Removal**: actors farther than radius + ``removal_margin`` from every CAV (they drove away); vehicles
  stopped for more than ``stuck_time`` out of sight (SUMO's teleporting is off, so this is what breaks a
  gridlock); vehicles that SUMO could not insert within ``depart_timeout``.

Spawn points are precomputed once per map: points every ``spawn_spacing`` metres along every normal
(non-junction) lane that some background vehicle type may use (vehicles; SUMO's lane permissions decide
which type may spawn where, so bicycles only where bicycles may go) and along every sidewalk
(pedestrians). A KD-tree over the CAVs finds each point's nearest CAV; the distance, lane and heading
tests are numpy over the points. Vehicles drive a route that SUMO's router finds
(``simulation.findRoute``) from the spawn edge to a random far destination edge; pedestrians walk a route from
``simulation.findIntermodalRoute``. All random choices come from ``world.rng``, so a seeded route
replays identically. Spawning and removal run every ``update_period`` ticks; nothing runs on the ticks
in between.

Commands (Bench2Drive's BA commands: ``leave_space``, ``remove_lane``, ``stop_lane``, ``opposite_traffic``,
``clear_junction``, ``max_speed`` ...) are :mod:`cmudrive.sim.background_commands`; scenarios type against its
:class:`~cmudrive.sim.background_commands.BackgroundCommands`.

How this differs from Bench2Drive's background activity, which steers CARLA's Traffic Manager with
per-lane *sources* around the ego (2 cars ahead and 2 behind in each same-direction lane at 15 m spacing,
oncoming sources 80 m ahead, a source 40 m before each junction entry), with speeds tied to the ego's and
no lane changes:

- we keep a *density target* within a radius of all CAVs instead of per-lane sources, because 2 to 16
  CAVs share one world and per-ego sources would overlap and fight;
- SUMO's own car-following, lane changing, junction and pedestrian models drive the background actors
  on ordinary routes; we never set their speeds relative to a CAV (no ``ExtraSpace``, no catch-up), only
  cap or stop them on command;
- ``LeaveSpace`` deletes the cars ahead instead of moving them, and a removed lane only stops spawning
  there: SUMO may still route cars into it from upstream;
- "opposite" is judged geometrically against each vehicle's nearest CAV (heading difference > 120
  degrees, and ahead of it), not from the ego road's lane topology as B2D's oncoming sources are.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import cKDTree

from cmudrive.maps.index import wrap_angle
from cmudrive.maps.model import LaneKind
from cmudrive.sim.actor_types import ACTOR_TYPES, BACKGROUND_VEHICLE_MIX
from cmudrive.sim.background_commands import CommandsMixin
from cmudrive.sim.background_geometry import (
    CavPoses,
    Pending,
    Scene,
    SpawnPoints,
    active_cavs,
    behind_a_cav,
    build_scene,
    lane_points,
    live_vehicles,
    nearest_point,
)
from cmudrive.sim.snapshot import Role
from cmudrive.sim.sumo import SumoError

if TYPE_CHECKING:
    from cmudrive.sim.world import World

OPPOSITE_HEADING = np.radians(120.0)  # [rad] a lane heading further than this from a CAV's runs "opposite"
OTHER_LANE_CLEARANCE = 3.0  # [m] a spawn point this close to any actor (any lane) is blocked
BLOCKER_NEIGHBOURS = 8  # nearest actors checked per spawn point
DESTINATION_DRAWS = 6  # random destination edges drawn per spawn; the farthest routable one is used
ROUTE_TRIES = 3  # router calls per spawn before the actor just follows its spawn edge
PEDESTRIAN_TYPE = "pedestrian"


@dataclass(frozen=True)
class BackgroundConfig:
    """How much background activity, where, and how often it is managed."""

    vehicles: int = 40  # target number of background vehicles within `radius` of any active CAV
    pedestrians: int = 20  # target number of background pedestrians within `pedestrian_radius`
    radius: float = 150.0  # [m]
    pedestrian_radius: float = 80.0  # [m]
    removal_margin: float = 30.0  # [m] actors beyond radius + margin from every active CAV are removed
    spawn_min_distance: float = 60.0  # [m] later spawns are at least this far from every active CAV
    fill_clearance: float = 15.0  # [m] the initial fill keeps this far from every CAV
    # no spawn behind a CAV (on its road: within fill_behind_width sideways) closer than it needs to slow
    # from the lane's speed to the CAV's with fill_decel, plus fill_stop_gap: at tick 0 the CAVs are not
    # yet on SUMO's lanes, so SUMO's insertion check cannot see them, and a car inserted at the lane's
    # speed 15 m behind a standing CAV on a highway ran into it within a second; later spawns (>= 60 m
    # away) at 33 m/s behind a CAV pulling away from standstill on Town04's highway did the same
    fill_decel: float = 2.5  # [m/s^2]
    fill_stop_gap: float = 10.0  # [m]
    fill_behind_width: float = 8.0  # [m]
    spawn_spacing: float = 10.0  # [m] spacing of vehicle spawn points along a lane
    spawn_clearance: float = 15.0  # [m] no vehicle spawns this close to an actor on the same lane
    pedestrian_spacing: float = 5.0  # [m] spacing of pedestrian spawn points (and their clearance)
    lane_end_margin: float = 5.0  # [m] no spawn point closer than this to the end of its lane
    update_period: int = 10  # [ticks] spawning and removal run every this many ticks (10 = 0.5 s)
    max_spawns_per_update: int = 4  # vehicles per update after the initial fill
    max_pedestrian_spawns_per_update: int = 2  # pedestrians per update after the initial fill
    stuck_speed: float = 0.1  # [m/s] slower than this counts as stopped
    stuck_time: float = 60.0  # [s] stopped this long out of sight -> removed
    depart_timeout: float = 3.0  # [s] a vehicle SUMO could not insert within this is removed (dropped)
    # a background actor standing this long inside a junction or on a crossing, within deadlock_reach
    # ahead of a standing CAV, is removed: SUMO's car or pedestrian waits for the CAV's copy in its path
    # while the CAV waits for it (one such pair stood until the CAV counted as blocked, in ~1 of 10
    # junction routes of the expert)
    deadlock_time: float = 15.0  # [s]
    deadlock_reach: float = 10.0  # [m]
    vehicle_mix: dict[str, float] = field(default_factory=lambda: dict(BACKGROUND_VEHICLE_MIX))  # type share

    def __post_init__(self) -> None:
        if self.vehicles < 0 or self.pedestrians < 0:
            raise ValueError("background targets must be >= 0")
        if self.update_period < 1:
            raise ValueError(f"update_period must be >= 1 tick, got {self.update_period}")
        if not 0.0 <= self.fill_clearance <= self.radius or not 0.0 <= self.spawn_min_distance:
            raise ValueError("need 0 <= fill_clearance <= radius and spawn_min_distance >= 0")
        if min(self.spawn_spacing, self.pedestrian_spacing) <= 0.0:
            raise ValueError("spawn spacings must be > 0 m")
        unknown = [t for t in self.vehicle_mix if t not in ACTOR_TYPES]
        if unknown or not self.vehicle_mix or min(self.vehicle_mix.values()) < 0.0:
            raise ValueError(f"bad vehicle_mix {self.vehicle_mix}: unknown types {unknown} or shares < 0")


@dataclass(frozen=True)
class SpawnRecord:
    """One background actor added to SUMO."""

    time: float  # [s] simulation time of the spawn
    actor_id: str
    type_name: str
    x: float  # [m] spawn point (a vehicle's front bumper, a pedestrian's centre)
    y: float  # [m]
    lane: int  # map lane index
    heading: float  # [rad] lane heading at the spawn point
    cav_distance: float  # [m] distance to the nearest active CAV at spawn time
    initial: bool  # part of the initial fill


class BackgroundActivity(CommandsMixin):
    """Background traffic and pedestrians around the CAVs of one world.

    Usage::

        world.background = BackgroundActivity(BackgroundConfig())
        world.background.populate(world)   # once, after the CAVs are added; World.tick calls update()
    """

    def __init__(self, config: BackgroundConfig | None = None) -> None:
        self.config = config if config is not None else BackgroundConfig()
        self.stats: dict[str, int] = dict.fromkeys(
            (
                "spawned",
                "spawned_vehicles",
                "spawned_pedestrians",
                "removed_far",
                "removed_stuck",
                "removed_deadlock",
                "removed_command",
                "dropped",
                "refused",
            ),
            0,
        )
        self.spawns: list[SpawnRecord] = []
        self._world: World | None = None
        self._types = list(self.config.vehicle_mix)
        shares = np.array([self.config.vehicle_mix[t] for t in self._types], np.float64)
        self._type_p = shares / shares.sum()
        self._n_spawned = 0
        self._pending: dict[str, Pending] = {}
        self._deadlocked_since: dict[str, float] = {}  # [s] background actor id -> since when it blocks
        self._type_of: dict[str, str] = {}  # our vehicles' type names
        self._stopped_since: dict[str, float] = {}  # vehicle -> time it was first seen stopped [s]
        self._stopped_lanes: dict[int, float] = {}  # lane -> halt what is behind this arc length [m]
        self._halted: dict[str, int] = {}  # vehicle -> stopped lane that halted it
        self._opposite = True
        self._speed_cap: float | None = None

    # ------------------------------------------------------------------ setup
    def _bind(self, world: World) -> None:
        """Precompute the spawn points and lane permissions of the world's map (once per world)."""
        if self._world is world:
            return
        import libsumo

        self._world = world
        m = world.map
        normal = ~m.lane_internal
        veh_lanes = np.flatnonzero(normal & np.isin(m.lane_kind, [LaneKind.DRIVING, LaneKind.BIKE]))
        ped_lanes = np.flatnonzero(normal & (m.lane_kind == LaneKind.SIDEWALK))
        # SUMO's permissions (from the network file) decide which vehicle types may use a lane
        self._allowed = np.zeros((m.num_lanes, len(self._types)), bool)
        classes = [ACTOR_TYPES[t].vclass for t in self._types]
        self._sumo_scale = np.ones(m.num_lanes)  # SUMO lane length / polyline length
        for lane in np.concatenate([veh_lanes, ped_lanes]).tolist():
            lane_id = str(m.lane_ids[lane])
            self._sumo_scale[lane] = libsumo.lane.getLength(lane_id) / max(float(m.lane_length[lane]), 1e-6)
            if m.lane_kind[lane] == LaneKind.SIDEWALK:
                continue
            allowed = set(libsumo.lane.getAllowed(lane_id))  # empty: every class not disallowed
            disallowed = set(libsumo.lane.getDisallowed(lane_id))
            self._allowed[lane] = [(not allowed or c in allowed) and c not in disallowed for c in classes]
        veh_lanes = veh_lanes[self._allowed[veh_lanes].any(axis=1)]
        cfg = self.config
        self._veh_points = lane_points(m, veh_lanes, cfg.spawn_spacing, cfg.lane_end_margin)
        self._ped_points = lane_points(m, ped_lanes, cfg.pedestrian_spacing, cfg.lane_end_margin)
        self._lane_removed = np.zeros(m.num_lanes, bool)
        # destinations: the edges of the candidate lanes, per vehicle type, with their centre points
        mid = m.index.frenet_to_xy(np.arange(m.num_lanes), 0.5 * m.lane_length)
        self._dest_lanes = [veh_lanes[self._allowed[veh_lanes, t]] for t in range(len(self._types))]
        self._dest_xy = [mid[lanes] for lanes in self._dest_lanes]
        self._ped_dest_lanes = ped_lanes
        self._ped_dest_xy = mid[ped_lanes]

    def _need_world(self) -> World:
        if self._world is None:
            raise RuntimeError("BackgroundActivity is not bound to a world yet: call populate(world) first")
        return self._world

    # ------------------------------------------------------------------ the loop
    def populate(self, world: World) -> None:
        """Initial fill: up to the targets anywhere within the radii, >= ``fill_clearance`` from every CAV."""
        self._bind(world)
        cavs = active_cavs(world)
        if len(cavs.xy) == 0:
            return
        scene = self._scene(world, cavs)
        self._spawn_vehicles(world, scene, cavs, initial=True)
        self._spawn_pedestrians(world, scene, cavs, initial=True)

    def update(self, world: World) -> None:
        """Called by ``World.tick`` after every SUMO step; works every ``update_period`` ticks."""
        self._bind(world)
        if world.step_count % self.config.update_period:
            return
        cavs = active_cavs(world)
        if len(cavs.xy) == 0:
            return
        scene = self._scene(world, cavs)
        self._settle_spawns(world, scene)
        self._remove_far(world, scene)
        self._remove_stuck(world, scene)
        self._break_deadlocks(world, scene, cavs)
        if not self._opposite:  # keep the oncoming lanes ahead empty, removing only out of sight
            self._remove_opposite(world, scene, cavs, self.config.spawn_min_distance)
        self._halt_on_stopped_lanes(scene)
        self._spawn_vehicles(world, scene, cavs, initial=False)
        self._spawn_pedestrians(world, scene, cavs, initial=False)

    # ------------------------------------------------------------------ scene
    def _scene(self, world: World, cavs: CavPoses) -> Scene:
        snap = world.last_snapshot if world.last_snapshot is not None else world.snapshot()
        return build_scene(snap, world, self._pending, cavs)

    def _remove(self, world: World, scene: Scene, rows: np.ndarray, counter: str) -> int:
        """Remove the actors of scene ``rows`` (background only) from SUMO and forget them."""
        rows = rows[scene.alive[rows] & scene.background[rows]]
        for r in rows.tolist():
            actor_id = scene.ids[r]
            world.sumo.remove(actor_id)
            self._pending.pop(actor_id, None)
            self._stopped_since.pop(actor_id, None)
            self._halted.pop(actor_id, None)
            self._type_of.pop(actor_id, None)
        scene.alive[rows] = False
        self.stats[counter] += len(rows)
        return len(rows)

    # ------------------------------------------------------------------ removal
    def _settle_spawns(self, world: World, scene: Scene) -> None:
        """Forget spawns that appeared (or already left); drop those SUMO could not insert in time."""
        import libsumo

        waiting = set(libsumo.simulation.getPendingVehicles())
        seen = set(world.last_snapshot.ids.tolist()) if world.last_snapshot is not None else set()
        late: list[str] = []
        for actor_id, p in list(self._pending.items()):
            if actor_id in seen or actor_id not in world.sumo.actors:
                del self._pending[actor_id]
                if actor_id in seen and not p.person and self._speed_cap is not None:
                    libsumo.vehicle.setMaxSpeed(actor_id, self._speed_cap)
            elif world.time - p.time > self.config.depart_timeout and (p.person or actor_id in waiting):
                late.append(actor_id)
        if late:
            index = {a: i for i, a in enumerate(scene.ids)}
            self._remove(world, scene, np.array([index[a] for a in late], np.int64), "dropped")

    def _remove_far(self, world: World, scene: Scene) -> None:
        cfg = self.config
        limit = np.where(scene.person, cfg.pedestrian_radius, cfg.radius) + cfg.removal_margin
        self._remove(world, scene, np.flatnonzero(scene.cav_dist > limit), "removed_far")

    def _remove_stuck(self, world: World, scene: Scene) -> None:
        cfg = self.config
        rows = live_vehicles(scene)
        now = world.time
        stopped = scene.speed[rows] < cfg.stuck_speed  # NaN (not inserted yet) compares False
        since = self._stopped_since
        present = {scene.ids[r] for r in rows.tolist()}
        for actor_id in [a for a in since if a not in present]:
            del since[actor_id]
        for r, is_stopped in zip(rows.tolist(), stopped.tolist(), strict=True):
            if is_stopped:
                since.setdefault(scene.ids[r], now)
            else:
                since.pop(scene.ids[r], None)
        stuck = [
            r
            for r in rows.tolist()
            if now - since.get(scene.ids[r], now) > cfg.stuck_time
            and scene.cav_dist[r] > cfg.spawn_min_distance
            and scene.ids[r] not in self._halted
        ]
        self._remove(world, scene, np.array(stuck, np.int64), "removed_stuck")

    def _break_deadlocks(self, world: World, scene: Scene, cavs: CavPoses) -> None:
        """Remove background actors that stood ``deadlock_time`` inside a junction (or on a crossing) just
        ahead of a standing CAV (see ``BackgroundConfig.deadlock_time``)."""
        cfg, m, snap = self.config, world.map, world.last_snapshot
        since = self._deadlocked_since
        if snap is None:
            return
        cav_rows = np.flatnonzero(snap.role == Role.CAV)
        standing_cavs = cav_rows[np.abs(snap.speed[cav_rows]) < cfg.stuck_speed]
        rows = np.flatnonzero(
            scene.alive
            & scene.background
            & (scene.speed < cfg.stuck_speed)
            & (scene.lane >= 0)
            & (scene.cav_dist < cfg.deadlock_reach)
        )
        rows = rows[m.lane_internal[scene.lane[rows]]]
        blocking: set[str] = set()
        if len(rows) and len(standing_cavs):
            rel = scene.xy[rows][:, None, :] - np.stack([snap.x, snap.y], axis=1)[standing_cavs][None, :, :]
            yaw = snap.yaw[standing_cavs][None, :]
            along = rel[..., 0] * np.cos(yaw) + rel[..., 1] * np.sin(yaw)
            dist = np.hypot(rel[..., 0], rel[..., 1])
            ahead = ((along > 0.0) & (dist < cfg.deadlock_reach)).any(axis=1)
            blocking = {scene.ids[r] for r in rows[ahead].tolist()}
        now = world.time
        for actor_id in [a for a in since if a not in blocking]:
            del since[actor_id]
        for actor_id in blocking:
            since.setdefault(actor_id, now)
        stale = [r for r in rows.tolist() if now - since.get(scene.ids[r], now) >= cfg.deadlock_time]
        self._remove(world, scene, np.array(stale, np.int64), "removed_deadlock")
        for r in stale:
            since.pop(scene.ids[r], None)

    def _remove_opposite(self, world: World, scene: Scene, cavs: CavPoses, min_distance: float) -> int:
        """Remove vehicles heading against their nearest CAV, ahead of it, within the radius."""
        rows = live_vehicles(scene)
        rows = rows[(scene.cav_dist[rows] <= self.config.radius) & (scene.cav_dist[rows] >= min_distance)]
        k = scene.cav_near[rows]
        against = np.abs(wrap_angle(scene.yaw[rows] - cavs.yaw[k])) > OPPOSITE_HEADING
        rel = scene.xy[rows] - cavs.xy[k]
        ahead = rel[:, 0] * np.cos(cavs.yaw[k]) + rel[:, 1] * np.sin(cavs.yaw[k]) > 0.0
        return self._remove(world, scene, rows[against & ahead], "removed_command")

    # ------------------------------------------------------------------ spawning
    def _candidates(
        self,
        points: SpawnPoints,
        scene: Scene,
        cavs: CavPoses,
        radius: float,
        min_distance: float,
        clearance: float,
        blockers: np.ndarray,
        opposite_filter: bool,
        rng: np.random.Generator,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Indices of usable spawn points and their distance to the nearest CAV [m]."""
        # the nearest CAV of every point, kept within `radius` of it; one compiled loop over points x CAVs
        # (~40 us for ~2000 points and 16 CAVs; a query on a KD-tree of the CAVs took ~240 us)
        nearest, dist = nearest_point(points.xy, cavs.xy)
        idx = np.flatnonzero(dist <= radius)
        dist, nearest = dist[idx], nearest[idx]
        # every other slot of a lane this update, so two spawns of one batch are >= 2 spacings apart
        ok = (dist >= min_distance) & ~self._lane_removed[points.lane[idx]]
        ok &= points.slot[idx] % 2 == rng.integers(2)
        if opposite_filter and not self._opposite:
            ok &= np.abs(wrap_angle(points.heading[idx] - cavs.yaw[nearest])) <= OPPOSITE_HEADING
        idx, dist = idx[ok], dist[ok]
        rows = np.flatnonzero(blockers)
        if len(idx) and len(rows):
            # the BLOCKER_NEIGHBOURS nearest actors of each point (index len(rows) where none is in reach)
            gap, near = cKDTree(scene.xy[rows]).query(
                points.xy[idx], k=BLOCKER_NEIGHBOURS, distance_upper_bound=clearance
            )  # (K, k) each
            lane = np.append(scene.lane[rows], -2)[near]
            blocked = ((lane == points.lane[idx, None]) & np.isfinite(gap)) | (gap < OTHER_LANE_CLEARANCE)
            free = ~blocked.any(axis=1)
            idx, dist = idx[free], dist[free]
        return idx, dist

    def _spawn_vehicles(self, world: World, scene: Scene, cavs: CavPoses, initial: bool) -> None:
        cfg = self.config
        rows = live_vehicles(scene)
        want = cfg.vehicles - int(np.count_nonzero(scene.cav_dist[rows] <= cfg.radius))
        if not initial:
            want = min(want, cfg.max_spawns_per_update)
        if want <= 0:
            return
        rng = world.rng
        pts = self._veh_points
        idx, dist = self._candidates(
            pts,
            scene,
            cavs,
            cfg.radius,
            cfg.fill_clearance if initial else cfg.spawn_min_distance,
            cfg.spawn_clearance,
            scene.alive & ~scene.person,
            True,
            rng,
        )
        keep = ~behind_a_cav(
            world.map, pts, idx, cavs, cfg.fill_decel, cfg.fill_stop_gap, cfg.fill_behind_width
        )
        idx, dist = idx[keep], dist[keep]
        types = rng.choice(len(self._types), size=want, p=self._type_p)
        counts = np.bincount(types, minlength=len(self._types))
        free = np.ones(len(idx), bool)
        for t, n in enumerate(counts.tolist()):
            pool = np.flatnonzero(free & self._allowed[pts.lane[idx], t])
            if n == 0 or len(pool) == 0:
                continue
            pick = rng.choice(pool, size=min(n, len(pool)), replace=False)
            free[pick] = False
            for j in pick.tolist():
                self._add_vehicle(world, self._types[t], int(idx[j]), float(dist[j]), initial)

    def _add_vehicle(
        self, world: World, type_name: str, point: int, cav_distance: float, initial: bool
    ) -> None:

        m, pts = world.map, self._veh_points
        lane = int(pts.lane[point])
        edge = str(m.edge_ids[m.lane_edge[lane]])
        vid = f"bgv{self._n_spawned}"
        self._n_spawned += 1
        edges = self._vehicle_route(world, type_name, edge, pts.xy[point])
        depart_pos = round(float(pts.s[point] * self._sumo_scale[lane]), 2)
        try:
            world.sumo.add_vehicle(
                vid,
                type_name,
                edges,
                int(Role.BACKGROUND),
                depart_pos=depart_pos,
                depart_lane=int(m.lane_index[lane]),
                depart_speed="max",
            )
        except SumoError:
            self.stats["refused"] += 1
            return
        self._type_of[vid] = type_name
        length = ACTOR_TYPES[type_name].length
        self._record(world, vid, type_name, pts, point, cav_distance, initial, length, person=False)

    def _vehicle_route(self, world: World, type_name: str, edge: str, xy: np.ndarray) -> list[str]:
        """SUMO's route from ``edge`` to a random far edge this type may use; just ``edge`` if none."""
        import libsumo

        m = world.map
        t = self._types.index(type_name)
        lanes, dest_xy = self._dest_lanes[t], self._dest_xy[t]
        draws = world.rng.integers(len(lanes), size=DESTINATION_DRAWS)
        far_first = draws[np.argsort(-np.linalg.norm(dest_xy[draws] - xy, axis=1), kind="stable")]
        for j in far_first[:ROUTE_TRIES].tolist():
            goal = str(m.edge_ids[m.lane_edge[lanes[j]]])
            if goal == edge:
                continue
            try:
                route = libsumo.simulation.findRoute(edge, goal, vType=type_name)
            except libsumo.TraCIException:
                continue
            if route.edges:
                return list(route.edges)
        return [edge]

    def _spawn_pedestrians(self, world: World, scene: Scene, cavs: CavPoses, initial: bool) -> None:
        cfg = self.config
        rows = np.flatnonzero(scene.alive & scene.background & scene.person)
        want = cfg.pedestrians - int(np.count_nonzero(scene.cav_dist[rows] <= cfg.pedestrian_radius))
        if not initial:
            want = min(want, cfg.max_pedestrian_spawns_per_update)
        if want <= 0 or len(self._ped_points.lane) == 0:
            return
        rng = world.rng
        idx, dist = self._candidates(
            self._ped_points,
            scene,
            cavs,
            cfg.pedestrian_radius,
            cfg.fill_clearance if initial else cfg.spawn_min_distance,
            cfg.pedestrian_spacing,
            scene.alive & scene.person,
            False,
            rng,
        )
        if len(idx) == 0:
            return
        pick = rng.choice(len(idx), size=min(want, len(idx)), replace=False)
        for j in pick.tolist():
            self._add_pedestrian(world, int(idx[j]), float(dist[j]), initial)

    def _add_pedestrian(self, world: World, point: int, cav_distance: float, initial: bool) -> None:
        import libsumo

        m, pts, rng = world.map, self._ped_points, world.rng
        lane = int(pts.lane[point])
        edge = str(m.edge_ids[m.lane_edge[lane]])
        depart_pos = float(pts.s[point] * self._sumo_scale[lane])
        draws = rng.integers(len(self._ped_dest_lanes), size=DESTINATION_DRAWS)
        reach = np.linalg.norm(self._ped_dest_xy[draws] - pts.xy[point], axis=1)
        far_first = draws[np.argsort(-reach, kind="stable")]
        edges, arrival = [edge], float(rng.uniform(0.0, m.lane_length[lane]) * self._sumo_scale[lane])
        for j in far_first[:ROUTE_TRIES].tolist():
            goal_lane = int(self._ped_dest_lanes[j])
            goal = str(m.edge_ids[m.lane_edge[goal_lane]])
            goal_pos = float(rng.uniform(0.1, 0.9) * m.lane_length[goal_lane] * self._sumo_scale[goal_lane])
            try:
                stages = libsumo.simulation.findIntermodalRoute(
                    edge, goal, pType=PEDESTRIAN_TYPE, departPos=depart_pos, arrivalPos=goal_pos
                )
            except libsumo.TraCIException:
                continue
            walk = [e for st in stages for e in st.edges]
            if goal != edge and walk:
                edges, arrival = walk, goal_pos
                break
        pid = f"bgp{self._n_spawned}"
        self._n_spawned += 1
        try:
            world.sumo.add_person(pid, edges, depart_pos, arrival, int(Role.BACKGROUND))
        except SumoError:
            self.stats["refused"] += 1
            return
        self._record(world, pid, PEDESTRIAN_TYPE, pts, point, cav_distance, initial, 0.0, person=True)

    def _record(
        self,
        world: World,
        actor_id: str,
        type_name: str,
        pts: SpawnPoints,
        point: int,
        cav_distance: float,
        initial: bool,
        length: float,
        person: bool,
    ) -> None:
        xy, heading, lane = pts.xy[point], float(pts.heading[point]), int(pts.lane[point])
        self._pending[actor_id] = Pending(world.time, xy.copy(), heading, lane, length, person)
        self.spawns.append(
            SpawnRecord(
                world.time,
                actor_id,
                type_name,
                float(xy[0]),
                float(xy[1]),
                lane,
                heading,
                cav_distance,
                initial,
            )
        )
        self.stats["spawned"] += 1
        self.stats["spawned_pedestrians" if person else "spawned_vehicles"] += 1

    # ------------------------------------------------------------------ queries
    def background_ids(self, world: World | None = None) -> list[str]:
        """Ids of the background actors SUMO holds now (vehicles and pedestrians, in insertion order)."""
        world = world or self._need_world()
        return [a for a, info in world.sumo.actors.items() if info.role == Role.BACKGROUND]
