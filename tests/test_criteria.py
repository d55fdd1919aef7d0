"""Route criteria on the mini network: one small hand-built scene per criterion, moved tick by tick.

Scenes are synthetic snapshots (no SUMO): CAVs are placed along their dense routes at a chosen speed, other
actors where the scene needs them, collisions come from ``detect_collisions``. Layout of the mini network
(tests/conftest.py): signalised junction C at (200, 0), priority-stop T-junction N at (200, 200), lanes
WC_1/WC_2 eastbound at y = -4.8/-1.6 ending at x = 192.8, two-way road C-E (CE_1 eastbound at y = -1.6,
EC_1 westbound at y = +1.6), CN_1 northbound at x = 201.6 with a stop sign at y = 192.8.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field

import numpy as np
import pytest

from cmudrive.bench.criteria import CriteriaConfig, RouteCriteria
from cmudrive.bench.criteria.collisions import CollisionMemory
from cmudrive.bench.criteria.lanes import lane_state
from cmudrive.bench.records import (
    STATUS_BLOCKED,
    STATUS_COMPLETED,
    STATUS_DEVIATED,
    STATUS_PERFECT,
    STATUS_RUNNING,
    STATUS_TICK_CAP,
    STATUS_TIMEOUT,
    CavResult,
)
from cmudrive.maps import RoadMap, StaticScenery
from cmudrive.maps.routing import LanePos, Route, RoutePlanner
from cmudrive.sim.collisions import detect_collisions
from cmudrive.sim.snapshot import ActorKind, Role, Snapshot

DT = 0.05  # [s]
CAV_LENGTH, CAV_WIDTH = 4.89, 2.10  # [m]
LIMIT = 13.89  # [m/s] speed limit of the W-C-E roads
N_SIGNALS = 16  # signals of light C; W approach: WC_1 -> CS_0 is 10, WC_1 -> CE_1 is 11, WC_2 -> CN_1 is 12
ALL_GREEN = "G" * N_SIGNALS
ALL_RED = "r" * N_SIGNALS


def with_signals(base: str, **signals: str) -> str:
    """Light C's state string with some signals (keyword s<index>) changed."""
    chars = list(base)
    for name, char in signals.items():
        chars[int(name[1:])] = char
    return "".join(chars)


def plan(mini: RoadMap, lane: str, s: float, goal_lane: str, goal_s: float) -> Route:
    return RoutePlanner(mini).plan_lanes(LanePos(mini.lane(lane), s), LanePos(mini.lane(goal_lane), goal_s))


def pose_at(route: Route, d: float) -> tuple[float, float, float]:
    """(x, y, yaw) at distance d [m] along a dense route, straight on past its end."""
    x = float(np.interp(d, route.distance, route.xy[:, 0]))
    y = float(np.interp(d, route.distance, route.xy[:, 1]))
    yaw = float(np.interp(d, route.distance, np.unwrap(route.heading)))
    beyond = max(d - route.length, 0.0)
    return x + beyond * np.cos(yaw), y + beyond * np.sin(yaw), yaw


@dataclass
class Actor:
    id: str
    x: float
    y: float
    yaw: float = 0.0
    speed: float = 0.0
    kind: int = ActorKind.CAR
    role: int = Role.BACKGROUND
    length: float = 4.5
    width: float = 1.9


@dataclass
class Scene:
    """A route's criteria fed with synthetic snapshots, one :meth:`tick` per 50 ms."""

    mini: RoadMap
    routes: list[Route]
    config: CriteriaConfig = field(default_factory=CriteriaConfig)
    step: int = 0

    def __post_init__(self) -> None:
        self.ids = [f"cav{i}" for i in range(len(self.routes))]
        # no static scenery: these scenes test the other criteria (layout collisions: test_scenery.py)
        self.criteria = RouteCriteria(
            self.mini, self.routes, self.ids, self.config, DT, scenery=StaticScenery.empty()
        )

    def tick(
        self,
        cavs: list[tuple[float, float, float, float]],
        others: tuple[Actor, ...] = (),
        tls: str = ALL_GREEN,
    ) -> None:
        """One tick with the CAVs at (x, y, yaw, speed) (finished CAVs are left out, as the world does)."""
        self.step += 1
        alive = ~self.criteria.finished()
        actors = [
            Actor(c, *pose, kind=ActorKind.CAR, role=Role.CAV, length=CAV_LENGTH, width=CAV_WIDTH)
            for c, pose, on in zip(self.ids, cavs, alive, strict=True)
            if on
        ] + list(others)
        snap = Snapshot.from_rows(
            self.step,
            self.step * DT,
            np.array([tls]),
            **{
                ("ids" if f == "id" else f): np.array([getattr(a, f) for a in actors])
                for f in Actor.__dataclass_fields__
            },
        )
        self.criteria.update(snap, detect_collisions(snap))

    def drive(
        self, speed: float, start: float = 0.0, until: float | None = None, tls: str = ALL_GREEN
    ) -> None:
        """Drive the single CAV along its route at ``speed`` [m/s] from distance ``start`` to ``until``
        (default: past the end), or until it finishes."""
        route = self.routes[0]
        end = route.length + 3.0 if until is None else until
        d = start
        while d <= end + 1e-9 and not self.criteria.finished()[0]:
            self.tick([(*pose_at(route, d), speed)], tls=tls)
            d += speed * DT

    def stand(self, ticks: int, at: float = 0.0) -> None:
        for _ in range(ticks):
            self.tick([(*pose_at(self.routes[0], at), 0.0)])

    def result(self, cav: int = 0) -> CavResult:
        return self.criteria.results()[cav]


def counts(result: CavResult) -> dict[str, int]:
    return {k: len(v) for k, v in result.infractions.items() if v}


@pytest.fixture(scope="module")
def through_c(mini: RoadMap) -> Route:
    """WC_1 (x = 140) straight through C onto CE_1 (x = 257): ~117 m over the signalised junction."""
    return plan(mini, "WC_1", 140.0, "CE_1", 50.0)


@pytest.fixture(scope="module")
def east(mini: RoadMap) -> Route:
    """CE_1 from x = 212 to x = 392: 180 m straight east on a two-way road."""
    return plan(mini, "CE_1", 5.0, "CE_1", 185.0)


# ---- route completion -------------------------------------------------------------------------------


def test_cav_driving_its_whole_route_is_perfect(mini: RoadMap, through_c: Route) -> None:
    scene = Scene(mini, [through_c])
    finished_at = []
    route = through_c
    d = 0.0
    while not scene.criteria.finished()[0]:
        scene.tick([(*pose_at(route, d), 10.0)])
        if scene.criteria.newly_finished()[0]:
            finished_at.append(d)
        d += 0.5
    assert len(finished_at) == 1 and route.length - 2.0 <= finished_at[0] <= route.length + 1.0
    result = scene.result()
    assert result.status == STATUS_PERFECT
    assert result.route_completion == 100.0 and result.infraction_score == 1.0
    assert counts(result) == {}
    assert result.route_length == pytest.approx(route.length)
    assert json.loads(json.dumps(asdict(result)))["status"] == STATUS_PERFECT  # plain JSON types


def test_cav_stopped_halfway_has_half_the_route_completed(mini: RoadMap, through_c: Route) -> None:
    scene = Scene(mini, [through_c])
    scene.drive(8.0, until=through_c.length / 2)
    scene.stand(100, at=through_c.length / 2)
    result = scene.result()
    assert result.status == STATUS_RUNNING and not scene.criteria.finished()[0]
    assert result.route_completion == pytest.approx(50.0, abs=2.0)


# ---- collisions -------------------------------------------------------------------------------------


def test_pedestrian_collision_halves_the_score(mini: RoadMap, east: Route) -> None:
    scene = Scene(mini, [east])
    for k in range(40):
        x, y, yaw = pose_at(east, 0.4 * k)
        walker = Actor("ped1", x + 2.0, y, speed=1.0, kind=ActorKind.PEDESTRIAN, length=0.5, width=0.5)
        scene.tick([(x, y, yaw, 8.0)], others=(walker,) if k == 20 else ())
    result = scene.result()
    assert counts(result) == {"collisions_pedestrian": 1}
    assert result.infraction_score == pytest.approx(0.5)
    hit = result.infractions["collisions_pedestrian"][0]
    assert hit.actor == "ped1" and hit.factor == 0.5 and hit.tick == 21 and hit.time == pytest.approx(1.05)


def test_same_car_counts_once_within_5_s_and_again_after(mini: RoadMap, east: Route) -> None:
    """Car bg1 touches the CAV (5 m/s) at 1 s, 3 s and 8 s; car bg2 touches it 0.1 s after the first hit."""
    scene = Scene(mini, [east])
    touch = {20: "bg1", 22: "bg2", 60: "bg1", 160: "bg1"}  # tick -> who is alongside, overlapping 0.5 m
    for k in range(200):
        x, y, yaw = pose_at(east, 0.25 * k)
        others = (Actor(touch[k], x, y + 1.5, speed=5.0),) if k in touch else ()
        scene.tick([(x, y, yaw, 5.0)], others=others)
    result = scene.result()
    hits = result.infractions["collisions_vehicle"]
    assert [(h.actor, h.tick) for h in hits] == [("bg1", 21), ("bg1", 161)]
    assert result.infraction_score == pytest.approx(0.6**2)


def test_collision_while_standing_is_ignored_but_the_moving_cav_is_charged(mini: RoadMap) -> None:
    standing = plan(mini, "WC_2", 100.0, "WC_2", 180.0)
    moving = plan(mini, "WC_1", 97.5, "WC_1", 180.0)  # alongside cav1 (x = 100) after 10 ticks
    scene = Scene(mini, [moving, standing])
    for k in range(30):
        x, y, yaw = pose_at(moving, 0.25 * k)
        if k == 10:
            y += 1.8  # swerves into cav1, 1.4 m to the side: the boxes overlap by 0.7 m
        scene.tick([(x, y, yaw, 5.0), (*pose_at(standing, 0.0), 0.0)])
    car = Actor("bg1", 100.0, -0.5, speed=3.0)  # a car brushes the standing CAV
    scene.tick([(*pose_at(moving, 10.0), 5.0), (*pose_at(standing, 0.0), 0.0)], others=(car,))
    moving_result, standing_result = scene.criteria.results()
    assert [(h.key, h.actor) for h in moving_result.infractions["collisions_vehicle"]] == [
        ("collisions_vehicle", "cav1")
    ]
    assert standing_result.infractions["collisions_vehicle"] == []
    assert standing_result.infraction_score == 1.0


def test_two_moving_cavs_that_collide_are_both_charged(mini: RoadMap) -> None:
    right = plan(mini, "WC_1", 90.0, "WC_1", 180.0)
    left = plan(mini, "WC_2", 90.0, "WC_2", 180.0)
    scene = Scene(mini, [right, left])
    for k in range(20):
        (x0, y0, yaw0), (x1, y1, yaw1) = pose_at(right, 0.4 * k), pose_at(left, 0.4 * k)
        squeeze = 1.0 if k == 10 else 0.0  # both drift 1 m towards each other: 1.2 m apart, 2.1 m wide
        scene.tick([(x0, y0 + squeeze, yaw0, 8.0), (x1, y1 - squeeze, yaw1, 8.0)])
    charged = [[h.actor for h in r.infractions["collisions_vehicle"]] for r in scene.criteria.results()]
    assert charged == [["cav1"], ["cav0"]]


def test_collision_with_a_prop_is_layout(mini: RoadMap, east: Route) -> None:
    scene = Scene(mini, [east])
    x, y, yaw = pose_at(east, 10.0)
    cone = Actor("cone1", x + 2.3, y, kind=ActorKind.PROP, role=Role.PROP, length=0.4, width=0.4)
    scene.tick([(x, y, yaw, 6.0)], others=(cone,))
    assert counts(scene.result()) == {"collisions_layout": 1}
    assert scene.result().infraction_score == pytest.approx(0.65)


# ---- red lights -------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("goal", "tls", "ran"),
    [
        (("CE_1", 50.0), with_signals(ALL_GREEN, s11="r"), True),  # straight on red
        (("CE_1", 50.0), with_signals(ALL_RED, s11="G"), False),  # straight on green
        (("CE_1", 50.0), with_signals(ALL_GREEN, s11="y"), False),  # yellow is not red
        (("CS_0", 50.0), with_signals(ALL_RED, s10="G"), False),  # right turn on its green arrow
        (("CS_0", 50.0), with_signals(ALL_GREEN, s10="r"), True),  # right turn on red, straight green
    ],
)
def test_red_light_is_charged_once_when_crossing_on_red(
    mini: RoadMap, goal: tuple[str, float], tls: str, ran: bool
) -> None:
    route = plan(mini, "WC_1", 150.0, *goal)
    scene = Scene(mini, [route])
    scene.drive(8.0, until=80.0, tls=tls)  # from x = 150 well into the exit road
    result = scene.result()
    assert counts(result) == ({"red_light": 1} if ran else {})
    if ran:
        hit = result.infractions["red_light"][0]
        assert hit.factor == 0.7
        # the rear segment (2.0-3.4 m behind the centre) reaches the stop line at x = 192.8
        assert 194.5 <= hit.x <= 196.5


def test_standing_at_a_red_light_then_going_on_green_is_clean(mini: RoadMap, through_c: Route) -> None:
    scene = Scene(mini, [through_c])
    stop = 52.8 - 0.5 * CAV_LENGTH - 1.0  # front bumper 1 m before the line at x = 192.8
    scene.drive(8.0, until=stop, tls=ALL_RED)
    for _ in range(100):
        scene.tick([(*pose_at(through_c, stop), 0.0)], tls=ALL_RED)
    scene.drive(8.0, start=stop)
    assert scene.result().status == STATUS_PERFECT


# ---- stop signs -------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("gap", "ran"),
    [
        (None, True),  # rolls through at 5 m/s
        (1.0, False),  # stops with the front bumper 1 m before the line
        (3.5, False),  # ... 3.5 m before: still inside the 4 m stop area
        (6.0, True),  # ... 6 m before: outside the stop area, then rolls through
    ],
)
def test_stop_sign_needs_a_stop_inside_the_stop_area(mini: RoadMap, gap: float | None, ran: bool) -> None:
    route = plan(mini, "CN_1", 150.0, "NNE_1", 30.0)  # north on CN_1 (stop line at y = 192.8), right turn
    scene = Scene(mini, [route])
    line = 192.8 - 160.4  # [m] route distance of the stop line
    if gap is not None:
        stop = line - gap - 0.5 * CAV_LENGTH
        scene.drive(5.0, until=stop)
        scene.stand(10, at=stop)
        scene.drive(5.0, start=stop)
    else:
        scene.drive(5.0)
    result = scene.result()
    assert counts(result) == ({"stop_infraction": 1} if ran else {})
    assert result.infraction_score == pytest.approx(0.8 if ran else 1.0)
    if ran:
        assert result.infractions["stop_infraction"][0].y == pytest.approx(
            192.8, abs=0.5
        )  # centre at the line


def test_stop_sign_is_ignored_when_driving_against_the_lane(mini: RoadMap) -> None:
    """Northbound on the southbound lane NC_1 (x = 198.4) past N: no stop sign applies to that lane."""
    route = plan(mini, "CN_1", 150.0, "NNE_1", 30.0)
    scene = Scene(mini, [route])
    for k in range(120):
        scene.tick([(198.4, 170.0 + 0.25 * k, np.pi / 2, 5.0)])
    assert "stop_infraction" not in counts(scene.result())


# ---- outside route lanes ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("y_off", "wrong_check", "factor"),
    [
        (3.2, True, 0.8),  # on the opposite lane EC_1 for 20 % of the route
        (3.2, False, None),  # the same with the wrong-direction check off: no penalty
        (-6.0, False, 0.8),  # off every lane (6 m right of the lane centre), whatever the switch
    ],
)
def test_outside_route_lanes_factor_is_the_share_of_the_route(
    mini: RoadMap, east: Route, y_off: float, wrong_check: bool, factor: float | None
) -> None:
    scene = Scene(mini, [east])
    scene.criteria.set_wrong_direction_check(0, wrong_check)
    d = 0.0
    while not scene.criteria.finished()[0]:
        x, y, yaw = pose_at(east, d)
        off = 60.0 <= d < 96.0  # 36 m of the 180 m route
        scene.tick([(x, y + (y_off if off else 0.0), yaw, 10.0)])
        d += 0.5
    result = scene.result()
    outside = result.infractions["outside_route_lanes"]
    if factor is None:
        assert outside == [] and result.status == STATUS_PERFECT
    else:
        assert len(outside) == 1 and result.status == STATUS_COMPLETED
        assert outside[0].factor == pytest.approx(factor, abs=0.01)
        assert result.infraction_score == pytest.approx(outside[0].factor)


def test_junction_area_counts_as_on_the_road(mini: RoadMap) -> None:
    """Cutting the right turn N -> W at C through the junction's corner, 3.6 m from every junction lane,
    is inside C's outline and not outside the lanes; the same distance from a lane outside any junction
    is; driving against EC_1 is wrong-way, driving through C in any direction is not."""
    xy = np.array([[194.5, 9.0], [194.5, 14.0], [300.0, 1.6], [200.0, 0.0]])
    yaw = np.array([-0.75 * np.pi, -0.5 * np.pi, 0.0, 0.25 * np.pi])
    outside, wrong = lane_state(mini, xy, yaw, mini.index.nearest_lane(xy), CriteriaConfig())
    assert outside.tolist() == [False, True, False, False]
    assert wrong.tolist() == [False, False, True, False]


# ---- route deviation --------------------------------------------------------------------------------


def test_cav_35_m_off_its_route_has_deviated(mini: RoadMap, east: Route) -> None:
    scene = Scene(mini, [east])
    scene.drive(10.0, until=50.0)
    x, y, yaw = pose_at(east, 50.5)
    scene.tick([(x, y + 35.0, yaw, 10.0)])
    assert scene.criteria.finished()[0] and scene.criteria.newly_finished()[0]
    result = scene.result()
    assert result.status == STATUS_DEVIATED
    assert counts(result) == {"route_dev": 1, "outside_route_lanes": 1}
    assert result.route_completion == pytest.approx(50.0 / 180.0 * 100.0, abs=1.0)
    scene.tick([(x, y, yaw, 10.0)])  # a finished CAV is no longer evaluated
    assert not scene.criteria.newly_finished()[0] and scene.result().status == STATUS_DEVIATED


def test_driving_20_m_beside_the_route_deviates_after_30_percent(mini: RoadMap, east: Route) -> None:
    scene = Scene(mini, [east])
    d = 0.0
    while not scene.criteria.finished()[0] and d < 200.0:
        x, y, yaw = pose_at(east, d)
        scene.tick([(x, y + 20.0, yaw, 10.0)])
        d += 0.5
    result = scene.result()
    assert result.status == STATUS_DEVIATED
    assert 30.0 <= result.route_completion <= 32.0  # failed as soon as off-route progress passed 30 %


# ---- blocked and timeouts ---------------------------------------------------------------------------


def test_standing_60_05_s_is_blocked_and_59_9_s_is_not(mini: RoadMap, east: Route) -> None:
    scene = Scene(mini, [east])
    scene.stand(1198)  # 59.90 s
    assert not scene.criteria.finished()[0]
    scene.stand(2)  # 60.00 s: not yet longer than 60 s
    assert not scene.criteria.finished()[0]
    scene.stand(1)  # 60.05 s
    assert scene.criteria.newly_finished()[0]
    result = scene.result()
    assert result.status == STATUS_BLOCKED and counts(result) == {"vehicle_blocked": 1}
    assert result.infraction_score == 1.0  # ends the evaluation, no factor


def test_blocked_is_suspended_while_a_scenario_timeout_runs(mini: RoadMap, east: Route) -> None:
    scene = Scene(mini, [east])
    scene.stand(600)
    scene.criteria.suspend_blocked(0, True)
    scene.stand(1300)  # 65 s, suspended
    assert not scene.criteria.finished()[0]
    scene.criteria.suspend_blocked(0, False)  # the clock restarts from zero
    scene.stand(1200)
    assert not scene.criteria.finished()[0]
    scene.stand(1)
    assert scene.result().status == STATUS_BLOCKED


def test_route_timeout_fires_at_the_base_budget_without_progress(mini: RoadMap, east: Route) -> None:
    scene = Scene(mini, [east], CriteriaConfig(route_timeout_base=10.0))
    scene.criteria.suspend_blocked(0, True)
    scene.stand(200)  # 10.00 s
    assert not scene.criteria.finished()[0]
    scene.stand(1)
    result = scene.result()
    assert result.status == STATUS_TIMEOUT and counts(result) == {"route_timeout": 1}


def test_route_timeout_budget_grows_with_progress(mini: RoadMap, east: Route) -> None:
    """At 1 m/s each metre earns 1 / (0.1 x 13.89 m/s) = 0.72 s, so t = 20 s + 0.72 t fires at t = 71.4 s;
    the route index trails the CAV by up to 1 m (1 m point spacing), which brings it forward to 68.8 s."""
    scene = Scene(mini, [east], CriteriaConfig(route_timeout_base=20.0))
    scene.drive(1.0)
    per_metre = 1.0 / (0.1 * LIMIT)  # [s/m]
    latest = 20.0 / (1.0 - per_metre)
    earliest = (20.0 - per_metre * (1.0 + DT)) / (1.0 - per_metre)
    assert scene.result().status == STATUS_TIMEOUT
    assert earliest <= scene.step * DT <= latest


def test_end_route_fails_only_the_running_cavs(mini: RoadMap, east: Route) -> None:
    short = plan(mini, "WC_1", 5.0, "WC_1", 25.0)  # 20 m, on another road than ``east``
    scene = Scene(mini, [short, east])
    for k in range(80):
        d = 0.5 * k
        scene.tick([(*pose_at(short, d), 10.0), (*pose_at(east, d), 10.0)])
    assert scene.criteria.finished().tolist() == [True, False]
    scene.criteria.end_route(STATUS_TICK_CAP)
    assert scene.criteria.finished().all() and scene.criteria.newly_finished().tolist() == [False, True]
    done, cut = scene.criteria.results()
    assert done.status == STATUS_PERFECT and done.route_completion == 100.0
    assert cut.status == STATUS_TICK_CAP and cut.route_completion == pytest.approx(39.5 / 180 * 100, abs=1.0)
    with pytest.raises(ValueError, match="failure status"):
        scene.criteria.end_route(STATUS_PERFECT)


# ---- minimum speed ----------------------------------------------------------------------------------


def test_min_speed_is_100_without_traffic(mini: RoadMap, east: Route) -> None:
    scene = Scene(mini, [east])
    scene.drive(10.0)
    result = scene.result()
    assert result.min_speed_checkpoints == [100.0] * 20
    assert result.infractions["min_speed_infractions"] == []


def test_min_speed_is_50_when_nearby_traffic_drives_twice_as_fast(mini: RoadMap, east: Route) -> None:
    """Only background vehicles within 50 m count: not the far car, the pedestrian or the scenario car."""
    scene = Scene(mini, [east])
    d = 0.0
    while not scene.criteria.finished()[0]:
        x, y, yaw = pose_at(east, d)
        others = (
            Actor("fast", x + 20.0, y + 3.2, yaw=np.pi, speed=20.0),
            Actor("far", x + 80.0, y + 3.2, speed=0.0),
            Actor("walker", x, y - 3.0, speed=1.0, kind=ActorKind.PEDESTRIAN, length=0.5, width=0.5),
            Actor("adversary", x - 20.0, y, speed=0.0, role=Role.SCENARIO),
        )
        scene.tick([(x, y, yaw, 10.0)], others=others)
        d += 0.5
    result = scene.result()
    assert result.min_speed_checkpoints == pytest.approx([50.0] * 20)
    assert len(result.infractions["min_speed_infractions"]) == 20
    assert result.infraction_score == 1.0 and result.status == STATUS_PERFECT  # recorded only


# ---- scenario hooks ---------------------------------------------------------------------------------


def test_yield_to_emergency_vehicle_is_charged_only_when_still_ahead_of_it(
    mini: RoadMap, east: Route
) -> None:
    scene = Scene(mini, [east, east])
    scene.tick([(224.0, -1.6, 0.0, 5.0), (214.0, -1.6, 0.0, 5.0)])
    ev_xy, ev_heading = (219.0, 1.0), 0.0  # heading east, between the two CAVs, on the other lane
    assert scene.criteria.record_yield_to_emergency_vehicle(0, ev_xy, ev_heading, actor="ambulance1")
    assert not scene.criteria.record_yield_to_emergency_vehicle(1, ev_xy, ev_heading)
    ahead, behind = scene.criteria.results()
    assert [i.actor for i in ahead.infractions["yield_emergency_vehicle_infractions"]] == ["ambulance1"]
    assert ahead.infraction_score == pytest.approx(0.7)
    assert counts(behind) == {} and behind.infraction_score == 1.0


def test_config_and_inputs_are_checked(mini: RoadMap, east: Route) -> None:
    with pytest.raises(ValueError, match="blocked_time"):
        CriteriaConfig(blocked_time=-1.0)
    with pytest.raises(TypeError):
        CriteriaConfig(blocked_seconds=60.0)  # type: ignore[call-arg]
    with pytest.raises(ValueError, match="one route per CAV"):
        RouteCriteria(mini, [east, east], ["cav0"])


def test_scenario_timeout_hook_records_its_penalty(mini: RoadMap, east: Route) -> None:
    scene = Scene(mini, [east])
    scene.drive(5.0, until=10.0)
    scene.criteria.record_scenario_timeout(0, tick=30, message="ScenarioTimeout of Accident expired")
    hit = scene.result().infractions["scenario_timeouts"][0]
    assert (hit.tick, hit.time, hit.factor) == (30, pytest.approx(1.5), 0.7)
    assert scene.result().infraction_score == pytest.approx(0.7)
    with pytest.raises(IndexError):
        scene.criteria.suspend_blocked(3, True)


# ---- differences from upstream that were fixed (issue: Bench2Drive routes on the CARLA towns) -------


def test_open_min_speed_checkpoint_is_dropped_below_95_percent(mini: RoadMap, east: Route) -> None:
    """Upstream drops the checkpoint the CAV is still in unless it did more than 95 % of its route: a CAV
    that drives 12 m (at the traffic's speed) and then stands 60 s keeps only its closed parts, 100 %."""
    scene = Scene(mini, [east])
    d = 0.0
    while d < 12.0 or scene.step < 1300:
        moving = d < 12.0
        x, y, yaw = pose_at(east, d)
        fast = Actor("bg", x + 20.0, y + 3.2, yaw=np.pi, speed=10.0 if moving else 5.0)
        scene.tick([(x, y, yaw, 10.0 if moving else 0.0)], others=(fast,))
        if scene.criteria.finished()[0]:
            break
        d += 0.5 if moving else 0.0
    result = scene.result()
    assert result.route_completion < 10.0
    assert result.min_speed_checkpoints == pytest.approx([100.0])  # part 1 closed, part 2 open: dropped
    assert result.infractions["min_speed_infractions"] == []


def test_completion_looks_two_points_ahead(mini: RoadMap, east: Route) -> None:
    """WINDOWS_SIZE = 2: a CAV that jumps 5 m in one tick only advances its completion by 2 points."""
    assert CriteriaConfig().completion_window == 2
    scene = Scene(mini, [east])
    scene.tick([(*pose_at(east, 10.0), 5.0)])
    before = scene.result().route_completion
    scene.tick([(*pose_at(east, 15.5), 5.0)])
    gained = (scene.result().route_completion - before) / 100.0 * east.length
    assert gained == pytest.approx(2.0, abs=0.05)


def test_collision_spot_is_forgotten_once_5_m_away() -> None:
    """A second car hitting the CAV at the spot of its last counted collision is ignored while the CAV
    stayed near it, and charged once the CAV had been more than 5 m away (upstream clears the spot)."""
    spot, far = np.array([[10.0, 0.0]]), np.array([[16.0, 0.0]])
    cav, fast = np.array([0]), np.array([5.0])
    for went_away, charged in ((False, False), (True, True)):
        memory = CollisionMemory(1, CriteriaConfig())
        assert memory.count(cav, np.array(["bg1"]), spot, fast, time=1.0).tolist() == [True]
        memory.forget_far(cav, far if went_away else spot + 1.0)
        assert memory.count(cav, np.array(["bg2"]), spot, fast, time=9.0).tolist() == [charged]


def test_driving_as_fast_as_the_traffic_is_not_too_slow(mini: RoadMap, east: Route) -> None:
    """Three cars at the CAV's own 8.3 m/s: every part is 100 % and none is listed (or marked "too slow"
    in a replay), although the traffic's mean speed is summed in floating point over 400 ticks."""
    scene = Scene(mini, [east])
    d = 0.0
    while not scene.criteria.finished()[0]:
        x, y, yaw = pose_at(east, d)
        others = tuple(Actor(f"bg{k}", x + 10.0 * (k + 1), y + 3.2, yaw=np.pi, speed=8.3) for k in range(3))
        scene.tick([(x, y, yaw, 8.3)], others=others)
        d += 8.3 * DT
    result = scene.result()
    assert result.min_speed_checkpoints == pytest.approx([100.0] * 20)
    assert result.infractions["min_speed_infractions"] == []
