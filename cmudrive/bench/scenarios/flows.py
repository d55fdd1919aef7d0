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
  driving after their first collision.
* ``OppositeFlow`` (not imposed): SUMO's own car-following, lights and right of way, capped at the flow
  speed, no lane changes: the oncoming traffic of the *TwoWays scenarios.
"""

from __future__ import annotations

import numpy as np

from cmudrive.bench.scenarios.placement import LanePoint, point_xy
from cmudrive.maps import RoadMap, Route
from cmudrive.maps.routing import LanePos, RoutePlanner
from cmudrive.sim.actor_types import ACTOR_TYPES
from cmudrive.sim.snapshot import Role, Snapshot
from cmudrive.sim.world import World

SINK_RADIUS = 2.0  # [m] a car this close to the sink is removed
FLOW_TYPE = "car"
IMPOSED_SPEED_FACTOR = 3.0  # an ActorFlow car may drive this many times a lane's limit (its speed is imposed)


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
