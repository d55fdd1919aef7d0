"""Vehicle flows from a source to a sink (``reference/SCENARIOS.md``, "ActorFlow" and "OppositeFlow").

A :class:`VehicleFlow` spawns SUMO cars at a source lane point whenever the car it spawned last has driven
farther than the current gap g from it (g drawn again from U[from, to] after each spawn), drives them on
SUMO's lane-level route to the sink, and removes each car once it is within ``SINK_RADIUS`` of the sink
or has left the network; :meth:`VehicleFlow.stop` removes them all.

Two behaviours (``imposed``):

* ``ActorFlow`` (imposed): every car keeps the flow speed [m/s] set by ``setSpeed``, ignores red lights
  and right of way, never changes lanes, and, as upstream's, ignores the vehicles ahead (SUMO's safe-speed
  bit off): it does not brake for a CAV that forces its way in or stands in its lane, it hits it. After
  the first collision of one of the flow's cars (``World.collisions``, with anything), every car of the
  flow, present and future, falls back to SUMO's car-following, as upstream's fall back to normal
  driving after their first collision. Upstream's normal driving is CARLA's BasicAgent, which brakes for
  any vehicle inside the polygon of its route ahead. SUMO's car-following sees a CAV only through its
  copy on the nearest lane: a CAV whose nose reaches into the flow's lane from a junction's internal lane
  is a foe SUMO waits for at the conflict point of the two internal lanes, which can lie beside or past
  the CAV's nose, and the car drove on into the CAV (SignalizedJunctionLeftTurn_1: 0.57 m deep, not
  charged as the CAV stood) or stopped beside it, in its way (SignalizedJunctionLeftTurnEnterFlow_3,
  SignalizedJunctionRightTurn_2: CAVs and flow cars waiting for each other to the tick cap). So a
  following car also brakes, geometrically, to stand ``YIELD_STANDOFF`` short of the first actor
  (vehicle or walker) that reaches into its swept path ahead (within half its width + ``YIELD_CLEARANCE``)
  and stands or crosses it (a vehicle driving along the path is SUMO's leader to follow), and drives on
  at the flow speed once none does (:meth:`VehicleFlow._yield`); SUMO's own stops (its lane leaders, its
  junction foes) stay, so the car stops at the earlier of the two.
* ``OppositeFlow`` (not imposed): SUMO's own car-following, lights and right of way, capped at the flow
  speed, no lane changes: the oncoming traffic of the *TwoWays scenarios.
"""

from __future__ import annotations

import numpy as np

from cmudrive.bench.scenarios.placement import LanePoint, point_xy
from cmudrive.maps import RoadMap, Route
from cmudrive.maps.routing import LanePos, RoutePlanner
from cmudrive.sim.actor_types import ACTOR_TYPES
from cmudrive.sim.snapshot import ActorKind, Role, Snapshot
from cmudrive.sim.world import World

SINK_RADIUS = 2.0  # [m] a car this close to the sink is removed
FLOW_TYPE = "car"
IMPOSED_SPEED_FACTOR = 3.0  # an ActorFlow car may drive this many times a lane's limit (its speed is imposed)
YIELD_STANDOFF = 4.0  # [m] a following flow car stands this far short of an actor across its path
YIELD_CLEARANCE = 0.0  # [m] past the car's half width: an actor this close to its path is in it (BasicAgent)
YIELD_REACTION = 1.0  # [s] of driving looked ahead beyond the braking distance and the standoff
YIELD_ALONG = 0.5  # [rad] an actor moving within this of the path's heading is followed, not yielded to
YIELD_STANDING = 1.0  # [m/s] an actor slower than this is yielded to whatever its heading
YIELD_STEP = 0.25  # [m] spacing of the swept path's sample points


def flow_path(
    road_map: RoadMap, source: LanePoint, sink: LanePoint, lanes: np.ndarray | None = None
) -> Route:
    """The lane-level path a flow's cars drive from ``source`` to ``sink`` over ``lanes`` ((N,) bool;
    default the driving lanes); RouteError when there is none."""
    planner = RoutePlanner(road_map, lanes=lanes)
    return planner.plan_lanes(LanePos(source.lane, source.s), LanePos(sink.lane, sink.s))


class VehicleFlow:
    """One flow of SUMO cars; :meth:`update` once per tick while it runs."""

    def __init__(
        self,
        name: str,
        world: World | None,
        road_map: RoadMap,
        source: LanePoint,
        sink: LanePoint,
        gap: tuple[float, ...],
        speed: float,
        rng: np.random.Generator,
        imposed: bool,
        type_name: str = FLOW_TYPE,
        lanes: np.ndarray | None = None,
    ) -> None:
        """``type_name``: the actor type of the flow's vehicles; ``lanes``: (N,) bool mask of the lanes its
        path may use (default the driving lanes; the bike lanes for a bicycle flow)."""
        self.name, self._world, self.map = name, world, road_map
        self.source, self.sink, self.gap_range, self.speed = source, sink, gap, float(speed)
        self.rng, self.imposed, self.type_name = rng, imposed, type_name
        path = flow_path(road_map, source, sink, lanes)
        self.path = path
        self.path_length = path.length  # [m]
        names = [
            str(road_map.edge_ids[road_map.lane_edge[x]]) for x in path.path if not road_map.lane_internal[x]
        ]
        self.edges = [e for i, e in enumerate(names) if i == 0 or e != names[i - 1]]
        self.sink_xy = point_xy(road_map, sink)
        self.cars: list[str] = []
        self.born: dict[str, int] = {}  # car -> world step count when it was added
        self.collided = False  # one of its cars hit something: the flow follows cars from then on
        self._yielding: dict[str, float] = {}  # car -> speed [m/s] set to stand short of an actor
        self.spawned = 0
        self.gap = self._draw()

    @property
    def world(self) -> World:
        if self._world is None:
            raise RuntimeError(f"flow {self.name} was built for its plan only: it has no world")
        return self._world

    def _draw(self) -> float:
        lo, hi = self.gap_range[0], self.gap_range[-1]
        return float(self.rng.uniform(lo, hi))

    def update(self, snap: Snapshot) -> None:
        """Spawn at the source when the last car is a gap away; remove cars at the sink."""
        import libsumo

        sumo = self.world.sumo
        rows = {str(a): i for i, a in enumerate(snap.ids.tolist()) if str(a).startswith(self.name)}
        # a car SUMO discarded at insertion (it could not depart, e.g. too fast before a red line) is neither
        # running nor pending, and never reported as arrived: drop it, or the flow would wait for it forever
        known = set(libsumo.vehicle.getIDList()) | set(libsumo.simulation.getPendingVehicles())
        for car in list(self.cars):
            r = rows.get(car)
            stepped = self.world.step_count > self.born.get(car, self.world.step_count)  # SUMO tried it
            gone = car not in sumo.actors or (stepped and car not in known)
            at_sink = (
                r is not None
                and np.hypot(snap.x[r] - self.sink_xy[0], snap.y[r] - self.sink_xy[1]) < SINK_RADIUS
            )
            if gone or at_sink:
                sumo.remove(car)
                self.cars.remove(car)
                self.born.pop(car, None)
        # after the clean-up: a car SUMO discarded cannot be commanded (EnterActorFlow_3, seed 1, crashed
        # the route when the flow's first collision came in the tick after such a discard)
        if self.imposed and not self.collided and self._hit_something():
            self.collided = True
            for car in self.cars:  # the speed stays as it is (the car that hit something is held)
                if car in sumo.actors:
                    self._control(car, set_speed=False)
        if self.imposed and self.collided:
            self._yield(snap, rows)
        last = f"{self.name}:{self.spawned - 1}"
        if self.spawned and last in self.cars:
            try:
                driven = float(libsumo.vehicle.getDistance(last))
            except libsumo.TraCIException:  # not inserted yet
                return
            if driven < self.gap:
                return
        self._spawn()

    def prefill(self) -> None:
        """Cars every gap U[from, to] along the path from the source to ``SINK_RADIUS`` short of the sink,
        the one nearest the source last (the next spawn waits for it). SUMO cannot insert a car on a
        junction's internal lane: places inside a junction are skipped."""
        m, path = self.map, self.path
        places: list[int] = []
        d = self.gap
        while d < path.length - SINK_RADIUS - 0.5 * ACTOR_TYPES[self.type_name].length:
            places.append(int(np.searchsorted(path.distance, d)))
            d += self._draw()
        for k in reversed(places):
            lane = int(path.lane[k])
            if m.lane_internal[lane]:
                continue
            edge = str(m.edge_ids[m.lane_edge[lane]])
            self._spawn(LanePoint(lane, float(path.s[k])), self.edges[self.edges.index(edge) :])
        self._spawn()

    def _spawn(self, at: LanePoint | None = None, edges: list[str] | None = None) -> None:
        car = f"{self.name}:{self.spawned}"
        self.spawned += 1
        kind = ACTOR_TYPES[self.type_name]
        half = 0.5 * kind.length
        at = at or self.source
        pos = min(at.s + half, float(self.map.lane_length[at.lane]) - 0.1)
        speed = min(self.speed, kind.max_speed)  # SUMO refuses a departure above the type's top speed
        m = self.map
        if self._must_stop_ahead(at.lane):
            room = max(float(m.lane_length[at.lane]) - pos - 1.0, 0.0)  # [m] to the stop line
            bt = kind.decel * kind.tau  # SUMO's safe speed: stop within room after a reaction time tau
            speed = min(speed, float(np.sqrt(bt * bt + 2.0 * kind.decel * room) - bt))
        sumo = self.world.sumo
        sumo.add_vehicle(
            car, self.type_name, edges or self.edges, int(Role.SCENARIO),
            depart_pos=pos, depart_lane=int(self.map.lane_index[at.lane]), depart_speed=speed,
        )  # fmt: skip
        if self.imposed:
            self._control(car)
            import libsumo

            libsumo.vehicle.setSpeedFactor(
                car, IMPOSED_SPEED_FACTOR
            )  # lane limits must not cap the flow speed
            top = ACTOR_TYPES[self.type_name].max_speed
            if self.speed > top:
                libsumo.vehicle.setMaxSpeed(car, self.speed)
        else:
            import libsumo

            sumo.override(car, lane_changes=False)
            libsumo.vehicle.setMaxSpeed(car, self.speed)
        self.cars.append(car)
        self.born[car] = self.world.step_count
        self.gap = self._draw()

    def _must_stop_ahead(self, lane: int) -> bool:
        """A car departing on ``lane`` may have to stop at the end of it, so SUMO inserts it only as fast as
        it could stop there (else it discards the car): the flow's link leaving ``lane`` is signalised (the
        light may be red, or forced red for the scenario: "never switches to 'G'") or has no right of way
        (a minor, stop, all-way or equal link: "unpriorised junction too close"). The check is SUMO's, at
        insertion only: once driving, an ActorFlow car ignores lights and right of way."""
        m, lanes = self.map, self.path.path
        at = np.flatnonzero(lanes == lane)
        if not len(at) or at[0] + 1 >= len(lanes):
            return False  # the lane is the path's last: no link ahead
        nxt = lanes[at[0] + 1]
        link = np.flatnonzero((m.link_from == lane) & ((m.link_via == nxt) | (m.link_to == nxt)))
        if not len(link):  # consecutive lanes of a planned path are always linked
            return False
        k = int(link[0])
        return bool(m.link_tls[k] >= 0 or not str(m.link_state[k]).isupper())

    def _yield(self, snap: Snapshot, rows: dict[str, int]) -> None:
        """A following car (the flow has collided) that would reach an actor (vehicle or walker) standing
        in or crossing its path brakes to stand ``YIELD_STANDOFF`` short of it (module docstring); the flow
        speed comes back once none is ahead. A car the world holds after its own collision is left to the
        world. All cars of the flow in one batch (this runs every tick)."""
        import libsumo

        for car in [c for c in self._yielding if c not in self.cars]:
            del self._yielding[car]
        cars = [
            c for c in self.cars if c in rows and c in self.world.sumo.actors and not self.world.is_held(c)
        ]
        if not cars:
            return
        kind = ACTOR_TYPES[self.type_name]
        movers = np.flatnonzero(snap.valid & (snap.kind != ActorKind.PROP))  # walkers too (SUMO's crossings)
        room = self._room(
            snap, np.array([rows[c] for c in cars]), movers, kind.width, kind.length, kind.decel
        )
        target = np.minimum(self.speed, np.sqrt(2.0 * kind.decel * np.maximum(room, 0.0)))
        for car, t in zip(cars, target.tolist(), strict=True):
            before = self._yielding.get(car)
            if t < self.speed:
                if before is None or abs(before - t) > 0.05:
                    libsumo.vehicle.setSpeed(car, t)
                    self._yielding[car] = t
            elif before is not None:
                libsumo.vehicle.setSpeed(car, self.speed)
                del self._yielding[car]

    def _room(
        self, snap: Snapshot, cars: np.ndarray, movers: np.ndarray, width: float, length: float, decel: float
    ) -> np.ndarray:
        """(C,) [m] each car (snapshot rows ``cars``) may still drive before it stands ``YIELD_STANDOFF``
        short of the first point of its path ahead that lies within half its ``width`` +
        ``YIELD_CLEARANCE`` of the box of one of the actors ``movers`` (rows; the car itself left out)
        that stands or does not move along the path there; inf when there is none within its braking
        distance, the standoff and ``YIELD_REACTION`` of driving."""
        path = self.path
        cx, cy = snap.x[cars], snap.y[cars]
        k = np.argmin(
            (path.xy[None, :, 0] - cx[:, None]) ** 2 + (path.xy[None, :, 1] - cy[:, None]) ** 2, axis=1
        )
        front = path.distance[k] + 0.5 * length  # (C,)
        v = np.maximum(snap.speed[cars], 0.0)
        look = YIELD_STANDOFF + v * v / (2.0 * decel) + v * YIELD_REACTION + 1.0
        room = np.full(len(cars), np.inf)
        near = movers[
            (np.hypot(snap.x[movers][None, :] - cx[:, None], snap.y[movers][None, :] - cy[:, None])
             < (look + 10.0)[:, None]).any(axis=0)
        ]  # fmt: skip
        if not len(near):
            return room
        steps = np.arange(int(np.ceil(look.max() / YIELD_STEP)) + 1) * YIELD_STEP
        d = front[:, None] + steps[None, :]  # (C, P) the swept paths' samples
        valid = (steps[None, :] < look[:, None]) & (d < path.length)
        px, py = np.interp(d, path.distance, path.xy[:, 0]), np.interp(d, path.distance, path.xy[:, 1])
        ph = np.interp(d, path.distance, np.unwrap(path.heading))
        dx, dy = px[..., None] - snap.x[near], py[..., None] - snap.y[near]  # (C, P, A)
        c, s = np.cos(snap.yaw[near]), np.sin(snap.yaw[near])
        out_u = np.maximum(np.abs(dx * c + dy * s) - 0.5 * snap.length[near], 0.0)
        out_w = np.maximum(np.abs(-dx * s + dy * c) - 0.5 * snap.width[near], 0.0)
        inside = np.hypot(out_u, out_w) < 0.5 * width + YIELD_CLEARANCE
        along = np.abs(np.angle(np.exp(1j * (snap.yaw[near] - ph[..., None])))) < YIELD_ALONG
        # (SUMO's car-following sees no walker on the road: a walker is yielded to whatever its heading)
        vehicle = snap.kind[near] != ActorKind.PEDESTRIAN
        followed = along & vehicle & (snap.speed[near] >= YIELD_STANDING)
        itself = near[None, None, :] == cars[:, None, None]
        hit = (inside & ~followed & ~itself).any(axis=2) & valid  # (C, P)
        first = np.argmax(hit, axis=1)
        has = hit[np.arange(len(cars)), first]
        room[has] = d[has, first[has]] - front[has] - YIELD_STANDOFF
        return room

    def _hit_something(self) -> bool:
        """One of this flow's cars is in a collision of the last tick."""
        ev = self.world.collisions
        if not len(ev):
            return False
        prefix = f"{self.name}:"
        ids = np.concatenate([ev.id_a, ev.id_b]).astype(str)
        return bool(np.any(np.char.startswith(ids, prefix)))

    def _control(self, car: str, set_speed: bool = True) -> None:
        """An ActorFlow car: the flow speed, red lights and right of way ignored, no lane changes, and the
        vehicles ahead ignored until the flow's first collision."""
        self.world.sumo.override(
            car,
            ignore_lights=True,
            ignore_right_of_way=True,
            ignore_vehicles=not self.collided,
            speed=self.speed if set_speed else None,
            lane_changes=False,
        )

    def stop(self) -> None:
        for car in self.cars:
            self.world.sumo.remove(car)
        self.cars.clear()
