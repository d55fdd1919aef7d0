"""`cmudrive routes show` and the scenarios' plans it draws: where each planned actor stands, in metres."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from cmudrive.bench.routes import RouteSpec, write_routes
from cmudrive.bench.scenarios import PlanPath, PlanPoint, Scenario, plan_scenarios
from cmudrive.cli import app
from cmudrive.maps import RoadMap, load_map
from tests.scenario_helpers import frenet, lane_cav, scenario, trigger

T_S = 40.0  # [m] trigger's arc length on CAV 0's lane


def planned(spec: RouteSpec) -> tuple[RoadMap, Scenario]:
    m = load_map(spec.town)
    return m, plan_scenarios(spec, m, spec.dense_routes(m)).scenarios[0]


def points(sc: Scenario, kind: str) -> list[PlanPoint]:
    return [it for it in sc.plan() if isinstance(it, PlanPoint) and it.kind == kind]


def accident() -> RouteSpec:
    m = load_map("interurban")
    lane, left = "R1a-R2a_0", "R1a-R2a_1"
    cavs = (lane_cav(m, 0, lane, 20.0, 230.0), lane_cav(m, 1, left, 20.0, 230.0))
    sc = scenario("Accident", trigger(m, lane, T_S), distance="60")
    return RouteSpec("acc", "interurban", "ClearNoon", 0, cavs, (sc,))


def test_accident_plan_puts_the_cars_at_distance_and_beyond() -> None:
    """Police car at fwd(60 m), car A 10 m and car B 16 m further, all 0.3 lane widths to the right."""
    m, sc = planned(accident())
    lane = "R1a-R2a_0"
    w = float(m.lane_width[m.lane(lane)])
    cars = points(sc, "police") + points(sc, "car")
    s, d = frenet(m, lane, np.array([c.xy for c in cars]))
    assert s - T_S == pytest.approx([60.0, 70.0, 76.0], abs=0.2)
    assert d == pytest.approx(-0.3 * w, abs=0.05)
    assert len(points(sc, "warning_sign")) == 1


def test_emergency_plan_starts_distance_behind_the_trigger_in_the_ego_lane() -> None:
    m = load_map("interurban")
    lane = "R1a-R2a_0"
    sc_spec = scenario("YieldToEmergencyVehicle", trigger(m, lane, T_S), distance="30")
    cavs = (lane_cav(m, 0, lane, 20.0, 300.0),)
    _, sc = planned(RouteSpec("ev", "interurban", "ClearNoon", 0, cavs, (sc_spec,)))
    (ev,) = points(sc, "ambulance")
    s, d = frenet(m, lane, ev.xy)
    assert s[0] == pytest.approx(T_S - 30.0, abs=0.1)
    assert abs(d[0]) < 0.05
    (approach,) = [it for it in sc.plan() if isinstance(it, PlanPath)]
    assert approach.kind == "approach"
    assert np.linalg.norm(approach.xy[0] - ev.xy) < 0.1
    assert np.min(np.linalg.norm(approach.xy - sc.trigger_xy, axis=1)) < 1.0  # it drives through T


def test_parking_exit_plan_parks_cars_ahead_and_behind_the_slot() -> None:
    m = load_map("downtown")
    lane = "J0_0-J0_1_2"
    spec = RouteSpec(
        "park", "downtown", "ClearNoon", 0, (lane_cav(m, 0, lane, 20.0, 135.0),),
        (scenario("ParkingExit", trigger(m, lane, 20.0)),),
    )  # fmt: skip
    _, sc = planned(spec)
    (slot,) = points(sc, "slot")
    side = str(m.lane_ids[sc.slot.lane])  # type: ignore[attr-defined]
    s_slot, _ = frenet(m, side, slot.xy)
    s_cars, _ = frenet(m, side, np.array([c.xy for c in points(sc, "car")[:2]]))
    assert s_cars - s_slot[0] == pytest.approx([20.0, -10.0], abs=0.2)


def test_flow_plan_runs_from_source_to_sink() -> None:
    from tests.test_scenario_flows import flow_route

    spec, sink = flow_route("highway", "MergerIntoSlowTraffic")
    _, sc = planned(spec)
    (flow,) = [it for it in sc.plan() if isinstance(it, PlanPath)]
    assert flow.kind == "flow"
    assert np.linalg.norm(flow.xy[-1] - sink) < 0.5
    assert np.all(np.linalg.norm(np.diff(flow.xy, axis=0), axis=1) < 2.0)  # a dense path, no jumps


def test_planning_needs_no_world() -> None:
    """Scenarios built for their plan refuse to run: the life cycle needs the world."""
    _, sc = planned(accident())
    with pytest.raises(RuntimeError, match="plan only"):
        sc.on_instantiate()


def test_routes_show_writes_a_png(tmp_path: Path) -> None:
    spec = accident()
    path = tmp_path / "routes.xml"
    write_routes([spec, replace(spec, id="other")], path)
    out = tmp_path / "acc.png"
    result = CliRunner().invoke(app, ["routes", "show", str(path), "acc", "-o", str(out)])
    assert result.exit_code == 0, result.output
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert 20_000 < len(data) < 400_000
    missing = CliRunner().invoke(app, ["routes", "show", str(path), "nope", "-o", str(out)])
    assert missing.exit_code == 1
    assert "no route 'nope'" in missing.output


def test_two_ways_plan_runs_the_oncoming_flow_against_the_cav() -> None:
    """AccidentTwoWays (downtown, one lane each way, speed limit v): the OppositeFlow path lies on the
    oncoming lane and runs against CAV 0, from 1.5 v[km/h] + 30 m before the point beside the last car."""
    m = load_map("downtown")
    lane = "J0_0-J0_1_2"
    i = m.lane(lane)
    gap = {"from": "20", "to": "40"}
    sc_spec = scenario("AccidentTwoWays", trigger(m, lane, 20.0), distance="40", frequency=gap)
    cavs = (lane_cav(m, 0, lane, 5.0, min(200.0, m.lane_length[i] - 3.0)),)
    spec = RouteSpec("two", "downtown", "ClearNoon", 0, cavs, (sc_spec,))
    _, sc = planned(spec)
    (flow,) = [it for it in sc.plan() if isinstance(it, PlanPath)]
    opposite = str(m.lane_ids[m.lane_opposite[i]])
    s, d = frenet(m, opposite, flow.xy)
    inside = (s > 0.5) & (s < m.lane_length[m.lane_opposite[i]] - 0.5)
    assert np.all(np.abs(d[inside]) < 0.1)  # on the oncoming lane's centreline
    assert np.all(np.diff(s[inside]) > 0)  # in its direction: against CAV 0
    s_ego, _ = frenet(m, lane, flow.xy[[0, -1]])
    assert s_ego[0] > s_ego[1]


def test_cyclists_ride_and_control_loss_patches_are_planned_where_placed() -> None:
    """HazardAtSideLane: each bicycle's ride is bicycle_drive_distance long from its start; ControlLoss: the
    patches 14, 48 and 74 m past T on CAV 0's lane."""
    m = load_map("interurban")
    lane = "R1a-R2a_0"
    cavs = (lane_cav(m, 0, lane, 20.0, 300.0),)
    hazard = scenario("HazardAtSideLane", trigger(m, lane, T_S), distance="40", bicycle_drive_distance="30")
    _, sc = planned(RouteSpec("h", "interurban", "ClearNoon", 0, cavs, (hazard,)))
    rides = [it for it in sc.plan() if isinstance(it, PlanPath)]
    bikes = points(sc, "bicycle")
    assert [r.kind for r in rides] == ["ride", "ride"]
    for ride, bike in zip(rides, bikes, strict=True):
        assert np.linalg.norm(ride.xy[0] - bike.xy) < 0.05
        assert np.sum(np.linalg.norm(np.diff(ride.xy, axis=0), axis=1)) == pytest.approx(30.0, abs=0.5)
    _, sc = planned(
        RouteSpec("c", "interurban", "ClearNoon", 0, cavs, (scenario("ControlLoss", trigger(m, lane, T_S)),))
    )
    s, d = frenet(m, lane, np.array([p.xy for p in points(sc, "patch")]))
    assert s - T_S == pytest.approx([14.0, 48.0, 74.0], abs=0.1)
    assert np.all(np.abs(d) < 0.05)
