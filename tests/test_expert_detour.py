"""The expert's lateral shifts around obstacles (``cmudrive.agents.expert.detour``) on synthetic snapshots
over real towns: interurban's two-lane one-way ring road, downtown's two-way street (one lane each way,
a parking lane on the right) and highway's single-lane exit ramp; then closed loop, a CAV that follows
its shifted path passing a ParkedObstacle."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest

from cmudrive.agents import Agent, Observation, Observations, RouteSetup
from cmudrive.agents.expert.detour import Detour, DetourConfig, DetourPlanner, DetourReason
from cmudrive.bench import RouteSpec
from cmudrive.maps import RoadMap, Route, RoutePlanner, load_map
from cmudrive.maps.routing import LanePos
from cmudrive.sim.dynamics import Controls, VehicleParams
from cmudrive.sim.snapshot import SIGNAL_EMERGENCY_BLUE, ActorKind, Role, Snapshot

ONE_WAY = ("interurban", "R1a-R2a_0")  # 3.5 m lanes, a same-direction lane on the left
TWO_WAY = ("downtown", "J0_0-J0_1_2")  # 3.3 m, oncoming lane on the left, parking lane on the right
SINGLE = ("highway", "EB_gore1-S_exit1_0")  # 3.5 m, no lane beside it
CAV_S = 20.0  # [m] the CAV's arc length on its lane


@dataclass
class Actor:
    """A synthetic actor at arc length ``s`` of the scene's lane, ``d`` left of its centre."""

    s: float
    d: float = 0.0
    speed: float = 0.0
    kind: int = ActorKind.CAR
    role: int = Role.SCENARIO
    length: float = 4.5
    width: float = 1.85
    yaw: float = 0.0  # relative to the lane
    siren: bool = False
    name: str = ""


class Scene:
    """One CAV on a lane-following route and actors placed along that lane."""

    def __init__(self, town: str, lane: str, end: float | None = None) -> None:
        self.map: RoadMap = load_map(town)
        self.lane = self.map.lane(lane)
        length = float(self.map.lane_length[self.lane])
        self.route: Route = RoutePlanner(self.map).plan_lanes(
            LanePos(self.lane, 5.0), LanePos(self.lane, end if end is not None else length - 2.0)
        )
        self.width = float(self.map.lane_width[self.lane])

    def pose(self, s: float, d: float = 0.0) -> tuple[np.ndarray, float]:
        lane = np.array([self.lane])
        xy = self.map.index.frenet_to_xy(lane, np.array([s]), np.array([d]))[0]
        return xy, float(self.map.index.heading_at(lane, np.array([s]))[0])

    def snapshot(
        self, t: float, actors: list[Actor], cav_s: float = CAV_S, cav_speed: float = 5.0
    ) -> Snapshot:
        rows = [Actor(cav_s, 0.0, cav_speed, ActorKind.CAR, Role.CAV, 4.89, 2.10, name="cav0"), *actors]
        poses = [self.pose(a.s, a.d) for a in rows]
        return Snapshot.from_rows(
            0,
            t,
            np.array([], str),
            ids=np.array([a.name or f"actor{j}" for j, a in enumerate(rows)]),
            kind=np.array([a.kind for a in rows], np.int8),
            role=np.array([a.role for a in rows], np.int8),
            x=np.array([p[0][0] for p in poses]),
            y=np.array([p[0][1] for p in poses]),
            yaw=np.array([p[1] + a.yaw for p, a in zip(poses, rows, strict=True)]),
            speed=np.array([a.speed for a in rows]),
            length=np.array([a.length for a in rows]),
            width=np.array([a.width for a in rows]),
            signals=np.array([SIGNAL_EMERGENCY_BLUE if a.siren else 0 for a in rows], np.int32),
        )

    def progress(self, cav_s: float = CAV_S) -> int:
        xy, _ = self.pose(cav_s)
        return int(np.argmin(np.linalg.norm(self.route.xy - xy, axis=1)))

    def run(
        self,
        actors: list[Actor],
        config: DetourConfig | None = None,
        ticks: tuple[float, ...] = (0.0, 1.5),
        cav_s: float = CAV_S,
        planner: DetourPlanner | None = None,
    ) -> tuple[DetourPlanner, np.ndarray, Detour]:
        """Updates at each time (the standing clock starts at the first): the planner, the lane arc length
        [m] of each offset point, and the last result."""
        planner = planner or DetourPlanner(self.map, [self.route], config)
        k = self.progress(cav_s)
        out = None
        for t in ticks:
            out = planner.update(self.snapshot(t, actors, cav_s), np.array([0]), np.array([0]), np.array([k]))
        assert out is not None
        s_pts = self.route.distance[k : k + planner.cfg.horizon]
        return planner, s_pts - self.route.distance[k] + cav_s, out


def straight_on(m: RoadMap, lane: int, past: float) -> Route:
    """A route from 5 m along ``lane`` through the junction at its end to ``past`` m beyond it."""
    end = float(m.lane_length[lane])
    h = float(m.index.heading_at(np.array([lane]), np.array([end]))[0])
    exit_xy = m.index.frenet_to_xy(np.array([lane]), np.array([end]))[0]
    goal = exit_xy + past * np.array([np.cos(h), np.sin(h)])
    return RoutePlanner(m).plan(m.index.frenet_to_xy(np.array([lane]), np.array([5.0]))[0], goal)


def plateau(offset: np.ndarray) -> float:
    return float(offset[np.argmax(np.abs(offset))])


# ------------------------------------------------------------------ obstacles on a one-way road
def test_parked_car_30m_ahead_shifts_into_the_left_lane_and_back() -> None:
    """ParkedObstacle (0.35 w right) 30 m ahead: the shift squeezes the left lane's traffic, so it goes to
    that lane's centre (3.5 m); full from 1 m + half the CAV before the car's rear to as far past its
    front, with 8 m ramps either side."""
    scene = Scene(*ONE_WAY)
    car = Actor(CAV_S + 30.0, -0.35 * scene.width)
    _, s, out = scene.run([car])
    offset = out.offset[0]
    assert out.reason[0] == DetourReason.OBSTACLE and not out.waiting[0]
    assert out.actors[0].tolist() == [1]
    rear, front = car.s - 2.25, car.s + 2.25
    full = (s > rear - 2.45 - 1.0 + 0.01) & (s < front + 2.45 + 1.0 - 0.01)
    assert offset[full] == pytest.approx(3.5, abs=0.05)
    assert np.all(offset[s < rear - 3.45 - 8.0 - 0.01] == 0.0)
    assert np.all(offset[s > front + 3.45 + 8.0 + 0.01] == 0.0)
    ramp = (s > front + 3.45) & (s < front + 3.45 + 8.0)
    assert np.all(np.diff(offset[ramp]) < 0.0)  # back over 8 m after the car


def test_just_enough_when_full_lane_change_is_off() -> None:
    """Without the full lane change the shift is the car's reach into the lane + half the CAV + 0.6 m."""
    scene = Scene(*ONE_WAY)
    car = Actor(CAV_S + 30.0, -0.35 * scene.width)
    _, _, out = scene.run([car], DetourConfig(full_lane_change=False))
    expected = -0.35 * scene.width + 0.5 * 1.85 + 0.5 * 2.10 + 0.6
    assert plateau(out.offset[0]) == pytest.approx(expected, abs=0.05)


def test_slow_cyclists_at_the_side_are_passed_within_the_lane() -> None:
    """HazardAtSideLane: bicycles 0.275 w right at 2.8 m/s; the CAV passes them mostly in its own lane
    (1.01 m left, no squeeze of the left lane: no gap check, no full lane change)."""
    scene = Scene(*ONE_WAY)
    bikes = [
        Actor(CAV_S + 25.0 + a, -0.275 * scene.width, 2.8, ActorKind.BICYCLE, length=1.8, width=0.65)
        for a in (0.0, 9.0)
    ]
    _, s, out = scene.run(bikes, ticks=(0.0,))
    assert plateau(out.offset[0]) == pytest.approx(-0.275 * 3.5 + 0.325 + 1.05 + 0.6, abs=0.05)
    assert sorted(out.actors[0].tolist()) == [1, 2]
    assert np.all(out.offset[0][s > CAV_S + 34.0 + 0.9 + 3.45 + 8.0] == 0.0)  # back after the 2nd


def test_cones_use_the_construction_ramp() -> None:
    """ConstructionObstacle's L of cones: ramps of 10.5 m, into the left lane."""
    scene = Scene(*ONE_WAY)
    w = scene.width
    cone = dict(kind=ActorKind.PROP, role=Role.PROP, length=0.4, width=0.4)
    cones = [Actor(CAV_S + 30.0 + a, 0.425 * w, **cone) for a in (2.0, 4.0, 6.0, 8.0)]  # type: ignore[arg-type]
    cones += [Actor(CAV_S + 38.0, 0.425 * w - (k + 1.0), **cone) for k in range(3)]  # type: ignore[arg-type]
    _, s, out = scene.run(cones, ticks=(0.0,))
    offset = out.offset[0]
    assert plateau(offset) == pytest.approx(3.5)
    first = CAV_S + 32.0 - 0.2 - 2.445 - 1.0  # full shift from here
    assert np.all(offset[s < first - 10.5 - 0.01] == 0.0) and np.all(offset[s > first + 0.01][:5] == 3.5)
    rising = (s > first - 10.5) & (s < first)
    assert 0.0 < offset[rising].min() and offset[rising].max() < 3.5


def test_cones_beside_the_path_widen_the_shift() -> None:
    """ConstructionObstacleTwoWays on a two-way road: the board at the lane centre and the cones across
    the lane ask for a shift that would run the CAV into the line of cones along the lane's left edge
    (no obstacle to the unshifted path): the shift grows to clear those too."""
    scene = Scene(*TWO_WAY)
    prop = dict(kind=ActorKind.PROP, role=Role.PROP)
    board = Actor(CAV_S + 30.0, 0.0, length=0.5, width=1.2, **prop)  # type: ignore[arg-type]
    side = [Actor(CAV_S + 37.0 + 2.0 * k, 1.6, length=0.4, width=0.4, **prop) for k in range(4)]  # type: ignore[arg-type]
    across = [Actor(CAV_S + 43.0, 0.6 - k, length=0.4, width=0.4, **prop) for k in range(3)]  # type: ignore[arg-type]
    _, s, out = scene.run([board, *side, *across], ticks=(0.0,))
    assert out.reason[0] == DetourReason.ONCOMING_LANE
    assert plateau(out.offset[0]) == pytest.approx(1.6 + 0.2 + 1.05 + 0.6, abs=0.05)  # not 0.8 + 1.65
    assert set(range(2, 6)) <= set(out.actors[0].tolist())
    beside = (s > CAV_S + 37.0 - 0.2) & (s < CAV_S + 43.0 + 0.2)
    assert np.all(out.offset[0][beside] - 1.05 >= 1.6 + 0.2 + 0.6 - 0.01)  # 0.6 m clear of every cone


# ------------------------------------------------------------------ what is not an obstacle
def test_a_queued_car_is_not_an_obstacle() -> None:
    """A scenario car standing off-centre close behind a moving car (a queue), or standing at the lane
    centre, is followed, not passed."""
    scene = Scene(*ONE_WAY)
    leader = Actor(CAV_S + 36.0, 0.0, 4.0)
    for d in (-0.35 * scene.width, 0.0):
        _, _, out = scene.run([Actor(CAV_S + 30.0, d), leader])
        assert out.reason[0] == DetourReason.NONE and not out.offset.any()


def test_a_car_waiting_at_the_junction_entry_is_not_an_obstacle() -> None:
    """A car standing 3 m before the route's next junction (a red light's stop line), even off-centre,
    is not passed; the same car 30 m before the junction is."""
    m = load_map(TWO_WAY[0])
    lane = m.lane(TWO_WAY[1])
    end = float(m.lane_length[lane])
    route = straight_on(m, lane, 40.0)
    assert route.in_junction.any()
    scene = Scene(*TWO_WAY)
    scene.route = route
    for s, moves in ((end - 3.0 - 2.25, False), (end - 30.0, True)):
        cav_s = s - 25.0
        _, _, out = scene.run([Actor(s, -0.3 * scene.width)], cav_s=cav_s)
        assert bool(out.offset.any()) == moves, s


def test_a_car_that_just_stopped_is_not_yet_an_obstacle() -> None:
    """The standing clock: a scenario car standing for less than ``min_standing`` is not passed."""
    scene = Scene(*ONE_WAY)
    _, _, out = scene.run([Actor(CAV_S + 30.0, -0.35 * scene.width)], ticks=(0.0, 0.5))
    assert not out.offset.any()


def test_no_room_no_shift() -> None:
    """A single-lane ramp without a lane beside it: the car cannot be passed; no shift, BLOCKED."""
    scene = Scene(*SINGLE)
    _, _, out = scene.run([Actor(CAV_S + 30.0, -0.35 * scene.width)])
    assert not out.offset.any() and out.reason[0] == DetourReason.BLOCKED and not out.waiting[0]


# ------------------------------------------------------------------ two-way road: the oncoming lane
class RouteScene(Scene):
    """A scene whose arc length ``s`` is the distance along a route that may cross junctions."""

    def __init__(self, town: str, route: Route) -> None:
        self.map = load_map(town)
        self.route = route
        self.lane = int(route.lane[0])
        self.width = float(self.map.lane_width[self.lane])

    def pose(self, s: float, d: float = 0.0) -> tuple[np.ndarray, float]:
        r = self.route
        h = float(np.interp(s, r.distance, np.unwrap(r.heading)))
        xy = np.array([np.interp(s, r.distance, r.xy[:, 0]), np.interp(s, r.distance, r.xy[:, 1])])
        return xy + d * np.array([-np.sin(h), np.cos(h)]), h


def test_a_late_shift_ramps_from_the_junction_exit() -> None:
    """Cyclists that stopped just past a junction (HazardAtSideLaneTwoWays, bicycles parked after their
    50 m): a CAV standing inside the junction, where its lane has no neighbour, shifts from the junction's
    exit onward instead of giving up (it was BLOCKED there for good)."""
    m = load_map(TWO_WAY[0])
    route = straight_on(m, m.lane(TWO_WAY[1]), 60.0)
    inside = np.flatnonzero(route.in_junction)
    exit_s = float(route.distance[inside[-1] + 1])
    scene = RouteScene(TWO_WAY[0], route)
    w = scene.width
    bike = dict(kind=ActorKind.BICYCLE, length=1.8, width=0.65)
    bikes = [Actor(exit_s + 4.0 + a, -0.275 * w, **bike) for a in (0.0, 9.0)]  # type: ignore[arg-type]
    cav_s = exit_s - 3.0  # in the junction, its front 1.8 m from the first bicycle's rear
    _, s, out = scene.run(bikes, cav_s=cav_s)
    assert out.reason[0] == DetourReason.ONCOMING_LANE
    offset = out.offset[0][: len(s)]  # (the route ends within the horizon)
    assert np.all(offset[s < exit_s - 0.01] == 0.0)  # nothing inside the junction
    assert plateau(offset) == pytest.approx(-0.275 * w + 0.325 + 1.05 + 0.6, abs=0.05)


def test_two_ways_waits_for_the_oncoming_car_then_passes() -> None:
    """ParkedObstacleTwoWays: an oncoming car 40 m away at 10 m/s keeps the CAV waiting, straight in its
    lane, at the start of the ramp; without it the CAV passes through the oncoming lane, just far enough."""
    scene = Scene(*TWO_WAY)
    w = scene.width
    car = Actor(CAV_S + 30.0, -0.35 * w)
    oncoming = Actor(CAV_S + 40.0, w, 10.0, yaw=np.pi)
    _, _, out = scene.run([car, oncoming])
    assert out.waiting[0] and out.reason[0] == DetourReason.ONCOMING_LANE
    assert out.traffic[0].tolist() == [2] and out.actors[0].tolist() == [1]
    assert not out.offset.any()
    ramp_start = car.s - 2.25 - 2.445 - 1.0 - 8.0
    assert out.stop_distance[0] == pytest.approx(ramp_start - CAV_S, abs=0.05)
    assert abs(scene.route.distance[out.stop_index[0]] - (ramp_start - 5.0)) < 1.0  # route starts at 5 m
    _, _, out = scene.run([car])
    assert not out.waiting[0] and out.reason[0] == DetourReason.ONCOMING_LANE
    assert plateau(out.offset[0]) == pytest.approx(-0.35 * w + 0.925 + 1.05 + 0.6, abs=0.05)
    # an oncoming car far enough away (it needs longer than the pass + 10 m) does not hold the CAV
    _, _, out = scene.run([car, Actor(CAV_S + 140.0, w, 5.0, yaw=np.pi)])
    assert not out.waiting[0]


def test_once_out_of_its_lane_the_shift_is_kept() -> None:
    """The CAV entered the ramp with the lane clear. An oncoming car appearing while its side is still in
    its lane stops it (the path back in lane); once its side is over the line, it goes on."""
    scene = Scene(*TWO_WAY)
    w = scene.width
    car = Actor(CAV_S + 30.0, -0.35 * w)
    ramp_start = car.s - 2.25 - 2.445 - 1.0 - 8.0
    oncoming = Actor(ramp_start + 40.0, w, 10.0, yaw=np.pi)

    def drive_to(s_end: float) -> DetourPlanner:
        planner, _, _ = scene.run([car], cav_s=CAV_S)
        for k, s in enumerate(np.arange(ramp_start - 1.0, s_end + 0.01, 0.5)):
            scene.run([car], ticks=(2.0 + 0.05 * k,), cav_s=float(s), planner=planner)
        return planner

    planner = drive_to(ramp_start + 1.0)
    assert planner.held[0]
    _, _, out = scene.run([car, oncoming], ticks=(9.0,), cav_s=ramp_start + 1.5, planner=planner)
    assert out.waiting[0] and not planner.held[0] and not out.offset.any()

    planner = drive_to(ramp_start + 6.0)
    assert planner.held[0]
    _, _, out = scene.run([car, oncoming], ticks=(9.0,), cav_s=ramp_start + 6.5, planner=planner)
    assert not out.waiting[0] and out.offset[0].max() > 1.0
    # past the car the shift ramps back down and is forgotten
    _, _, out = scene.run([], ticks=(5.0,), cav_s=car.s + 20.0, planner=planner)
    assert not out.offset.any() and not planner.held[0]


def test_past_the_obstacle_an_oncoming_car_ahead_cuts_the_way_back_short() -> None:
    """AccidentTwoWays: a flow car spawned ahead after the CAV pulled out stops facing it in the oncoming
    lane. Once the CAV's rear is past the parked car it returns to its lane within 4 m (not the 8 m ramp
    that ends where the oncoming car stands); without the oncoming car the ramp keeps its 8 m."""
    scene = Scene(*TWO_WAY)
    w = scene.width
    car = Actor(CAV_S + 30.0, -0.35 * w)
    ramp_start = car.s - 2.25 - 2.445 - 1.0 - 8.0
    p1 = car.s + 2.25 + 2.445 + 1.0  # the plateau ends here (CAV centre; its rear 1 m past the car)
    here = p1 - 0.5

    def drive_to(s_end: float) -> DetourPlanner:
        planner, _, _ = scene.run([car], cav_s=CAV_S)
        for k, s in enumerate(np.arange(ramp_start - 1.0, s_end + 0.01, 0.5)):
            scene.run([car], ticks=(2.0 + 0.05 * k,), cav_s=float(s), planner=planner)
        return planner

    facing = Actor(here + 2.445 + 6.0 + 2.25, w, 0.0, yaw=np.pi)  # standing, 6 m from the CAV's front
    _, s, out = scene.run([car, facing], ticks=(9.0,), cav_s=here, planner=drive_to(here - 0.5))
    offset = out.offset[0]
    assert offset[np.argmin(np.abs(s - here))] > 1.0  # still out when it starts back
    assert np.all(offset[s >= here + 4.0 + 0.01] == 0.0)
    _, s, out = scene.run([car], ticks=(9.0,), cav_s=here, planner=drive_to(here - 0.5))
    assert out.offset[0][np.argmin(np.abs(s - (here + 4.0)))] > 0.5  # the full ramp: still out at +4 m


def test_opened_door_is_passed() -> None:
    """VehicleOpensDoorTwoWays: the car in the parking lane is no obstacle; its opened door (a prop
    reaching into the lane) is."""
    scene = Scene(*TWO_WAY)
    car = Actor(CAV_S + 30.0, -2.5, name="S1:car")  # its side 1.6 m right of the lane centre
    _, _, out = scene.run([car])
    assert not out.offset.any()
    door = Actor(CAV_S + 29.0, -1.15, kind=ActorKind.CAR, role=Role.PROP, length=1.0, width=0.15, yaw=2.1)
    _, _, out = scene.run([car, door])
    assert out.offset[0].max() > 0.5 and out.actors[0].tolist() == [2]


# ------------------------------------------------------------------ invading cars, emergency vehicles
def test_invading_oncoming_car_moves_the_cav_right() -> None:
    """InvadingTurn: an oncoming car 0.45 m over the centre line 35 m ahead: right by enough to keep
    0.5 m, within the lane and the parking lane beside it."""
    scene = Scene(*TWO_WAY)
    w = scene.width
    inv = Actor(CAV_S + 35.0, w - (0.25 + 0.5 * w - 0.7), 8.0, yaw=np.pi)
    _, _, out = scene.run([inv], ticks=(0.0,))
    inner = inv.d - 0.925
    assert out.reason[0] == DetourReason.INVADING
    assert plateau(out.offset[0]) == pytest.approx(inner - 1.05 - 0.5, abs=0.05)
    assert out.offset[0][0] == 0.0  # the ramp starts at the CAV
    # ordinary oncoming traffic at its lane centre is left alone
    _, _, out = scene.run([Actor(CAV_S + 35.0, w, 8.0, yaw=np.pi)], ticks=(0.0,))
    assert not out.offset.any()


def test_yield_to_an_emergency_vehicle_from_behind() -> None:
    """A siren 30 m behind in the CAV's lane: the CAV moves into the left lane; not while a car is
    beside it there."""
    scene = Scene(*ONE_WAY)
    ev = Actor(CAV_S, 0.0, 25.0, ActorKind.EMERGENCY, length=6.2, width=2.3, siren=True)  # 30 m behind
    _, _, out = scene.run([ev], ticks=(0.0,), cav_s=CAV_S + 30.0)
    assert out.reason[0] == DetourReason.EMERGENCY and plateau(out.offset[0]) == pytest.approx(3.5)
    beside = Actor(CAV_S + 29.0, scene.width, 10.0, role=Role.BACKGROUND)
    _, _, out = scene.run([ev, beside], ticks=(0.0,), cav_s=CAV_S + 30.0)
    assert not out.offset.any() and not out.waiting[0]
    assert out.reason[0] == DetourReason.EMERGENCY and out.traffic[0].tolist() == [2]


# ------------------------------------------------------------------ cost
def test_sixteen_cavs_among_two_hundred_actors_is_cheap() -> None:
    """16 CAVs on interurban's two lanes among 200 background cars and a few obstacles."""
    scene = Scene(*ONE_WAY)
    rng = np.random.default_rng(0)
    routes = [scene.route] * 16
    planner = DetourPlanner(scene.map, routes)
    cav_s = 10.0 + 15.0 * np.arange(16)
    actors = [
        Actor(float(s), float(rng.choice([0.0, scene.width])), 8.0, role=Role.BACKGROUND)
        for s in rng.uniform(5.0, 280.0, 200)
    ]
    actors += [Actor(float(s), -0.35 * scene.width) for s in (60.0, 150.0)]
    base = scene.snapshot(0.0, actors)
    xy = np.array([scene.pose(float(s))[0] for s in cav_s])
    cav = Snapshot.from_rows(
        0,
        0.0,
        np.array([], str),
        ids=np.array([f"cav{j}" for j in range(16)]),
        kind=np.zeros(16, np.int8),
        role=np.full(16, Role.CAV, np.int8),
        x=xy[:, 0],
        y=xy[:, 1],
        yaw=np.full(16, base.yaw[0]),
        speed=np.full(16, 8.0),
        length=np.full(16, 4.89),
        width=np.full(16, 2.1),
    )
    rest = base.select(np.arange(1, base.num_actors))
    fields = ("ids", "kind", "role", "x", "y", "yaw", "speed", "length", "width")
    cols = {f: np.concatenate([getattr(cav, f), getattr(rest, f)]) for f in fields}
    rows, index = np.arange(16), np.arange(16)
    progress = np.array([scene.progress(float(s)) for s in cav_s])
    times = []
    for t in range(40):
        snap = Snapshot.from_rows(t, 0.05 * t + 2.0 * (t > 0), np.array([], str), **cols)
        t0 = time.perf_counter()
        planner.update(snap, rows, index, progress)
        times.append(time.perf_counter() - t0)
    median = float(np.median(times[5:]))
    print(f"detour update, 16 CAVs, {snap.num_actors} actors: median {1e3 * median:.3f} ms")
    assert median < 5e-3  # typical ~0.5 ms; generous for a loaded CI machine


# ------------------------------------------------------------------ closed loop
class DetourFollower(Agent):
    """Test driver: pure pursuit on the shifted path at 8 m/s, stopping where the planner waits and for
    actors in the shifted path's corridor (what the expert's IDM will do)."""

    observations: ClassVar[frozenset[Observation]] = frozenset({Observation.PRIVILEGED})
    CRUISE = 8.0  # [m/s]
    DECEL = 3.0  # [m/s^2]

    def setup(self, route: RouteSetup) -> None:
        assert route.road_map is not None
        self.routes = [c.dense_route for c in route.cavs]
        assert all(r is not None for r in self.routes)
        self.planner = DetourPlanner(route.road_map, self.routes)  # type: ignore[arg-type]
        self.progress = np.zeros(len(self.routes), np.int64)
        self.params = VehicleParams()
        self.offsets: list[np.ndarray] = []

    def run_step(self, obs: Observations) -> Controls:
        snap = obs.snapshot
        assert snap is not None
        rows, index = snap.cav_rows()
        row_of = dict(zip(index.tolist(), rows.tolist(), strict=True))
        cav_rows = np.array([row_of[int(i)] for i in obs.cav_index], np.int64)
        n = len(cav_rows)
        steer, throttle, brake = np.zeros(n), np.zeros(n), np.zeros(n)
        for c, i in enumerate(obs.cav_index.tolist()):
            r = self.routes[i]
            assert r is not None
            k0 = int(self.progress[i])
            pos = np.array([obs.x[c], obs.y[c]])
            self.progress[i] = k0 + int(np.argmin(np.linalg.norm(r.xy[k0 : k0 + 20] - pos, axis=1)))
        detour = self.planner.update(snap, cav_rows, obs.cav_index, self.progress[obs.cav_index])
        for c, i in enumerate(obs.cav_index.tolist()):
            r = self.routes[i]
            assert r is not None
            k = np.minimum(self.progress[i] + np.arange(80), len(r) - 1)
            h = r.heading[k]
            path = r.xy[k] + detour.offset[c][:, None] * np.stack([-np.sin(h), np.cos(h)], axis=1)
            if i == 0:
                self.offsets.append(detour.offset[c, :1].copy())
            pos, yaw, v = np.array([obs.x[c], obs.y[c]]), obs.yaw[c], obs.speed[c]
            look = 4.0 + 0.8 * v
            far = np.linalg.norm(path - pos, axis=1) >= look
            j = int(np.argmax(far)) if far.any() else len(path) - 1
            rel = path[j] - pos
            lx = np.cos(yaw) * rel[0] + np.sin(yaw) * rel[1]
            ly = -np.sin(yaw) * rel[0] + np.cos(yaw) * rel[1]
            wheel = np.arctan(self.params.wheelbase * 2.0 * ly / max(lx * lx + ly * ly, 1e-6))
            steer[c] = np.clip(-wheel / self.params.max_steer, -1.0, 1.0)
            gap = np.inf if not detour.waiting[c] else detour.stop_distance[c]
            others = np.ones(snap.num_actors, bool)
            others[cav_rows[c]] = False
            for a in np.flatnonzero(others):
                d = np.linalg.norm(path - np.array([snap.x[a], snap.y[a]]), axis=1)
                hit = np.flatnonzero(d < 0.5 * snap.width[a] + 1.05 + 0.3)
                if len(hit):
                    gap = min(gap, float(hit[0]) - 0.5 * snap.length[a] - 2.45 - 3.0)
            remaining = float(r.distance[-1] - r.distance[k[0]])
            target = min(self.CRUISE, np.sqrt(2.0 * self.DECEL * max(min(gap, remaining), 0.0)))
            error = target - v
            throttle[c] = np.clip(0.6 * error, 0.0, 1.0)
            brake[c] = 0.0 if error > -0.3 else min(1.0, -0.35 * error)
            if target < 0.1:
                throttle[c], brake[c] = 0.0, 1.0
        return Controls(steer=steer, throttle=throttle, brake=brake)


def closed_loop(
    kind: str,
    town: str,
    lane: str,
    tmp_path: Path,
    params: dict[str, object],
    background: bool = False,
    trigger_s: float = 20.0,
) -> tuple[RoadMap, object, object]:
    """CAV 0 follows one lane from 10 m to 200 m with the follower; the scenario triggers at
    ``trigger_s``."""
    from cmudrive.bench import EvalConfig
    from cmudrive.sim.background import BackgroundConfig
    from tests.scenario_helpers import EMPTY, lane_cav, run, scenario, trigger

    m = load_map(town)
    i = m.lane(lane)
    end = min(200.0, float(m.lane_length[i]) - 3.0)
    spec = RouteSpec(
        f"detour_{kind}",
        town,
        "ClearNoon",
        0,
        (lane_cav(m, 0, lane, 10.0, end),),
        (scenario(kind, trigger(m, lane, trigger_s), **params),),  # type: ignore[arg-type]
    )
    config = EvalConfig(background=BackgroundConfig() if background else EMPTY, tick_cap=2000)
    result, log = run(spec, tmp_path, agent=DetourFollower, config=config)
    return m, result, log


def contacts(result: object) -> list[str | None]:
    cav = result.cavs[0]  # type: ignore[attr-defined]
    return [inf.actor for key, ev in cav.infractions.items() if key.startswith("collisions") for inf in ev]


@pytest.mark.parametrize(
    ("kind", "town", "lane", "first"),
    [("ParkedObstacle", *ONE_WAY, "S1:car"), ("AccidentTwoWays", *TWO_WAY, "S1:police")],
)
def test_closed_loop_the_cav_passes_the_obstacle_without_contact(
    kind: str, town: str, lane: str, first: str, tmp_path: Path
) -> None:
    """The scenario engine places the obstacle 40 m past the trigger; the follower goes around it on the
    left (and, on the two-way road, past the oncoming flow's cars) without contact and finishes."""
    from tests.scenario_helpers import cav_track, frenet, track

    params: dict[str, object] = {"distance": "40"}
    if kind.endswith("TwoWays"):
        params["frequency"] = {"from": "40", "to": "60"}
    m, result, log = closed_loop(kind, town, lane, tmp_path, params)
    assert contacts(result) == []
    assert result.cavs[0].route_completion == pytest.approx(100.0)  # type: ignore[attr-defined]
    s_obstacle, _ = frenet(m, lane, track(log, first)[0, :2])  # type: ignore[arg-type]
    s, d = frenet(m, lane, cav_track(log, 0)[:, :2])  # type: ignore[arg-type]
    beside = np.abs(s - s_obstacle[0]) < 2.0
    assert beside.any() and d[beside].min() > 1.0


@pytest.mark.slow
def test_closed_loop_waits_for_oncoming_traffic(tmp_path: Path) -> None:
    """ParkedObstacleTwoWays with background traffic and a dense oncoming flow (gaps 20-40 m): the CAV
    stands at the start of the ramp until a gap opens, then passes without contact."""
    from tests.scenario_helpers import cav_track, frenet

    params: dict[str, object] = {"distance": "40", "frequency": {"from": "20", "to": "40"}}
    m, result, log = closed_loop("ParkedObstacleTwoWays", *TWO_WAY, tmp_path, params, background=True)
    assert contacts(result) == []
    assert result.cavs[0].route_completion == pytest.approx(100.0)  # type: ignore[attr-defined]
    tr = cav_track(log, 0)  # type: ignore[arg-type]
    s, _ = frenet(m, TWO_WAY[1], tr[:, :2])
    standing = tr[:, 3] < 0.1
    ramp_start = 20.0 + 40.0 - 2.25 - 2.445 - 1.0 - 8.0
    waited = np.count_nonzero(standing & (np.abs(s - ramp_start) < 3.0))  # 13 ticks when written
    assert waited >= 5


def test_closed_loop_yields_to_the_emergency_vehicle(tmp_path: Path) -> None:
    """YieldToEmergencyVehicle (40 m behind T): the CAV moves into the left lane, the ambulance passes,
    no failure to yield, no contact."""
    from tests.scenario_helpers import cav_track, frenet

    m, result, log = closed_loop(
        "YieldToEmergencyVehicle", *ONE_WAY, tmp_path, {"distance": "40"}, trigger_s=60.0
    )
    cav = result.cavs[0]  # type: ignore[attr-defined]
    assert cav.infractions["yield_emergency_vehicle_infractions"] == [] and contacts(result) == []
    _, d = frenet(m, ONE_WAY[1], cav_track(log, 0)[:, :2])  # type: ignore[arg-type]
    assert np.nanmax(d) > 3.0


def test_closed_loop_keeps_right_of_invading_cars(tmp_path: Path) -> None:
    """InvadingTurn (offset 0.3 m): the CAV keeps right and meets the invading cars without contact."""
    from tests.scenario_helpers import cav_track, frenet

    m, result, log = closed_loop("InvadingTurn", *TWO_WAY, tmp_path, {"distance": "40", "offset": "0.3"})
    assert contacts(result) == []
    _, d = frenet(m, TWO_WAY[1], cav_track(log, 0)[:, :2])  # type: ignore[arg-type]
    assert np.nanmin(d) < -0.3
