"""The libsumo session: start options and reading actors into arrays (the vehicle types it defines at
start: :mod:`cmudrive.sim.sumo_types`).

libsumo runs SUMO in-process and can hold one simulation per process; :func:`start_sumo` refuses to
start a second one while one is open, and :meth:`SumoSession.close` always releases it (the world is a
context manager, so routes and tests close it even on errors).

SUMO settings (chosen so that SUMO never silently hides a problem):

- ``--time-to-teleport -1``: SUMO never teleports a jammed vehicle. A deadlock stays visible (and shows
  in the snapshot); the background activity removes vehicles that are stuck out of the CAVs' sight.
- ``--time-to-impatience 30``: a vehicle waiting to enter a priority road grows impatient over 30 s
  (SUMO: 180 s) and then takes gaps that make priority traffic brake. CARLA's traffic manager has no
  priorities at unsignalised junctions (first come, first served); with SUMO's strict priorities a side
  road with steady cross traffic starved, and a CAV queued behind it was blocked.
- ``--collision.action warn`` with ``--collision.check-junctions``: SUMO's own lane-based collisions
  are logged and counted (``SumoSession.sumo_collisions``), never resolved by silently removing
  vehicles. Collisions that score CAVs come from our oriented-box check, not from SUMO.
- ``--lateral-resolution 0.8`` (sublane model): bicycles share lanes with cars, vehicles keep a
  lateral position (props and CAVs off the lane centre), and traffic forms a rescue lane for emergency
  vehicles with the bluelight device.
- ``--pedestrian.model striping``: pedestrians walk on sidewalks, crossings and walking areas.
- ``--max-depart-delay 5``: a vehicle that cannot be inserted within 5 s is dropped (and counted)
  instead of waiting forever.
- default junction model with internal links, ``--step-length 0.05`` (20 Hz, as CARLA leaderboard),
  ``--seed`` from the route: the same route, seed and controls replay bit-identically.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields
from functools import cache
from itertools import chain, repeat
from pathlib import Path

import numba
import numpy as np

from cmudrive.sim.actor_types import ACTOR_TYPES
from cmudrive.sim.snapshot import SIGNAL_BRAKELIGHT, SIGNAL_EMERGENCY_BLUE, ActorKind
from cmudrive.sim.sumo_types import define_vehicle_types

SUMO_STEP = 0.05  # [s]
LATERAL_RESOLUTION = 0.8  # [m] sublane width
MAX_DEPART_DELAY = 5.0  # [s]
SPEED_MODE_ALL = 31  # SUMO speed mode: safe speed, accel, decel, right of way, red lights all respected
SPEED_MODE_SAFE_SPEED = 1  # bit: keep a safe speed behind the vehicle ahead (car-following)
SPEED_MODE_RIGHT_OF_WAY = 8  # bit: respect right of way at junctions
SPEED_MODE_RED_LIGHT = 16  # bit: brake for red lights
LANE_CHANGE_MODE_DEFAULT = 1621  # SUMO's default lane-change mode
BRAKE_LIGHT_DECEL = 0.5  # [m/s^2] a SUMO vehicle decelerating harder than this shows brake lights
MATCH_RADIUS = 5.0  # [m] moveToXY looks for a lane this close first ...
MATCH_RADIUS_FAR = 100.0  # [m] ... and this far when the vehicle is off the road (SUMO's default)

_ACTIVE: list[SumoSession] = []


class SumoError(RuntimeError):
    """SUMO could not be started or refused a command; the message names the network or actor."""


@dataclass
class SumoActor:
    """What we know about an actor that lives in SUMO (SUMO only reports pose and speed)."""

    kind: ActorKind
    role: int
    length: float  # [m]
    width: float  # [m]
    is_person: bool = False


@dataclass
class SumoArrays:
    """SUMO actors read at one tick, in registration order; centre poses in the map frame."""

    ids: list[str]
    kind: np.ndarray  # (n,) int8 ActorKind
    role: np.ndarray  # (n,) int8 Role
    length: np.ndarray  # (n,) [m]
    width: np.ndarray  # (n,) [m]
    x: np.ndarray  # (n,) [m] box centre
    y: np.ndarray  # (n,) [m]
    yaw: np.ndarray  # (n,) [rad] counter-clockwise from +x
    speed: np.ndarray  # (n,) [m/s]
    accel: np.ndarray  # (n,) [m/s^2] from the speed change since the last read
    lane: np.ndarray  # (n,) int32 map lane index, -1 off the map's lanes
    lane_pos: np.ndarray  # (n,) [m] position of the vehicle's front along its lane (SUMO), 0 for persons
    signals: np.ndarray  # (n,) int32 SUMO signal bits: brake light (decelerating), blue light
    extra_lane: np.ndarray  # (len(extra),) int32 map lane of each id in ``read(extra=...)``, -1 if none
    columns_version: int  # changes whenever ids (and so kind, role, length, width) change


@dataclass
class _StaticColumns:
    """Per-actor columns that only change when the set of actors changes (rebuilt then, not per tick)."""

    ids: list[str] = field(default_factory=list)
    kind: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int8))
    role: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int8))
    length: np.ndarray = field(default_factory=lambda: np.zeros(0))
    width: np.ndarray = field(default_factory=lambda: np.zeros(0))
    back: np.ndarray = field(default_factory=lambda: np.zeros(0))  # [m] SUMO reference point to centre
    is_person: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    signals: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))  # blue lights
    vids: list[str] = field(default_factory=list)  # vehicles, in order
    pids: list[str] = field(default_factory=list)  # persons, in order
    vrows: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # rows of vids
    prows: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # rows of pids


@dataclass
class SumoSession:
    """An open libsumo simulation on one network."""

    net: Path
    seed: int
    actors: dict[str, SumoActor] = field(default_factory=dict)
    sumo_collisions: int = 0
    closed: bool = False
    _static: _StaticColumns = field(default_factory=_StaticColumns)
    _last_ids: list[str] = field(default_factory=list)
    _columns_version: int = 0
    _registered: int = 0  # registrations so far (add_vehicle, add_person)
    _static_registered: int = 0  # ... when _static was built
    _last_speed: np.ndarray = field(default_factory=lambda: np.zeros(0))
    # the ids in SUMO (vehicles and persons) at the last look, None: look again; the vehicle and person
    # counts then; the registered actors among them, in registration order
    _present: set[str] | None = None
    _present_counts: tuple[int, int] = (-1, -1)
    _present_ids: list[str] = field(default_factory=list)

    # ------------------------------------------------------------------ lifecycle
    def close(self) -> None:
        if self.closed:
            return
        import libsumo

        try:
            libsumo.close()
        finally:
            self.closed = True
            if self in _ACTIVE:
                _ACTIVE.remove(self)

    def step(self) -> set[str]:
        """One SUMO step; forget the actors that arrived. Returns the ids of the vehicles that arrived
        (registered or not: CAVs are not registered)."""
        import libsumo

        sim = libsumo.simulation
        libsumo.simulationStep()
        arrived = set(sim.getArrivedIDList())
        arrived_persons = sim.getArrivedPersonIDList()
        for gone in arrived:
            self.actors.pop(gone, None)
        for gone in arrived_persons:
            self.actors.pop(gone, None)
        if arrived or arrived_persons or sim.getDepartedNumber() or sim.getDepartedPersonNumber():
            self._present = None
        self.sumo_collisions += int(sim.getCollidingVehiclesNumber())
        return arrived

    # ------------------------------------------------------------------ reading
    def read(self, lane_index: Mapping[str, int], extra: list[str] | None = None) -> SumoArrays:
        """Pose, speed, lane and signals of every registered SUMO actor in the world now; ``extra``
        vehicle ids (in SUMO but not registered, i.e. CAVs) only get their lane. ``lane_index`` maps SUMO
        lane ids to map lane indices (lanes it lacks, and unknown ids, read as -1).

        Plain getters, not subscriptions: with ~170 actors libsumo's subscriptions add ~0.16 ms to the
        step and save ~0.13 ms of reading (measured on downtown, 2 cores). The getters are mapped over
        the ids (``map`` iterates in C, ~0.2 us per call), each column is built with one ``np.fromiter``
        and one compiled loop puts them in registration order; per tick that is ~20 numpy calls (each
        ~1-2 us in the loop) instead of ~60."""

        veh, per = _getters("vehicle"), _getters("person")
        ids, present = self._registered_present()
        static = self._static_columns(ids)
        vids, pids = static.vids, static.pids
        nv, n_p = len(vids), len(pids)
        lane_of = lane_index.get
        x, y, yaw, speed, lane, lane_pos = _actor_columns(
            static.vrows,
            np.fromiter(chain.from_iterable(map(veh.getPosition, vids)), np.float64, 2 * nv),
            np.fromiter(map(veh.getAngle, vids), np.float64, nv),
            np.fromiter(map(veh.getSpeed, vids), np.float64, nv),
            np.fromiter(map(lane_of, map(veh.getLaneID, vids), repeat(-1)), np.int32, nv),
            np.fromiter(map(veh.getLanePosition, vids), np.float64, nv),
            static.prows,
            np.fromiter(chain.from_iterable(map(per.getPosition, pids)), np.float64, 2 * n_p),
            np.fromiter(map(per.getAngle, pids), np.float64, n_p),
            np.fromiter(map(per.getSpeed, pids), np.float64, n_p),
            np.fromiter(map(lane_of, map(per.getLaneID, pids), repeat(-1)), np.int32, n_p),
            static.back,
        )
        accel, signals = _accel_signals(speed, self._speed_before(ids, speed), static.signals)
        self._last_ids, self._last_speed = ids, speed
        return SumoArrays(
            ids=static.ids,
            kind=static.kind,
            role=static.role,
            length=static.length,
            width=static.width,
            x=x,
            y=y,
            yaw=yaw,
            speed=speed,
            accel=accel,
            lane=lane,
            lane_pos=lane_pos,
            signals=signals,
            extra_lane=_extra_lanes(extra or [], present, veh.getLaneID, lane_of),
            columns_version=self._columns_version,
        )

    def _registered_present(self) -> tuple[list[str], set[str]]:
        """The registered actors in SUMO now (registration order) and every id in SUMO. Looked up again
        only after a step in which actors departed or arrived, a registration or removal, or when SUMO's
        vehicle or person count changed (any other way in or out); ~10 us a tick saved otherwise."""
        import libsumo

        counts = (libsumo.vehicle.getIDCount(), libsumo.person.getIDCount())
        if self._present is None or counts != self._present_counts:
            present = set(libsumo.vehicle.getIDList())
            present.update(libsumo.person.getIDList())
            self._present, self._present_counts = present, counts
            self._present_ids = [a for a in self.actors if a in present]
        return self._present_ids, self._present

    def _speed_before(self, ids: list[str], speed: np.ndarray) -> np.ndarray:
        """(n,) each actor's speed at the last read [m/s], its speed now where it was not there (its
        acceleration reads 0, as does everyone's on the first read)."""
        if ids == self._last_ids:
            return self._last_speed
        if not self._last_ids:
            return speed
        last = dict(zip(self._last_ids, self._last_speed.tolist(), strict=True))
        return np.array([last.get(a, s) for a, s in zip(ids, speed.tolist(), strict=True)])

    def _static_columns(self, ids: list[str]) -> _StaticColumns:
        # rebuilt when the actors present change, or when one was (re-)registered (an id can come back
        # as another type)
        if ids != self._static.ids or self._registered != self._static_registered:
            self._static_registered = self._registered
            self._columns_version += 1
            info = [self.actors[a] for a in ids]
            length = np.array([i.length for i in info], np.float64)
            kind = np.array([i.kind for i in info], np.int8)
            is_person = np.array([i.is_person for i in info], bool)
            vrows, prows = np.flatnonzero(~is_person), np.flatnonzero(is_person)
            self._static = _StaticColumns(
                ids=ids,
                kind=kind,
                role=np.array([i.role for i in info], np.int8),
                length=length,
                width=np.array([i.width for i in info], np.float64),
                # SUMO's vehicle position is the front bumper; a person's is its centre
                back=np.where(is_person, 0.0, 0.5 * length),
                is_person=is_person,
                signals=np.where(kind == ActorKind.EMERGENCY, SIGNAL_EMERGENCY_BLUE, 0).astype(np.int32),
                vids=[ids[i] for i in vrows.tolist()],
                pids=[ids[i] for i in prows.tolist()],
                vrows=vrows,
                prows=prows,
            )
        return self._static

    # ------------------------------------------------------------------ adding and moving
    def add_vehicle(
        self,
        vid: str,
        type_name: str,
        edges: list[str],
        role: int,
        depart_pos: float | str = "base",
        depart_lane: int | str = "best",
        depart_speed: float | str = "desired",
    ) -> None:
        """Insert a vehicle on a route of edges (it appears in the world at the next step)."""
        import libsumo

        t = ACTOR_TYPES[type_name]
        route_id = f"route:{vid}"
        try:
            libsumo.route.add(route_id, edges)
            libsumo.vehicle.add(
                vid,
                route_id,
                typeID=type_name,
                depart="now",
                departLane=str(depart_lane),
                departPos=str(depart_pos),
                departSpeed=str(depart_speed),
            )
        except libsumo.TraCIException as exc:
            raise SumoError(
                f"SUMO refused vehicle {vid} ({type_name}) on edges {edges[:3]}...: {exc}"
            ) from exc
        self.actors[vid] = SumoActor(t.kind, role, t.length, t.width)
        self._registered += 1
        self._present = None

    def add_person(
        self, pid: str, edges: list[str], depart_pos: float, arrival_pos: float, role: int
    ) -> None:
        """Insert a pedestrian walking along ``edges`` (a connected walk, e.g. from
        ``simulation.findIntermodalRoute``) from ``depart_pos`` on the first edge to ``arrival_pos`` [m] on
        the last; it appears in the world at the next step."""
        import libsumo

        t = ACTOR_TYPES["pedestrian"]
        try:
            libsumo.person.add(pid, edges[0], depart_pos, depart=-3, typeID="pedestrian")  # -3: now
        except libsumo.TraCIException as exc:
            raise SumoError(f"SUMO refused pedestrian {pid} on edges {edges[:3]}...: {exc}") from exc
        try:
            libsumo.person.appendWalkingStage(pid, edges, arrival_pos)
        except libsumo.TraCIException as exc:
            remove_from_sumo(pid, is_person=True)  # a person without a plan would fail the next step
            raise SumoError(f"SUMO refused the walk of pedestrian {pid} ({edges[:3]}...): {exc}") from exc
        self.actors[pid] = SumoActor(t.kind, role, t.length, t.width, is_person=True)
        self._registered += 1
        self._present = None

    def override(
        self,
        vid: str,
        *,
        ignore_lights: bool = False,
        ignore_right_of_way: bool = False,
        ignore_vehicles: bool = False,
        speed: float | None = None,
        lane_changes: bool = True,
    ) -> None:
        """Scenario control of a SUMO vehicle: run red lights, ignore right of way at junctions, ignore the
        vehicle ahead (no safe-speed car-following: it drives into what stands in its lane), hold a fixed
        ``speed`` [m/s] (0: a standing obstacle that traffic changes lanes around; -1: back to SUMO's own
        choice), no lane changes. Uses SUMO's speed-mode bits (default 31: every check on)."""
        import libsumo

        mode = SPEED_MODE_ALL
        if ignore_lights:
            mode &= ~SPEED_MODE_RED_LIGHT
        if ignore_right_of_way:
            mode &= ~SPEED_MODE_RIGHT_OF_WAY
        if ignore_vehicles:
            mode &= ~SPEED_MODE_SAFE_SPEED
        try:
            libsumo.vehicle.setSpeedMode(vid, mode)
            if speed is not None:
                libsumo.vehicle.setSpeed(vid, speed)
            libsumo.vehicle.setLaneChangeMode(vid, LANE_CHANGE_MODE_DEFAULT if lane_changes else 0)
        except libsumo.TraCIException as exc:
            raise SumoError(f"cannot override vehicle {vid}: {exc}") from exc

    def remove(self, actor_id: str) -> None:
        """Take a registered actor out of SUMO now (also one still waiting for insertion)."""
        info = self.actors.pop(actor_id, None)
        if info is not None:
            remove_from_sumo(actor_id, info.is_person)
            self._present = None

    def move_vehicles(
        self,
        ids: list[str],
        x: np.ndarray,
        y: np.ndarray,
        yaw: np.ndarray,
        speed: np.ndarray,
        length: np.ndarray,
    ) -> np.ndarray:
        """Place vehicles at centre poses (map frame) for the next step, SUMO's co-simulation pattern:
        ``moveToXY(keepRoute=0)`` maps each onto the nearest lane (any edge) and ``setSpeed`` tells SUMO
        traffic how fast it goes. Returns (n,) bool: no lane within MATCH_RADIUS (off the road).

        Not keepRoute=2 (CARLA's co-simulation): it lets SUMO's copy leave the network, and with the
        sublane model libsumo 1.28 then segfaults in the next step (docs/simulator.md)."""
        import libsumo

        front = _front_poses(
            np.asarray(x, np.float64),
            np.asarray(y, np.float64),
            np.asarray(yaw, np.float64),
            np.asarray(length, np.float64),
        ).tolist()
        move, set_speed = _movers()
        off_road = np.zeros(len(ids), bool)
        for i, (vid, fx, fy, angle, v) in enumerate(
            zip(ids, *front, np.asarray(speed).tolist(), strict=True)
        ):
            try:  # a small match radius keeps SUMO's lane search cheap (~10 us instead of ~80 us)
                move(vid, "", -1, fx, fy, angle, 0, MATCH_RADIUS)  # keepRoute=0, matchThreshold
            except libsumo.TraCIException:  # off the road: map it onto the nearest lane within 100 m
                off_road[i] = True
                move(vid, "", -1, fx, fy, angle, 0, MATCH_RADIUS_FAR)
            set_speed(vid, v)
        return off_road


@numba.njit(cache=True)
def _front_poses(x: np.ndarray, y: np.ndarray, yaw: np.ndarray, length: np.ndarray) -> np.ndarray:
    """(3, n) SUMO's pose of boxes given by their centre: front-bumper x, y [m] and angle [degrees,
    clockwise from north]."""
    out = np.empty((3, x.shape[0]))
    for i in range(x.shape[0]):
        half = 0.5 * length[i]
        out[0, i] = x[i] + half * np.cos(yaw[i])
        out[1, i] = y[i] + half * np.sin(yaw[i])
        out[2, i] = 90.0 - np.degrees(yaw[i])
    return out


@cache
def _movers() -> tuple[Callable[..., None], Callable[[str, float], None]]:
    """libsumo's C entry points of ``vehicle.moveToXY`` and ``vehicle.setSpeed`` (see ``_getters``),
    called with positional arguments (keyword arguments cost ~0.2 us more a call)."""
    import libsumo

    raw = getattr(libsumo, "_libsumo", None)
    return (
        getattr(raw, "vehicle_moveToXY", None) or libsumo.vehicle.moveToXY,
        getattr(raw, "vehicle_setSpeed", None) or libsumo.vehicle.setSpeed,
    )


@dataclass(frozen=True)
class _Getters:
    """The per-actor getters ``read`` calls, of one libsumo domain."""

    getPosition: Callable[[str], tuple[float, float]]  # libsumo's names
    getAngle: Callable[[str], float]
    getSpeed: Callable[[str], float]
    getLanePosition: Callable[[str], float]
    getLaneID: Callable[[str], str]


@cache
def _getters(domain: str) -> _Getters:
    """libsumo's C entry points behind ``libsumo.<domain>.get...``: the Python wrappers only forward
    the call, and skipping them saves ~0.08 us of ~0.25 us per call (~700 calls a tick). Falls back to
    the wrappers should a libsumo version name its entry points differently."""
    import libsumo

    raw, public = getattr(libsumo, "_libsumo", None), getattr(libsumo, domain)
    names = [f.name for f in fields(_Getters)]
    return _Getters(*(getattr(raw, f"{domain}_{n}", None) or getattr(public, n) for n in names))


def _extra_lanes(
    ids: list[str], present: set[str], lane_id: Callable[[str], str], lane_of: Callable[[str, int], int]
) -> np.ndarray:
    """(len(ids),) int32 map lane of each vehicle id, -1 for a lane off the map or an id not in SUMO."""
    if present.issuperset(ids):  # the common case: one map over the ids, no Python loop
        return np.fromiter(map(lane_of, map(lane_id, ids), repeat(-1)), np.int32, len(ids))
    return np.array([lane_of(lane_id(a), -1) if a in present else -1 for a in ids], np.int32)


@numba.njit(cache=True)
def _actor_columns(
    vrows: np.ndarray,
    v_xy: np.ndarray,
    v_angle: np.ndarray,
    v_speed: np.ndarray,
    v_lane: np.ndarray,
    v_lane_pos: np.ndarray,
    prows: np.ndarray,
    p_xy: np.ndarray,
    p_angle: np.ndarray,
    p_speed: np.ndarray,
    p_lane: np.ndarray,
    back: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Centre x, y [m], yaw [rad, wrapped to [-pi, pi)], speed, lane and lane position of all actors in
    registration order, from SUMO's vehicle (rows ``vrows``) and person (rows ``prows``) readings:
    positions ``*_xy`` flat (x0, y0, x1, ...), angles in degrees clockwise from north; ``back`` (n,) is
    SUMO's reference point to the box centre [m]. Persons get lane position 0."""
    n = vrows.shape[0] + prows.shape[0]
    x, y, yaw, speed = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    lane, lane_pos = np.empty(n, np.int32), np.zeros(n)
    for rows, xy, angle, v, on in (
        (vrows, v_xy, v_angle, v_speed, v_lane),
        (prows, p_xy, p_angle, p_speed, p_lane),
    ):
        for k in range(rows.shape[0]):
            i = rows[k]
            heading = np.radians(90.0 - angle[k])
            x[i] = xy[2 * k] - back[i] * np.cos(heading)
            y[i] = xy[2 * k + 1] - back[i] * np.sin(heading)
            yaw[i] = (heading + np.pi) % (2.0 * np.pi) - np.pi
            speed[i] = v[k]
            lane[i] = on[k]
    for k in range(vrows.shape[0]):
        lane_pos[vrows[k]] = v_lane_pos[k]
    return x, y, yaw, speed, lane, lane_pos


@numba.njit(cache=True)
def _accel_signals(
    speed: np.ndarray, speed_before: np.ndarray, fixed_signals: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Acceleration [m/s^2] over the last step (from the speed change: two getter calls per vehicle less
    than asking SUMO) and signal bits: ``fixed_signals`` (blue lights) plus the brake light where the
    deceleration exceeds BRAKE_LIGHT_DECEL."""
    accel = (speed - speed_before) / SUMO_STEP
    signals = fixed_signals.copy()
    for i in range(speed.shape[0]):
        if accel[i] < -BRAKE_LIGHT_DECEL:
            signals[i] |= SIGNAL_BRAKELIGHT
    return accel, signals


def remove_from_sumo(actor_id: str, is_person: bool = False) -> None:
    """Remove a vehicle or person from SUMO; ids SUMO no longer knows (arrived in the same step) are
    ignored."""
    import libsumo

    domain = libsumo.person if is_person else libsumo.vehicle
    try:
        domain.remove(actor_id)
    except libsumo.TraCIException:
        pass


def sumo_options(
    net: Path, seed: int, log_file: Path | None = None, extra: list[str] | None = None
) -> list[str]:
    """SUMO's command line; warnings go to ``log_file`` when given (they are chatty), else are muted."""
    return [
        "sumo",
        "--net-file",
        str(net),
        "--step-length",
        str(SUMO_STEP),
        "--seed",
        str(int(seed)),
        "--time-to-teleport",
        "-1",
        "--time-to-impatience",
        "30",
        "--collision.action",
        "warn",
        "--collision.check-junctions",
        "true",
        "--lateral-resolution",
        str(LATERAL_RESOLUTION),
        "--pedestrian.model",
        "striping",
        "--max-depart-delay",
        str(MAX_DEPART_DELAY),
        "--device.bluelight.reactiondist",
        "50",
        "--no-step-log",
        "true",
        *(["--log", str(log_file)] if log_file else ["--no-warnings", "true"]),
        *(extra or []),
    ]


def start_sumo(
    net: Path, seed: int, friction: float = 1.0, log_file: Path | None = None, extra: list[str] | None = None
) -> SumoSession:
    """Start libsumo on ``net``. Only one simulation may be open per process."""
    import libsumo

    if _ACTIVE:
        raise SumoError(
            f"a SUMO simulation on {_ACTIVE[0].net.name} is still open in this process; close it first "
            "(libsumo holds one simulation per process)"
        )
    try:
        libsumo.start(sumo_options(net, seed, log_file, extra))
    except libsumo.TraCIException as exc:
        raise SumoError(f"SUMO could not start on {net}: {exc}") from exc
    session = SumoSession(net=Path(net), seed=seed)
    _ACTIVE.append(session)
    try:
        define_vehicle_types(friction)
    except Exception:
        session.close()
        raise
    return session
