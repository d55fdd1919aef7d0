"""CrossingBicycleFlow: bicycles along the bike lane across CAV 0's left turn, and the light phases.

Downtown's signalised junction J1_2: CAV 0 drives east on J0_2-J1_2 and turns left (north); the bicycle
flow rides west along the far side's bike lane (J2_2-J1_2_1) straight through the junction, across CAV 0's
turn, to 40 m past the exit."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cmudrive.bench import EvalConfig
from cmudrive.bench.routes import RouteSpec
from cmudrive.bench.scenarios import PlanPath, Scenario, ScenarioError, plan_scenarios
from cmudrive.maps import LaneKind, RoadMap, load_map
from cmudrive.maps.coords import map_to_carla
from cmudrive.sim.traffic_lights import YELLOW_TIME
from tests.scenario_helpers import EMPTY, path_cav, run, scenario, track, trigger

APPROACH, LEFT_EXIT, BIKE_LANE = "J0_2-J1_2_2", "J1_2-J1_3_2", "J2_2-J1_2_1"  # downtown
SPEED, GAP = 8.0, (10.0, 20.0)  # [m/s], [m]
SOURCE_BEFORE = 50.0  # [m] the flow's source before the end of the bike lane


def bike_route(m: RoadMap, a: str, b: str, bike_xy: np.ndarray, route_id: str = "bikes") -> RouteSpec:
    ia, ib = m.lane(a), m.lane(b)
    xy = np.array(
        [
            m.index.frenet_to_xy(np.array([ia]), np.array([max(2.0, m.lane_length[ia] - 70.0)]))[0],
            m.index.frenet_to_xy(np.array([ia]), np.array([m.lane_length[ia] - 2.0]))[0],
            m.index.frenet_to_xy(np.array([ib]), np.array([min(50.0, m.lane_length[ib] - 5.0)]))[0],
        ]
    )
    c = map_to_carla(bike_xy[None])[0]
    sc = scenario(
        "CrossingBicycleFlow", trigger(m, a, max(3.0, m.lane_length[ia] - 40.0)),
        start_actor_flow={"x": str(c[0]), "y": str(c[1]), "z": "0"}, flow_speed=str(SPEED),
        source_dist_interval={"from": str(GAP[0]), "to": str(GAP[1])},
    )  # fmt: skip
    return RouteSpec(route_id, m.name, "ClearNoon", 0, (path_cav(m, 0, xy),), (sc,))


def downtown() -> tuple[RoadMap, RouteSpec, np.ndarray]:
    m = load_map("downtown")
    k = m.lane(BIKE_LANE)
    source = m.index.frenet_to_xy(np.array([k]), np.array([m.lane_length[k] - SOURCE_BEFORE]))[0]
    return m, bike_route(m, APPROACH, LEFT_EXIT, source), source


def test_bicycles_ride_the_bike_lane_across_the_cav_turn_at_the_flow_speed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Bicycles appear at the source (the later ones) or along the path (pre-filled), ride at 8 m/s on the
    bike lane through the junction across CAV 0's route; CAV 0's signal is red for 5 s from the
    activation with every other signal of the light red, then green (every lane of its road) with the others
    red until the end;
    the light is released afterwards."""
    seen: list[tuple[float, float]] = []
    original = Scenario.finish

    def finish(self: Scenario) -> None:
        if self.phase.name == "ACTIVE":
            seen.append((self.activated_at, self.time))
        original(self)

    monkeypatch.setattr(Scenario, "finish", finish)
    m, spec, source = downtown()
    route = spec.dense_routes(m)[0]
    result, log = run(spec, tmp_path)
    assert result.scenario_simulated is True
    act, end = seen[0]
    tick = lambda t: round(t / 0.05) - 1  # noqa: E731 (log tick of a world time)
    bikes = sorted(
        {a for a in log.arrays["actor_id"].tolist() if a.startswith("S1:bikes:")}, key=lambda a: int(a[9:])
    )
    assert len(bikes) >= 4
    tracks = {b: track(log, b) for b in bikes}
    first = {b: int(np.flatnonzero(~np.isnan(t[:, 0]))[0]) for b, t in tracks.items()}
    assert all(first[b] >= tick(act) for b in bikes)  # none before the activation
    later = [b for b in bikes if first[b] > first[bikes[0]] + 1]  # spawned at the source, not pre-filled
    assert later
    for b in later:
        assert np.linalg.norm(tracks[b][first[b], :2] - source) < 0.5 * 1.8 + SPEED * 0.05 + 0.3, b
    speeds = np.concatenate([t[~np.isnan(t[:, 3]), 3] for t in tracks.values()])
    assert np.median(speeds) == pytest.approx(SPEED, abs=0.05)  # 8 m/s, above a bicycle type's 7 m/s
    assert speeds.max() <= SPEED + 0.05
    bike_lanes = np.flatnonzero(m.lane_kind == LaneKind.BIKE)
    crossed = 0
    for b, t in tracks.items():
        xy = t[~np.isnan(t[:, 0]), :2]
        on = m.index.nearest_lane(xy, kinds=(LaneKind.BIKE,), max_distance=0.5)
        assert np.all(np.isin(on.lane, bike_lanes)), b  # every pose within 0.5 m of a bike lane
        gap = np.linalg.norm(xy[:, None, :] - route.xy[None], axis=2).min()
        crossed += gap < 1.0
    assert crossed >= 1  # a bicycle rode across CAV 0's route
    # the light phases
    before = int(np.flatnonzero(route.in_junction)[0]) - 1
    link = int(np.flatnonzero((m.link_from == route.lane[before]) & (m.link_tls >= 0))[0])
    light, k = int(m.link_tls[link]), int(m.link_tls_index[link])
    states = [str(log.tls_state(i)[light]) for i in range(log.num_ticks)]
    # 5 s all red; signals that were green show yellow for the first YELLOW_TIME of it
    red = states[tick(act + YELLOW_TIME) + 1 : tick(act + 5.0)]
    assert red and all(set(s) == {"r"} for s in red)
    assert all(set(s) <= {"r", "y"} for s in states[tick(act) + 1 : tick(act + YELLOW_TIME)])
    green = states[tick(act + 5.0) + 1 : tick(end)]
    assert green and all(s[k] == "G" and set(s[:k] + s[k + 1 :]) <= {"r", "G"} for s in green)
    approach = np.flatnonzero(m.lane_edge == m.lane_edge[route.lane[before]])  # CAV 0's road: one light
    ego_links = np.flatnonzero(np.isin(m.link_from, approach) & (m.link_tls == light))
    assert all({s[i] for i in m.link_tls_index[ego_links]} == {"G"} for s in green)  # the whole approach
    others = np.setdiff1d(np.arange(len(states[0])), m.link_tls_index[ego_links])
    assert all(set(np.array(list(s))[others]) == {"r"} for s in green)  # every other signal red
    program = set(m.tls_phases(light)[1].tolist())
    released = tick(end + YELLOW_TIME) + 2  # (signals the program turns red show yellow first)
    assert {states[i] for i in range(released, log.num_ticks)} <= program  # released
    assert all(np.isnan(t[tick(end) + 2 :, 0]).all() for t in tracks.values())  # bicycles removed at the end


def test_plan_of_an_unsignalised_junction_has_no_light_and_crosses_the_route() -> None:
    """Suburb (no traffic lights at its bike-lane junctions): the flow path runs on bike lanes from the
    source to 40 m past the junction exit and crosses CAV 0's left turn; no light is forced."""
    m = load_map("suburb")
    k = m.lane("J2_2-J1_2_1")
    source = m.index.frenet_to_xy(np.array([k]), np.array([m.lane_length[k] - 40.0]))[0]
    spec = bike_route(m, "J0_2-J1_2_2", "J1_2-J1_3_1", source)
    routes = spec.dense_routes(m)
    sc = plan_scenarios(spec, m, routes).scenarios[0]
    items = sc.plan()
    assert [it.kind for it in items] == ["flow"]
    flow = items[0]
    assert isinstance(flow, PlanPath)
    assert np.linalg.norm(flow.xy[0] - source) < 0.1
    exit_lane = int(sc.flow.path.lane[-1])  # type: ignore[attr-defined]
    assert m.lane_kind[exit_lane] == LaneKind.BIKE
    assert sc.flow.path.s[-1] == pytest.approx(40.0, abs=0.2)  # type: ignore[attr-defined]
    assert np.linalg.norm(flow.xy[:, None, :] - routes[0].xy[None], axis=2).min() < 1.0


def test_a_town_without_bike_lanes_is_a_clear_placement_error() -> None:
    m = load_map("Town03")
    lane, out = "-2_4", "20_4"  # a left turn at a signalised junction
    spec = bike_route(m, lane, out, m.polyline(m.lane(lane))[5], route_id="r_town03")
    with pytest.raises(ScenarioError) as err:
        plan_scenarios(spec, m, spec.dense_routes(m))
    message = str(err.value)
    assert message.startswith("route 'r_town03', scenario 'S1': ")
    assert "map 'Town03' has no bike lane" in message


def test_a_car_sumo_discards_at_insertion_leaves_the_flow(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Without the stop-capable departure speed, SUMO discards a bicycle pre-filled a few metres before the
    red line ("will not be able to depart") and never reports it as arrived: the flow forgets it at its next
    update instead of keeping a ghost (which, as its last car, would stop the flow for good)."""
    import libsumo

    from cmudrive.bench.scenarios import flows

    original_update = flows.VehicleFlow.update
    ghosts: list[list[str]] = []

    def update(self: flows.VehicleFlow, snap: object) -> None:
        original_update(self, snap)  # type: ignore[arg-type]
        known = set(libsumo.vehicle.getIDList()) | set(libsumo.simulation.getPendingVehicles())
        ghosts.append([c for c in self.cars if c not in known and self.born[c] < self.world.step_count])

    monkeypatch.setattr(flows.VehicleFlow, "_must_stop_ahead", lambda self, lane: False)
    monkeypatch.setattr(flows.VehicleFlow, "update", update)
    _, spec, _ = downtown()
    _, log = run(spec, tmp_path, config=EvalConfig(background=EMPTY, tick_cap=200))
    seen = {a for a in log.arrays["actor_id"].tolist() if a.startswith("S1:bikes:")}
    spawned = max(int(a[9:]) for a in seen) + 1
    assert len(seen) < spawned  # a bicycle never made it into the world: SUMO discarded it
    assert ghosts and not any(ghosts)  # the flow never held on to it after a SUMO step
