"""Placement rules (``route_rules``): a route that can run but whose layout breaks what its scenario
type needs is reported by route and rule: CAV 0's route too short for the scenario's end, a CAV that
starts against a scenario actor, a junction inside InvadingTurn."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from cmudrive.bench.route_check import build_placed, check_route
from cmudrive.bench.route_rules import MERGE_ROOM, PARKING_WIDTH, rule_violations
from cmudrive.bench.routes import RouteSpec, read_routes, write_routes
from cmudrive.bench.scenarios.cutins import HighwayCutIn
from cmudrive.bench.scenarios.parking import ParkingExit
from cmudrive.bench.scenarios.placement import neighbour, point_xy
from cmudrive.cli import app
from cmudrive.maps import RoadMap, load_map
from cmudrive.maps.model import LaneKind
from tests.scenario_helpers import interurban, lane_cav, scenario, trigger

ROUTES = Path(__file__).resolve().parents[1] / "cmudrive" / "assets" / "routes"
FIXTURES = Path(__file__).resolve().parent / "fixtures"
LANE, PASSING = "R1a-R2a_0", "R1a-R2a_1"  # interurban: the ego lane and the passing lane beside it


def accident(m: RoadMap, end_s: float, *more: object) -> RouteSpec:
    """An Accident 40 m past T (s = 40 m): police at s = 80, car B at 96, the end point E at 146 m."""
    sc = scenario("Accident", trigger(m, LANE, 40.0), distance="40")
    cavs = (lane_cav(m, 0, LANE, 5.0, end_s), *more)
    return RouteSpec("rules", "interurban", "ClearNoon", 0, cavs, (sc,))  # type: ignore[arg-type]


def rules_of(spec: RouteSpec, m: RoadMap) -> list[str]:
    routes = spec.dense_routes(m)
    return [v.rule for v in rule_violations(routes, build_placed(spec, m, routes))]


def test_a_route_that_ends_before_the_obstacles_end_point_breaks_route_reaches_end() -> None:
    m = interurban()
    assert rules_of(accident(m, 200.0), m) == []
    assert rules_of(accident(m, 130.0), m) == ["route-reaches-end"]  # E is 16 m further
    check = check_route(accident(m, 130.0), {})
    assert check.problem is None  # it still runs
    assert "ends 16 m short of the end point E" in check.rules[0].message


def test_a_cav_that_starts_on_a_scenario_actor_breaks_cav_clear_of_actors() -> None:
    """CAV 1 starting on the ego lane right behind the crashed car B (s = 96 m) starts against it; on the
    passing lane beside the police car it is clear (a lane width away)."""
    m = interurban()
    against = accident(m, 200.0, lane_cav(m, 1, LANE, 100.0, 200.0))
    beside = accident(m, 200.0, lane_cav(m, 1, PASSING, 80.0, 200.0))
    assert rules_of(against, m) == ["cav-clear-of-actors"]
    assert rules_of(beside, m) == []


def test_routes_check_names_route_and_rule_and_the_old_invading_turn_breaks_two(tmp_path: Path) -> None:
    """cmudrive220's InvadingTurn_1 as generated before the rules held the generator (Town01) runs but
    crosses a junction between T and the invading flow's source, and its CAV 0's route ends before the
    source (issue 23's audit): the check prints both by route and rule and still counts the route as one
    that can run."""
    spec = next(s for s in read_routes(FIXTURES / "rule_breakers.xml") if s.id == "InvadingTurn_1")
    path = tmp_path / "one.xml"
    write_routes([spec], path)
    result = CliRunner().invoke(app, ["routes", "check", str(path)])
    assert result.exit_code == 0, result.output
    out = " ".join(result.output.split())
    assert "rule InvadingTurn_1: route-reaches-end:" in out
    assert "rule InvadingTurn_1: junction-free-invading:" in out
    assert "1 of 1 routes can run" in out and "1 of them break a placement rule" in out


def test_a_cut_in_from_an_urban_junction_into_another_cavs_lane_breaks_highway_merge() -> None:
    """The old HighwayCutIn_2 (Town06): the car's lane change 10 m past its junction ends in a lane that
    CAV 0 never drives, so the cut-in happened in front of another CAV. Every committed HighwayCutIn merges
    from an unsignalised ramp into the lane CAV 0 is on there, with >= MERGE_ROOM of CAV 0's route after."""
    maps: dict[Path, RoadMap] = {}
    old = next(s for s in read_routes(FIXTURES / "rule_breakers.xml") if s.id == "HighwayCutIn_2")
    assert [r.rule for r in check_route(old, maps).rules] == ["highway-merge"]
    committed = [s for s in read_routes(ROUTES / "cmudrive220.xml") if s.id.startswith("HighwayCutIn")]
    assert len(committed) == 5
    for spec in committed:
        m = load_map(spec.town_path())
        routes = spec.dense_routes(m)
        (sc,) = build_placed(spec, m, routes)
        assert isinstance(sc, HighwayCutIn)
        target = neighbour(m, sc.merge_at.lane, "left")
        assert target in {int(x) for x in routes[0].path}, spec.id  # the car changes into CAV 0's lane
        k = int(np.argmin(np.linalg.norm(routes[0].xy - point_xy(m, sc.merge_at), axis=1)))
        assert routes[0].distance[-1] - routes[0].distance[k] >= MERGE_ROOM, spec.id


def test_the_stopped_queue_on_top_of_a_cav_breaks_cav_clear_of_actors() -> None:
    old = next(s for s in read_routes(FIXTURES / "rule_breakers.xml") if s.id == "StaticCutIn_2")
    rules = check_route(old, {}).rules
    assert [r.rule for r in rules] == ["cav-clear-of-actors"] and "CAV 4 starts against" in rules[0].message


def test_a_parking_slot_on_a_narrow_shoulder_breaks_parking_slot() -> None:
    """The old ParkingExit_3 (Town01) parked CAV 0 and both cars on a 0.3 m shoulder, about a metre into
    the driving lane; every committed ParkingExit uses a parking lane at least 2 m wide."""
    old = next(s for s in read_routes(FIXTURES / "rule_breakers.xml") if s.id == "ParkingExit_3")
    rules = check_route(old, {}).rules
    assert [r.rule for r in rules] == ["parking-slot"] and "0.3 m shoulder lane" in rules[0].message
    for name in ("cmudrive220", "training"):
        for spec in read_routes(ROUTES / f"{name}.xml"):
            if spec.scenarios and spec.scenarios[0].type == "ParkingExit":
                m = load_map(spec.town_path())
                (sc,) = build_placed(spec, m, spec.dense_routes(m))
                assert isinstance(sc, ParkingExit)
                assert m.lane_kind[sc.side] == LaneKind.PARKING and m.lane_width[sc.side] >= PARKING_WIDTH
