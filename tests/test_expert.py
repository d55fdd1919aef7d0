"""The privileged expert: its rules on synthetic snapshots of real towns, and closed-loop routes."""

from __future__ import annotations

import numpy as np
import pytest

from cmudrive.agents import Observations, RouteSetup, sparse_plan
from cmudrive.agents.expert import ExpertAgent, Reason
from cmudrive.bench import EvalConfig, evaluate_route
from cmudrive.bench.records import STATUS_PERFECT
from cmudrive.maps import RoadMap, Route, densify, load_map
from cmudrive.maps.model import StopKind
from cmudrive.sim.background import BackgroundConfig
from cmudrive.sim.snapshot import ActorKind, Role, Snapshot
from tests.test_evaluator import ring_route

EMPTY = BackgroundConfig(vehicles=0, pedestrians=0)


def route_through(
    m: RoadMap, approach: str, before: float = 80.0, after: float = 40.0
) -> tuple[Route, float]:
    """A dense route along lane ``approach`` (from ``before`` m before its end) through its first junction
    link to ``after`` m along the outgoing lane; and the route distance of the approach's end (stop line)."""
    lane = m.lane(approach)
    length = float(m.lane_length[lane])
    out = int(m.link_to[m.successor_links(lane)[0]])
    start = m.index.frenet_to_xy(np.array([lane]), np.array([max(length - before, 0.5)]))[0]
    mid = m.index.frenet_to_xy(np.array([lane]), np.array([length - 1.0]))[0]
    end = m.index.frenet_to_xy(np.array([out]), np.array([min(after, float(m.lane_length[out]) - 1.0)]))[0]
    route = densify(m, np.array([start, mid, end]))
    on = np.flatnonzero(route.lane == lane)
    line = float(route.distance[on[-1]] + length - route.s[on[-1]])
    return route, line


def expert_for(m: RoadMap, routes: list[Route], weather: str = "ClearNoon") -> ExpertAgent:
    agent = ExpertAgent()
    cavs = tuple(sparse_plan(f"cav{k}", r, privileged=True) for k, r in enumerate(routes))
    agent.setup(RouteSetup("test", m.name, weather, 0.05, cavs, m))
    return agent


def scene(
    route: Route,
    at: float,
    speed: float,
    others: list[dict[str, float]] | None = None,
    tls: np.ndarray | None = None,
    tick: int = 0,
) -> tuple[Snapshot, Observations]:
    """CAV 0 on ``route`` at route distance ``at`` [m] driving ``speed``, plus ``others`` (dicts of
    Snapshot columns), lights ``tls``."""
    k = int(np.searchsorted(route.distance, at))
    rows: dict[str, list[object]] = {
        "ids": ["cav0"],
        "x": [route.xy[k, 0]],
        "y": [route.xy[k, 1]],
        "yaw": [route.heading[k]],
        "speed": [speed],
        "role": [Role.CAV],
        "kind": [ActorKind.CAR],
        "length": [4.9],
        "width": [2.1],
    }
    for j, o in enumerate(others or []):
        o = {"length": 4.5, "width": 1.9, "speed": 0.0, "role": Role.BACKGROUND, "kind": ActorKind.CAR, **o}
        rows["ids"].append(f"a{j}")
        for key in ("x", "y", "yaw", "speed", "role", "kind", "length", "width"):
            rows[key].append(o[key])
    columns = {key: np.array(v) for key, v in rows.items()}
    columns["role"] = columns["role"].astype(np.int8)
    columns["kind"] = columns["kind"].astype(np.int8)
    snap = Snapshot.from_rows(tick, tick * 0.05, tls if tls is not None else np.array([], str), **columns)
    obs = Observations(
        tick=tick,
        time=tick * 0.05,
        cav_index=np.array([0]),
        x=snap.x[:1],
        y=snap.y[:1],
        yaw=snap.yaw[:1],
        speed=snap.speed[:1],
        accel=np.zeros(1),
        snapshot=snap,
    )
    return snap, obs


def lights_all(m: RoadMap, char: str) -> np.ndarray:
    return np.array(
        [char * len(str(m.phase_state[m.tls_phase_ptr[t]])) for t in range(len(m.tls_ids))], dtype=str
    )


@pytest.fixture(scope="module")
def downtown() -> RoadMap:
    return load_map("downtown")


def test_red_light_stops_the_cav_before_the_line_green_does_not(downtown: RoadMap) -> None:
    m = downtown
    lane = str(m.lane_ids[m.stop_lane[np.flatnonzero(m.stop_kind == StopKind.TRAFFIC_LIGHT)[0]]])
    route, line = route_through(m, lane)
    agent = expert_for(m, [route])
    _, obs = scene(route, line - 30.0, 8.0, tls=lights_all(m, "r"))
    controls = agent.run_step(obs)
    d = agent.decision
    assert d is not None and d.reason[0] == Reason.RED_LIGHT
    assert 30.0 - 2.45 - 1.5 < d.distance[0] < 30.0 - 2.45 + 1.5  # bumper to the stop line [m]
    assert controls.brake[0] > 0.0 and controls.throttle[0] == 0.0
    green = expert_for(m, [route])
    _, obs = scene(route, line - 30.0, 8.0, tls=lights_all(m, "G"))
    controls = green.run_step(obs)
    assert green.decision is not None and green.decision.reason[0] != Reason.RED_LIGHT
    assert controls.brake[0] == 0.0


def test_a_green_light_is_not_entered_when_the_cav_would_stop_across_its_line(downtown: RoadMap) -> None:
    """Keep the box clear: a car standing 6 m past a green light's line leaves no room for the CAV
    (4.89 m + the red-light segment's 1 m + its 4 m gap), so the CAV stops before the line, naming that car;
    it would otherwise stand across the line, and a red coming meanwhile is charged. With the car 15 m
    past the line the CAV drives in; a car moving away does not hold it either."""
    m = downtown
    lane = str(m.lane_ids[m.stop_lane[np.flatnonzero(m.stop_kind == StopKind.TRAFFIC_LIGHT)[0]]])
    route, line = route_through(m, lane)
    for past, speed, holds in ((6.0, 0.0, True), (15.0, 0.0, False), (6.0, 5.0, False)):
        k = int(np.searchsorted(route.distance, line + past + 2.25))
        car = {"x": route.xy[k, 0], "y": route.xy[k, 1], "yaw": route.heading[k], "speed": speed}
        agent = expert_for(m, [route])
        _, obs = scene(route, line - 20.0, 5.0, others=[car], tls=lights_all(m, "G"))
        agent.run_step(obs)
        d = agent.decision
        assert d is not None and d.reason[0] == Reason.LEADING_VEHICLE and d.object_id[0] == "a0"
        if holds:  # the stop is the line's: bumper to the line, not to the car
            assert 20.0 - 2.45 - 1.0 < d.distance[0] < 20.0 - 2.45 + 1.0
            assert d.desired_speed[0] < np.sqrt(2.0 * 2.5 * (20.0 - 2.45 - 4.0)) + 0.01
        else:
            assert d.distance[0] > 20.0 - 2.45 + past - 1.5


def test_stopped_car_ahead_is_followed_with_idm(downtown: RoadMap) -> None:
    """A car standing 25 m ahead in the lane: the expert names it and measures the bumper gap; at 10 m/s
    it brakes, at 5 m/s IDM still lets it close in, more gently than it would on an empty road."""
    m = downtown
    lane = str(m.lane_ids[m.stop_lane[np.flatnonzero(m.stop_kind == StopKind.TRAFFIC_LIGHT)[0]]])
    route, line = route_through(m, lane, before=100.0)
    at = line - 80.0
    k = int(np.searchsorted(route.distance, at + 25.0))
    car = {"x": route.xy[k, 0], "y": route.xy[k, 1], "yaw": route.heading[k]}
    accel = []
    for speed in (5.0, 10.0):
        agent = expert_for(m, [route])
        _, obs = scene(route, at, speed, others=[car], tls=lights_all(m, "G"))
        agent.run_step(obs)
        d = agent.decision
        assert d is not None and d.reason[0] == Reason.LEADING_VEHICLE and d.object_id[0] == "a0"
        assert 25.0 - 2.45 - 2.25 - 1.0 < d.distance[0] < 25.0 - 2.45 - 2.25 + 1.0
        accel.append(d.accel[0])
    assert accel[1] < 0.0 < accel[0] < 2.5


def test_desired_speed_is_what_the_rules_allow_whatever_the_cav_speed(downtown: RoadMap) -> None:
    """The speed-query label: with green the road's speed is allowed from standstill (where the
    acceleration-limited target speed is 1.25 m/s); a red light 15 m ahead allows sqrt(2 x 2.5 m/s^2 x
    (bumper gap - 6 m)) ~ 5.7 m/s, the same at 2 m/s and at 8 m/s (where the target speeds differ);
    standing at the line, 0."""
    m = downtown
    lane = str(m.lane_ids[m.stop_lane[np.flatnonzero(m.stop_kind == StopKind.TRAFFIC_LIGHT)[0]]])
    route, line = route_through(m, lane)
    green = expert_for(m, [route])
    _, obs = scene(route, line - 15.0, 0.0, tls=lights_all(m, "G"))
    green.run_step(obs)
    assert green.decision is not None
    road = green.decision.desired_speed[0]
    assert road > 7.0
    assert green.decision.target_speed[0] == pytest.approx(1.25)  # 0.5 s at 2.5 m/s^2 from standstill
    desired, target = [], []
    for speed in (2.0, 8.0):
        agent = expert_for(m, [route])
        _, obs = scene(route, line - 15.0, speed, tls=lights_all(m, "r"))
        agent.run_step(obs)
        d = agent.decision
        assert d is not None and d.reason[0] == Reason.RED_LIGHT
        expected = np.sqrt(2.0 * 2.5 * (d.distance[0] - 6.0))
        assert 5.0 < expected < road
        assert d.desired_speed[0] == pytest.approx(expected, abs=0.01)
        desired.append(d.desired_speed[0])
        target.append(d.target_speed[0])
    assert desired[0] == pytest.approx(desired[1])
    assert target[0] < 3.5 and target[1] < 8.0 - 1.0  # the target speed follows the CAV's speed
    agent = expert_for(m, [route])
    _, obs = scene(route, line - 2.45 - 6.5, 0.0, tls=lights_all(m, "r"))
    agent.run_step(obs)
    assert agent.decision is not None and agent.decision.desired_speed[0] == 0.0


def test_desired_speed_behind_a_moving_car_closes_to_its_speed(downtown: RoadMap) -> None:
    """A car ahead at 4 m/s allows sqrt(v^2 + 2 x 2.5 m/s^2 x (bumper gap - 4 m - v x 0.25 s)): more than
    its speed with a 10 m bumper gap, its speed once the gap is down to 5 m (whatever the CAV drives)."""
    m = downtown
    lane = str(m.lane_ids[m.stop_lane[np.flatnonzero(m.stop_kind == StopKind.TRAFFIC_LIGHT)[0]]])
    route, line = route_through(m, lane, before=100.0)
    at = line - 80.0
    for ahead, low, high in ((15.0, 6.0, 7.0), (9.0, 4.0, 4.0)):
        k = int(np.searchsorted(route.distance, at + ahead))
        car = {"x": route.xy[k, 0], "y": route.xy[k, 1], "yaw": route.heading[k], "speed": 4.0}
        agent = expert_for(m, [route])
        _, obs = scene(route, at, 6.0, others=[car], tls=lights_all(m, "G"))
        agent.run_step(obs)
        d = agent.decision
        assert d is not None and d.reason[0] == Reason.LEADING_VEHICLE
        expected = np.sqrt(16.0 + 5.0 * max(d.distance[0] - 4.0 - 1.0, 0.0))
        assert d.desired_speed[0] == pytest.approx(expected, abs=0.05)
        assert low <= d.desired_speed[0] <= high + 1e-9


def test_pedestrian_stepping_into_the_lane_stops_the_cav(downtown: RoadMap) -> None:
    m = downtown
    lane = str(m.lane_ids[m.stop_lane[np.flatnonzero(m.stop_kind == StopKind.TRAFFIC_LIGHT)[0]]])
    route, line = route_through(m, lane, before=100.0)
    at = line - 80.0
    k = int(np.searchsorted(route.distance, at + 15.0))
    left = route.heading[k] + np.pi / 2
    walker = {
        "x": route.xy[k, 0] + 3.0 * np.cos(left),
        "y": route.xy[k, 1] + 3.0 * np.sin(left),
        "yaw": route.heading[k] - np.pi / 2,  # walking across, toward the lane
        "speed": 1.4,
        "kind": ActorKind.PEDESTRIAN,
        "length": 0.5,
        "width": 0.6,
    }
    agent = expert_for(m, [route])
    _, obs = scene(route, at, 8.0, others=[walker], tls=lights_all(m, "G"))
    controls = agent.run_step(obs)
    d = agent.decision
    assert d is not None and d.reason[0] in (Reason.FORECAST, Reason.PEDESTRIAN)
    assert d.object_id[0] == "a0" and controls.brake[0] > 0.0


def test_stop_sign_needs_a_full_stop_then_clears(downtown: RoadMap) -> None:
    """At an all-way stop the expert stops with its bumper within 4 m of the line (the criterion's stop
    area), stands 25 ticks, and then goes."""
    m = downtown
    lane = str(m.lane_ids[m.stop_lane[np.flatnonzero(m.stop_kind == StopKind.ALLWAY_STOP)[0]]])
    route, line = route_through(m, lane)
    agent = expert_for(m, [route])
    _, obs = scene(route, line - 30.0, 6.0)
    agent.run_step(obs)
    assert agent.decision is not None and agent.decision.reason[0] == Reason.STOP_SIGN
    at = line - 2.45 - 2.5  # standing, bumper 2.5 m before the line
    for tick in range(1, 25):
        _, obs = scene(route, at, 0.0, tick=tick)
        controls = agent.run_step(obs)
        assert agent.decision is not None and agent.decision.reason[0] == Reason.STOP_SIGN, tick
        assert controls.brake[0] == 1.0
    _, obs = scene(route, at, 0.0, tick=25)  # the 25th tick standing: served
    controls = agent.run_step(obs)
    assert agent.decision is not None and agent.decision.reason[0] != Reason.STOP_SIGN
    assert controls.throttle[0] > 0.0


def test_expert_drives_both_cavs_to_the_end_without_infraction() -> None:
    result = evaluate_route(ring_route(), ExpertAgent, EvalConfig(background=EMPTY))
    assert [c.status for c in result.cavs] == [STATUS_PERFECT] * 2
    assert result.ticks < 1000  # 210-220 m from standstill at 0.72 x 25 m/s: ~15-20 s


def test_expert_is_deterministic_with_traffic() -> None:
    """The same route twice (background traffic on) gives the same records, tick for tick."""
    config = EvalConfig(tick_cap=600)
    a = evaluate_route(ring_route(seed=3), ExpertAgent, config).to_json()
    b = evaluate_route(ring_route(seed=3), ExpertAgent, config).to_json()
    a.pop("wall_time")
    b.pop("wall_time")
    assert a == b


@pytest.mark.parametrize("state", ["o", "O"])
def test_a_light_switched_off_is_driven_through_like_a_green(downtown: RoadMap, state: str) -> None:
    """A route's lights switched off (``RouteSpec.lights``): SUMO shows 'o' on minor links (give way to
    the links with priority, as on a minor green) and 'O' on major ones. Neither is a red light; with the
    junction empty the expert keeps going."""
    m = downtown
    lane = str(m.lane_ids[m.stop_lane[np.flatnonzero(m.stop_kind == StopKind.TRAFFIC_LIGHT)[0]]])
    route, line = route_through(m, lane)
    agent = expert_for(m, [route])
    _, obs = scene(route, line - 30.0, 8.0, tls=lights_all(m, state))
    controls = agent.run_step(obs)
    assert agent.decision is not None
    assert agent.decision.reason[0] not in (Reason.RED_LIGHT, Reason.YELLOW_LIGHT, Reason.YIELD)
    assert controls.brake[0] == 0.0
