"""Rule-following scenarios at junctions (forced light phases, a blocked exit, turn and drive counters)
on downtown and CARLA's Town03: light phases measured tick by tick in the route log, ends measured along
CAV 0's route."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest

from cmudrive.agents import Observations, PidAgent
from cmudrive.agents.autopilot import AutopilotAgent
from cmudrive.bench import EvalConfig, RouteSpec
from cmudrive.bench.criteria import CriteriaConfig
from cmudrive.bench.scenarios import ScenarioConfig
from cmudrive.bench.scenarios.base import Scenario
from cmudrive.bench.scenarios.junctions import LIGHT_PHASE
from cmudrive.maps import RoadMap, load_map
from cmudrive.sim.dynamics import Controls
from cmudrive.sim.traffic_lights import YELLOW_TIME
from tests.scenario_helpers import (
    EMPTY,
    StopsAt,
    cav_track,
    lane_cav,
    path_cav,
    run,
    scenario,
    stop_cavs,
    track,
    trigger,
)

A, RIGHT, STRAIGHT = "J0_0-J0_1_2", "J0_1-J1_1_1", "J0_1-J0_2_2"  # downtown: signalised junction J0_1
LEFT_A, LEFT_B = "J0_1-J0_0_2", "J0_0-J1_0_2"  # downtown: left turn at the priority junction J0_0


def through(m: RoadMap, kind: str, a: str, b: str, t_s: float) -> RouteSpec:
    ia, ib = m.lane(a), m.lane(b)
    xy = np.array(
        [
            m.index.frenet_to_xy(np.array([ia]), np.array([10.0]))[0],
            m.index.frenet_to_xy(np.array([ia]), np.array([m.lane_length[ia] - 3.0]))[0],
            m.index.frenet_to_xy(np.array([ib]), np.array([min(100.0, m.lane_length[ib] - 5.0)]))[0],
        ]
    )
    return RouteSpec(
        f"{kind}_{m.name}",
        m.name,
        "ClearNoon",
        0,
        (path_cav(m, 0, xy),),
        (scenario(kind, trigger(m, a, t_s)),),
    )


def ego_signal(m: RoadMap, spec: RouteSpec, log) -> list[str]:  # type: ignore[no-untyped-def]
    route = spec.dense_routes(m)[0]
    before = int(np.flatnonzero(route.in_junction)[0]) - 1
    link = int(np.flatnonzero((m.link_from == route.lane[before]) & (m.link_tls >= 0))[0])
    t, k = int(m.link_tls[link]), int(m.link_tls_index[link])
    return [str(log.tls_state(i)[t])[k] for i in range(log.num_ticks)]


def ends(monkeypatch: pytest.MonkeyPatch) -> list[tuple[float, np.ndarray, float]]:
    """Record (world time, CAV 0 position, activation time) whenever an active scenario finishes."""
    seen: list[tuple[float, np.ndarray, float]] = []
    original = Scenario.finish

    def finish(self: Scenario) -> None:
        if self.phase.name == "ACTIVE":
            st = self.world.cav_state
            seen.append((self.time, np.array([st.x[0], st.y[0]]), self.activated_at))
        original(self)

    monkeypatch.setattr(Scenario, "finish", finish)
    return seen


@pytest.mark.parametrize(("town", "a", "b"), [("downtown", A, RIGHT), ("Town03", "-2_3", "-21_4")])
def test_red_light_encounter_holds_red_then_green_then_releases(
    town: str, a: str, b: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    seen = ends(monkeypatch)
    m = load_map(town)
    spec = through(m, "VanillaSignalizedTurnEncounterRedLight", a, b, 80.0)
    result, log = run(spec, tmp_path)
    assert result.scenario_simulated is True
    signal = ego_signal(m, spec, log)
    end, _, act = seen[0]
    tick = lambda t: round(t / 0.05) - 1  # noqa: E731 (log tick of a world time)
    # 5 s red, the first YELLOW_TIME of it yellow where the light was green when the scenario began
    assert set(signal[tick(act + YELLOW_TIME) + 1 : tick(act + 5.0)]) == {"r"}
    assert set(signal[tick(act) + 1 : tick(act + YELLOW_TIME)]) <= {"r", "y"}
    assert set(signal[tick(act + 5.0) + 1 : tick(end)]) <= {"G"}  # then green until the end
    route = spec.dense_routes(m)[0]
    before = int(np.flatnonzero(route.in_junction)[0]) - 1
    light = int(m.link_tls[np.flatnonzero((m.link_from == route.lane[before]) & (m.link_tls >= 0))[0]])
    program = set(m.tls_phases(light)[1].tolist())
    released = tick(end + YELLOW_TIME) + 2  # (signals the program turns red show yellow first)
    after = [str(log.tls_state(k)[light]) for k in range(released, log.num_ticks)]
    assert set(after) <= program  # released: back to the states of the light's own program
    _ends_past_junction(m, spec, seen[0][1], 10.0)


@pytest.mark.parametrize(("town", "a", "b"), [("downtown", A, STRAIGHT), ("Town03", "-2_3", "-3_3")])
def test_green_light_encounter_gives_5_s_green_then_yellow_and_red(
    town: str, a: str, b: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    seen = ends(monkeypatch)
    m = load_map(town)
    spec = through(m, "VanillaSignalizedTurnEncounterGreenLight", a, b, 100.0)
    _, log = run(spec, tmp_path)
    end, _, act = seen[0]
    signal = ego_signal(m, spec, log)
    tick = lambda t: round(t / 0.05) - 1  # noqa: E731 (log tick of a world time)
    assert set(signal[tick(act) + 1 : tick(min(act + 5.0, end))]) == {"G"}  # 5 s green
    # then yellow for YELLOW_TIME and red: the CAV is never shown green -> red at once
    assert set(signal[tick(act + 5.0) + 1 : tick(min(act + 5.0 + YELLOW_TIME, end))]) <= {"y"}
    assert set(signal[tick(act + 5.0 + YELLOW_TIME) + 2 : tick(end)]) <= {"r"}
    assert end <= act + 10.0 + 0.1  # ends with the light sequence at the latest


@pytest.mark.parametrize("kind", ["VanillaNonSignalizedTurn", "VanillaNonSignalizedTurnEncounterStopsign"])
def test_vanilla_turn_ends_10_m_past_the_junction(
    kind: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    seen = ends(monkeypatch)
    m = load_map("downtown")
    spec = through(m, kind, LEFT_A, LEFT_B, 100.0)
    result, _ = run(spec, tmp_path)
    assert result.scenario_simulated is True and len(seen) == 1
    _ends_past_junction(m, spec, seen[0][1], 10.0)


def _ends_past_junction(m: RoadMap, spec: RouteSpec, where: np.ndarray, metres: float) -> None:
    route = spec.dense_routes(m)[0]
    inside = np.flatnonzero(route.in_junction)
    exit_k = int(inside[0]) + int(np.flatnonzero(~route.in_junction[inside[0] :])[0])
    k = int(np.argmin(np.linalg.norm(route.xy - where, axis=1)))
    assert route.distance[k] - route.distance[exit_k] == pytest.approx(metres, abs=1.5)


@pytest.mark.parametrize(("town", "a", "b"), [("downtown", A, RIGHT), ("Town03", "-2_3", "-21_4")])
def test_blocked_intersection_car_stands_past_the_exit_for_10_s(
    town: str, a: str, b: str, tmp_path: Path
) -> None:
    m = load_map(town)
    spec = through(m, "BlockedIntersection", a, b, 80.0)
    result, log = run(spec, tmp_path)
    route = spec.dense_routes(m)[0]
    blocker, cav = track(log, "S1:blocker"), cav_track(log, 0)
    present = np.flatnonzero(~np.isnan(blocker[:, 0]))
    inside = np.flatnonzero(route.in_junction)
    exit_k = int(inside[0]) + int(np.flatnonzero(~route.in_junction[inside[0] :])[0])
    k = int(np.argmin(np.linalg.norm(route.xy - blocker[present[0], :2], axis=1)))
    assert route.distance[k] - route.distance[exit_k] == pytest.approx(5.0, abs=1.0)  # 5 m past the exit
    assert np.linalg.norm(route.xy[k] - blocker[present[0], :2]) < 0.3  # on CAV 0's lane
    close = int(np.flatnonzero(np.linalg.norm(cav[:, :2] - blocker[present[0], :2], axis=1) < 13.0)[0])
    assert (present[-1] - close) * 0.05 == pytest.approx(10.0, abs=0.15)  # removed 10 s later
    assert any(i.actor == "S1:blocker" for i in result.cavs[0].infractions["collisions_vehicle"])


def test_drive_counter_scenarios_suspend_blocked_and_time_out(tmp_path: Path) -> None:
    """SequentialLaneChange (a 200 m counter with ST240): a CAV that stops is not blocked while the
    scenario's timeout (10 s here) runs, and then gets scenario_timeouts."""
    m = load_map("interurban")
    cavs = (lane_cav(m, 0, "R1a-R2a_0", 20.0, 230.0),)
    spec = RouteSpec(
        "counter",
        "interurban",
        "ClearNoon",
        0,
        cavs,
        (scenario("SequentialLaneChange", trigger(m, "R1a-R2a_0", 25.0)),),
    )
    config = EvalConfig(
        background=EMPTY, tick_cap=700, criteria=replace(CriteriaConfig(), blocked_time=5.0),
        scenarios=ScenarioConfig(timeout=10.0),
    )  # fmt: skip
    result, _ = run(spec, tmp_path, StopsAt, config)
    (t_out,) = [i.time for i in result.cavs[0].infractions["scenario_timeouts"]]
    blocked = result.cavs[0].infractions["vehicle_blocked"][0].time
    assert 10.5 < t_out < 16.0 and t_out + 5.0 <= blocked < t_out + 6.0


class RecordsControls(PidAgent):
    """The PID agent, keeping what it asked for (before any scenario changed it)."""

    asked: ClassVar[list[tuple[float, float]]] = []

    def run_step(self, obs: Observations) -> Controls:
        c = super().run_step(obs)
        RecordsControls.asked.append((float(c.steer[0]), float(c.throttle[0])))
        return c


def test_control_loss_adds_noise_near_the_three_patches(tmp_path: Path) -> None:
    """Within 2 m of the patches 14, 48 and 74 m past T the CAV's steer and throttle get noise of mean
    +-0.055 / +-0.03 (sign fixed per patch); elsewhere its controls are the agent's own."""
    RecordsControls.asked.clear()
    m = load_map("interurban")
    lane = "R1a-R2a_0"
    cavs = (lane_cav(m, 0, lane, 20.0, 230.0),)
    spec = RouteSpec(
        "loss", "interurban", "ClearNoon", 0, cavs, (scenario("ControlLoss", trigger(m, lane, 40.0)),)
    )
    result, log = run(spec, tmp_path, RecordsControls)
    assert result.scenario_simulated is True
    asked = np.array(RecordsControls.asked)  # (ticks, 2) steer, throttle
    applied = np.array(
        [[log.controls(k).steer[0], log.controls(k).throttle[0]] for k in range(log.num_ticks)]
    )
    n = min(len(asked), len(applied))
    changed = np.flatnonzero(np.abs(applied[:n] - asked[:n]).max(axis=1) > 1e-6)
    # the CAV position when the agent was asked: the log's previous tick
    cav = cav_track(log, 0)
    s_prev, _ = m.index.project(cav[changed - 1, :2], np.full(len(changed), m.lane(lane)))
    patches = np.array([54.0, 88.0, 114.0])  # T at s = 40 m
    assert np.abs(s_prev[:, None] - patches).min(axis=1).max() < 2.0 + 1.1  # only near a patch (+ a tick)
    for p in patches:  # every patch is felt, with one sign of steer noise each
        near = changed[np.abs(s_prev - p) < 3.1]
        assert len(near) >= 2
        noise = applied[near, 0] - asked[near, 0]
        assert np.all(noise > 0) or np.all(noise < 0)
        assert 0.02 < abs(noise.mean()) < 0.09


def test_hard_break_stops_the_traffic_ahead_for_10_s(tmp_path: Path) -> None:
    """HardBreakRoute among background traffic: the background vehicles ahead of CAV 0 on its road brake
    to a standstill after activation and drive on again 10 s later."""
    from cmudrive.sim.background import BackgroundConfig
    from cmudrive.sim.snapshot import Role

    m = load_map("interurban")
    lane = "R1a-R2a_0"
    spec = RouteSpec(
        "hard_break", "interurban", "ClearNoon", 0, (lane_cav(m, 0, lane, 20.0, 400.0),),
        (scenario("HardBreakRoute", trigger(m, lane, 40.0)),),
    )  # fmt: skip
    result, log = run(spec, tmp_path, config=EvalConfig(background=BackgroundConfig(), tick_cap=900))
    assert result.scenario_simulated is True
    cav = cav_track(log, 0)
    s_cav, _ = m.index.project(cav[:, :2], np.full(len(cav), m.lane(lane)))
    act = int(np.flatnonzero(s_cav >= 38.0)[0])  # activation: CAV 0 2 m short of T
    snap = log.snapshot(act)
    bg = np.flatnonzero(snap.role == Role.BACKGROUND)
    ring = np.array([m.lane("R1a-R2a_0"), m.lane("R1a-R2a_1")])
    ahead = []
    for r in bg.tolist():
        s, d = m.index.project(np.array([[snap.x[r], snap.y[r]]] * 2), ring)
        if np.abs(d).min() < 1.7 and s_cav[act] + 5.0 < s.min() < m.lane_length[ring[0]] - 30.0:
            ahead.append(str(snap.ids[r]))
    assert ahead, "no background vehicle ahead of CAV 0 at activation"
    speeds = {name: track(log, name)[:, 3] for name in ahead}
    stopped = [v[act + 180] for v in speeds.values() if not np.isnan(v[act + 180])]  # 9 s after activation
    assert stopped and max(stopped) < 0.5
    moving = [v[act + 300] for v in speeds.values() if not np.isnan(v[act + 300])]  # 5 s after the restart
    assert moving and max(moving) > 3.0


class StopsAfterTrigger(StopsAt):
    STOP_TIME = 9.0  # [s]: CAV 0 (Town03, from s = 10 m) has passed the trigger at s = 80 m


def test_the_forced_green_is_the_whole_approach_held_until_the_scenario_ends(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """VanillaSignalizedTurnEncounterRedLight on Town03's two-lane approach -2 (one traffic light upstream):
    CAV 0 stops after the trigger and never leaves the junction, so the scenario runs to the route's end
    (40 s). From 5 s after activation to that end, every signal of *both* lanes of the approach is green
    and every other signal of the light red: no 15 s cap, no lane of the approach left red."""
    seen = ends(monkeypatch)
    m = load_map("Town03")
    spec = through(m, "VanillaSignalizedTurnEncounterRedLight", "-2_3", "-21_4", 80.0)
    _, log = run(spec, tmp_path, StopsAfterTrigger, EvalConfig(background=EMPTY, tick_cap=800))
    end, _, act = seen[0]
    assert end == pytest.approx(40.0, abs=0.1) and act < 9.0  # ended with the route, activated before
    lanes = [m.lane("-2_3"), m.lane("-2_4")]
    links = np.flatnonzero(np.isin(m.link_from, lanes) & (m.link_tls >= 0))
    light = int(m.link_tls[links[0]])
    assert set(m.link_tls[links].tolist()) == {light} and len(links) >= 2
    ours = m.link_tls_index[links]
    first = round((act + LIGHT_PHASE) / 0.05) + 1
    for k in range(first, log.num_ticks - 1):
        state = str(log.tls_state(k)[light])
        assert {state[i] for i in ours} == {"G"}, (k, state)
        assert {c for i, c in enumerate(state) if i not in set(ours.tolist())} == {"r"}, (k, state)
    assert log.num_ticks - first > round(20.0 / 0.05)  # held for more than 20 s


def test_blocked_intersection_freezes_the_other_entries_until_it_ends(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Upstream's Junction{stopEntries}: from activation to the scenario's end, background traffic on
    every entry of the junction that CAV 0's route does not take is halted (here: the three lanes of the
    two other roads into downtown's J0_1), then released."""
    from cmudrive.sim.background import BackgroundActivity

    calls: list[tuple[str, list[int], float]] = []
    for name in ("stop_lane", "release_lane"):
        original = getattr(BackgroundActivity, name)

        def spy(self: BackgroundActivity, lanes, *rest, _name=name, _original=original):  # type: ignore[no-untyped-def]
            calls.append((_name, sorted(int(x) for x in lanes), self._need_world().time))
            return _original(self, lanes, *rest)

        monkeypatch.setattr(BackgroundActivity, name, spy)
    seen = ends(monkeypatch)
    m = load_map("downtown")
    spec = through(m, "BlockedIntersection", A, RIGHT, 80.0)
    run(spec, tmp_path)
    route = spec.dense_routes(m)[0]
    junction = int(m.lane_junction[route.lane[np.flatnonzero(route.in_junction)[0]]])
    via = m.link_via
    into = (via >= 0) & (m.lane_junction[np.maximum(via, 0)] == junction)
    into &= (m.lane_kind[m.link_from] == 0) & ~m.lane_internal[m.link_from]  # driving lanes into it
    entries = sorted(set(m.link_from[into].tolist()) - set(route.path.tolist()))
    assert len({m.lane_edge[e] for e in entries}) == 2 and len(entries) == 3  # the two other roads
    end, _, act = seen[0]
    assert [(c[0], c[1]) for c in calls] == [("stop_lane", entries), ("release_lane", entries)]
    assert calls[0][2] == pytest.approx(act, abs=0.06) and calls[1][2] == pytest.approx(end, abs=0.06)


class Cav0StopsAfterTrigger(AutopilotAgent):
    """The autopilot (it stops at red lights), but CAV 0 brakes to a standstill from 4 s on: it has passed
    T and stands short of the junction."""

    def run_step(self, obs: Observations) -> Controls:
        return stop_cavs(super().run_step(obs), obs, {0: 4.0})


def test_a_cav_held_at_the_scenarios_forced_red_is_not_blocked(tmp_path: Path) -> None:
    """SignalizedJunctionLeftTurn at downtown's J0_1 (CAV 0 from J0_2, the flow from J0_0): CAV 0 stops
    after the trigger and never turns, so the scenario holds the third approach (from J1_1) red until the
    route ends (30 s). CAV 1 on that approach waits at the red through no fault of its own: its blocked
    test (5 s here) is suspended while the scenario holds the junction."""
    m = load_map("downtown")
    a, b = m.lane("J0_2-J0_1_2"), m.lane("J0_1-J1_1_2")
    xy0 = np.array(
        [
            m.index.frenet_to_xy(np.array([a]), np.array([40.0]))[0],
            m.index.frenet_to_xy(np.array([a]), np.array([m.lane_length[a] - 2.0]))[0],
            m.index.frenet_to_xy(np.array([b]), np.array([40.0]))[0],
        ]
    )
    c, d = m.lane("J1_1-J0_1.pocket_3"), m.lane("J0_1-J0_0_2")
    xy1 = np.array(
        [
            m.index.frenet_to_xy(np.array([c]), np.array([2.0]))[0],
            m.index.frenet_to_xy(np.array([d]), np.array([60.0]))[0],
        ]
    )
    sc = scenario("SignalizedJunctionLeftTurn", trigger(m, "J0_2-J0_1_2", 55.0), flow_speed="10")
    spec = RouteSpec("held", "downtown", "ClearNoon", 0, (path_cav(m, 0, xy0), path_cav(m, 1, xy1)), (sc,))
    config = EvalConfig(background=EMPTY, tick_cap=600, criteria=replace(CriteriaConfig(), blocked_time=5.0))
    result, log = run(spec, tmp_path, Cav0StopsAfterTrigger, config)
    s1, _ = m.index.project(cav_track(log, 1)[-1:, :2], np.array([c]))
    assert s1[0] > 20.0 and cav_track(log, 1)[-1, 3] < 0.1  # CAV 1 stands at its stop line ...
    assert result.cavs[1].infractions["vehicle_blocked"] == []  # ... and is not blocked
    assert result.cavs[1].infractions["red_light"] == []


def test_a_node_that_only_joins_two_roads_is_not_the_scenarios_junction() -> None:
    """Town05: a right turn 22 m past ``25.16``, the node netconvert puts where two OpenDRIVE roads meet
    end to end (CARLA has no junction there). The junction types look past it to the real junction 829,
    as upstream's "next junction" does: Bench2Drive's own SignalizedJunctionRightTurn route on this
    approach was refused with "CAV 0's route does not turn right at its junction"."""
    from cmudrive.bench.route_check import build_placed
    from cmudrive.bench.routes import CavSpec
    from cmudrive.maps.coords import map_to_carla

    m = load_map("Town05")
    assert m.junction_is_join[m.junction("25.16")] and not m.junction_is_join[m.junction("829")]
    start = m.lane("-16_3")
    s0 = float(m.lane_length[start]) - 12.0
    pts = m.index.frenet_to_xy(np.array([start, m.lane("-25_3"), m.lane("-0_3")]), np.array([s0, 10.0, 20.0]))
    cav = CavSpec(0, np.column_stack([map_to_carla(pts), np.zeros(3)]))
    sc_spec = scenario("SignalizedJunctionRightTurn", trigger(m, "-16_3", s0 + 3.0), flow_speed="12")
    sc_spec = replace(sc_spec, params={**sc_spec.params, "source_dist_interval": {"from": "22", "to": "38"}})
    spec = RouteSpec("join", "Town05", "ClearNoon", 0, (cav,), (sc_spec,))
    routes = spec.dense_routes(m)
    (sc,) = build_placed(spec, m, routes)
    before, _, turn = sc.junction_exit()
    first = int(np.flatnonzero(routes[0].in_junction[before:])[0]) + before
    assert str(m.junction_ids[m.lane_junction[routes[0].lane[first]]]) == "829"
    assert np.degrees(turn) < -60.0  # the right turn, not the 0 degree pass through the join
