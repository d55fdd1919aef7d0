"""CARLA's towns as committed networks: rebuilt byte-identically, real light signals, degenerate roads,
and multi-CAV routes on all seven running without a simulation crash (the crash classes that routes
imported from Bench2Drive met: SUMO routes missing a sub-metre edge, a dead-end stub where a road goes
on, the red-light check on a town without lights)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import sumolib

from cmudrive.agents import AutopilotAgent
from cmudrive.bench import EvalConfig, evaluate_route
from cmudrive.bench.authoring.route_gen import generate_routes
from cmudrive.bench.criteria.stop_lines import StopLineTable
from cmudrive.bench.records import STATUS_AGENT_CRASHED, STATUS_SIM_CRASHED
from cmudrive.bench.routes import read_routes, write_routes
from cmudrive.maps import LanePos, RoadOption, RoutePlanner, load_map
from cmudrive.maps.errors import NetconvertError
from cmudrive.maps.importer import CARLA_TOWNS, carla_town_source, import_map, opendrive_id_map
from cmudrive.maps.netconvert import find_netconvert
from cmudrive.maps.opendrive import dead_end_stubs
from cmudrive.maps.towns import assets_dir
from cmudrive.sim import Controls, World, WorldConfig
from cmudrive.sim.background import BackgroundConfig

OPENDRIVE_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "opendrive"
FIXTURES = Path(__file__).parent / "fixtures"
FEW = BackgroundConfig(vehicles=10, pedestrians=5)

try:
    find_netconvert()
    HAVE_NETCONVERT = True
except NetconvertError:
    HAVE_NETCONVERT = False
needs_sources = pytest.mark.skipif(
    not (HAVE_NETCONVERT and OPENDRIVE_DIR.is_dir()), reason="netconvert or the CARLA .xodr files missing"
)


@needs_sources
@pytest.mark.slow
def test_committed_carla_towns_rebuild_byte_identically(tmp_path: Path) -> None:
    """`cmudrive maps build-carla DIR` gives back exactly the committed networks."""
    for town in CARLA_TOWNS:
        out = import_map(carla_town_source(OPENDRIVE_DIR, town), tmp_path / f"{town}.net.xml").dst
        assert out.read_bytes() == (assets_dir() / f"{town}.net.xml").read_bytes(), town


@needs_sources
def test_town01_lights_come_from_its_36_signals(tmp_path: Path) -> None:
    """Town01 is imported from the RoadRunner export with its 36 light signals: every light of the
    network is a junction that holds signals in the file, none is guessed."""
    src = carla_town_source(OPENDRIVE_DIR, "Town01")
    assert src.parent.name == "with-signals"
    report = import_map(src, tmp_path / "Town01.net.xml")
    assert report.source_tl_signals == 36 and report.tls_source == "opendrive"
    signal_junctions = set(opendrive_id_map(report.dst).tl_signals.values())
    committed = sumolib.net.readNet(str(assets_dir() / "Town01.net.xml"))
    lights = {t.getID() for t in committed.getTrafficLights()}
    # the 12 junctions holding the signals (3 each) have lights; netconvert adds 4 more from the same
    # signals (two mid-block pedestrian crossings, which a guess never makes, and two junctions)
    assert len(signal_junctions) == 12 and signal_junctions <= lights
    assert {"11.0", "5.20"} <= lights and len(lights) == report.tls == 16


def test_degenerate_road_joins_the_road_it_continues() -> None:
    """Town06's road 54 is 0.00002 m long; netconvert made it a 0.1 m edge into a dead end, so the
    Bench2Drive route from lane -53_2 to lane -55#0_6 could not be planned. It is gone, and -53 leads on
    into -55#0 in SUMO's network and in our lane graph."""
    path = assets_dir() / "Town06.net.xml"
    assert dead_end_stubs(path) == []
    net = sumolib.net.readNet(str(path))
    assert [e.getID() for e in net.getEdge("-53").getOutgoing()] == ["-55#0"]
    m = load_map("Town06")
    route = RoutePlanner(m).plan_lanes(LanePos(m.lane("-53_2"), 68.3), LanePos(m.lane("-55#0_6"), 54.0))
    assert 80.0 < route.length < 100.0  # 17 m + 54 m + the junction, with four short lane changes
    path = [str(m.lane_ids[lane]) for lane in route.path]
    assert path[0] == "-53_2" and path[-1] == "-55#0_6" and any(p.startswith(":704_") for p in path)
    assert len(path) >= 6  # four lane changes on the way


def test_cav_route_keeps_sub_metre_edges_for_sumo() -> None:
    """Town02's edge "2" (0.3 m) lies between two junctions: the 1 m route points skip it, the lane path
    keeps it, and SUMO accepts the CAV's route (it refused it: "No connection between edge '0' and
    edge '-18'")."""
    m = load_map("Town02")
    route = RoutePlanner(m).plan_lanes(LanePos(m.lane("0_2"), 10.0), LanePos(m.lane("-18_2"), 20.0))
    path_edges = [str(e) for e in m.edge_ids[m.lane_edge[route.path]] if not str(e).startswith(":")]
    point_edges = {str(e) for e in m.edge_ids[m.lane_edge[route.lane]]}
    assert path_edges == ["0", "2", "-18"] and "2" not in point_edges
    with World(WorldConfig("Town02", seed=0), road_map=m) as world:
        world.add_cav(route)
        snap = world.tick(Controls(np.zeros(1), np.full(1, 0.5), np.zeros(1)))
    assert snap.cav_rows()[1].tolist() == [0]


def test_collapsed_loop_lanes_are_not_driven() -> None:
    """Town06's 7-lane teardrop loops: netconvert's inner lanes fold to 3-6 m of shape for 50-58 m of
    road, and a plan along them jumped 10 m across the median. They are kept as non-driving lanes, so a
    route takes the loop's intact lane, as in CARLA."""
    m = load_map("Town06")
    assert [int(m.lane_kind[m.lane(x)]) for x in ("-71_2", "-71_3", "-71_4")] == [0, 4, 4]
    route = RoutePlanner(m).plan_lanes(LanePos(m.lane("29_3"), 2.0), LanePos(m.lane("-69_1"), 10.0))
    assert route.length > 100.0  # round the loop, not 20 m across the median
    assert "-71_3" not in {str(m.lane_ids[lane]) for lane in route.path}


def test_stop_line_lookup_on_a_town_without_lights() -> None:
    """Town06 has neither lights nor stop signs: every lane has no stop line (it raised IndexError)."""
    m = load_map("Town06")
    stops = StopLineTable.build(m, width_factor=1.0)
    lanes = np.array([-1, 0, m.lane("-53_2")])
    assert stops.at(lanes, stops.is_light).tolist() == [-1, -1, -1]
    assert stops.at(lanes, stops.is_sign).tolist() == [-1, -1, -1]


@pytest.mark.slow
@pytest.mark.parametrize("route_id", ["route_09", "route_18", "route_34", "route_41", "route_43", "route_49"])
def test_routes_that_crashed_now_run(route_id: str) -> None:
    (spec,) = [r for r in read_routes(FIXTURES / "carla_regressions.xml") if r.id == route_id]
    result = evaluate_route(spec, AutopilotAgent, EvalConfig(tick_cap=100, background=FEW))
    assert result.error is None, result.error
    assert result.ticks == 100 and result.route_completion > 0.0


def test_bench2drive_shaped_routes_on_every_carla_town_are_portable(tmp_path: Path) -> None:
    """4-CAV routes generated on each CARLA town keep the town's name, read back from another folder,
    plan, and run without a simulation or agent crash."""
    specs = [generate_routes(town, 1, 4, seed=3, length=(120.0, 220.0))[0] for town in CARLA_TOWNS]
    moved = tmp_path / "elsewhere"
    moved.mkdir()
    write_routes(specs, tmp_path / "b2d.xml")
    shutil.move(tmp_path / "b2d.xml", moved / "b2d.xml")
    text = (moved / "b2d.xml").read_text()
    assert 'town="Town03"' in text and ".net.xml" not in text
    options = set()
    for spec in read_routes(moved / "b2d.xml"):
        m = load_map(spec.town_path())
        for route in spec.dense_routes(m):
            options |= set(route.option.tolist())
        result = evaluate_route(spec, AutopilotAgent, EvalConfig(tick_cap=60, background=FEW))
        assert result.error is None, (spec.id, result.error)
        assert {c.status for c in result.cavs}.isdisjoint({STATUS_SIM_CRASHED, STATUS_AGENT_CRASHED})
    assert {RoadOption.LEFT, RoadOption.RIGHT} <= options


def test_user_network_found_beside_the_route_file_or_by_town_dir(tmp_path: Path) -> None:
    """A route file names its town; a network of that name beside the file or in a --town-dir folder
    serves it, before the committed towns."""
    (spec,) = generate_routes("downtown", 1, 2, seed=1)
    nets = tmp_path / "nets"
    nets.mkdir()
    shutil.copy(assets_dir() / "downtown.net.xml", nets / "mytown.net.xml")
    mine = type(spec)(spec.id, "mytown", spec.weather, spec.seed, spec.cavs)
    write_routes([mine], tmp_path / "r.xml")
    (read,) = read_routes(tmp_path / "r.xml")
    with pytest.raises(Exception, match=r"unknown town 'mytown'"):
        read.town_path()
    shutil.copy(nets / "mytown.net.xml", tmp_path / "mytown.net.xml")
    assert read.town_path() == tmp_path / "mytown.net.xml"
    (tmp_path / "mytown.net.xml").unlink()
    moved = type(read)(read.id, read.town, read.weather, read.seed, read.cavs, town_dirs=(str(nets),))
    assert moved.town_path() == nets / "mytown.net.xml"
