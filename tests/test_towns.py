"""Procedural towns: the committed networks load, are large and connected enough, and together hold every
road layout the scenario types need; a rebuild is byte-identical; bad names give a clear error."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections import Counter
from functools import cache
from pathlib import Path

import numpy as np
import pytest
import sumolib

from cmudrive.maps.errors import MapError, NetconvertError
from cmudrive.maps.importer import CARLA_TOWNS
from cmudrive.maps.netconvert import find_netconvert
from cmudrive.maps.towns import TOWNS, assets_dir, build_town
from cmudrive.maps.towns.build import netconvert_version
from cmudrive.maps.towns.plain import write_plain

MIN_DRIVING_LANE_LENGTH = 3000.0  # [m] per town
MAX_FILE_SIZE = 10e6  # [bytes]
MOTORWAY_SPEED = 25.0  # [m/s]


def _path(town: str) -> Path:
    return assets_dir() / f"{town}.net.xml"


@cache
def _net(town: str) -> sumolib.net.Net:
    return sumolib.net.readNet(
        str(_path(town)), withInternal=True, withPedestrianConnections=True, withPrograms=True
    )


def _nets() -> list[sumolib.net.Net]:
    return [_net(t) for t in TOWNS]


def _roads(net: sumolib.net.Net) -> list[sumolib.net.edge.Edge]:
    """Normal (not internal, crossing or walking-area) edges with at least one driving lane."""
    return [e for e in net.getEdges(withInternal=False) if _drive_lanes(e)]


def _drive_lanes(edge: sumolib.net.edge.Edge) -> list[sumolib.net.lane.Lane]:
    return [lane for lane in edge.getLanes() if "passenger" in lane.getPermissions()]


def _incoming_roads(node: sumolib.net.node.Node) -> list[sumolib.net.edge.Edge]:
    return [e for e in node.getIncoming() if e.getFunction() == "" and _drive_lanes(e)]


def _legs(node: sumolib.net.node.Node) -> set[str]:
    """Neighbouring junctions reached by roads (one per leg, whatever the direction)."""
    out = {e.getToNode().getID() for e in node.getOutgoing() if e.getFunction() == "" and _drive_lanes(e)}
    return out | {e.getFromNode().getID() for e in _incoming_roads(node)}


def _heading(edge: sumolib.net.edge.Edge, at_end: bool) -> np.ndarray:
    shape = np.array(edge.getShape())
    d = shape[-1] - shape[-2] if at_end else shape[1] - shape[0]
    return d / np.linalg.norm(d)


# ---------------------------------------------------------------- catalogue and committed files


def test_catalogue_names_and_descriptions() -> None:
    assert len(TOWNS) >= 5
    for name, spec in TOWNS.items():
        assert spec.name == name
        assert spec.description and "\n" not in spec.description


def test_assets_hold_only_the_towns() -> None:
    """Our procedural towns, and CARLA's Town01-07 imported from OpenDRIVE with their licence."""
    files = {p.name for p in assets_dir().iterdir()}
    carla = {f"{t}.net.xml" for t in CARLA_TOWNS} | {"LICENSE.opendrive-test-files.txt"}
    assert files - {"README.md"} - carla == {f"{t}.net.xml" for t in TOWNS}
    assert carla <= files
    for town in TOWNS:
        assert _path(town).stat().st_size < MAX_FILE_SIZE


@pytest.mark.parametrize("town", list(TOWNS))
def test_town_is_large_and_strongly_connected(town: str) -> None:
    net = _net(town)
    roads = _roads(net)
    length = sum(lane.getLength() for e in roads for lane in _drive_lanes(e))
    assert length >= MIN_DRIVING_LANE_LENGTH, f"{town}: only {length:.0f} m of driving lanes"
    ids = {e.getID() for e in roads}
    succ: dict[str, set[str]] = {i: set() for i in ids}
    pred: dict[str, set[str]] = {i: set() for i in ids}
    for e in roads:
        for to in e.getOutgoing():
            if to.getID() in ids:
                succ[e.getID()].add(to.getID())
                pred[to.getID()].add(e.getID())

    def reach(start: str, adj: dict[str, set[str]]) -> set[str]:
        seen, stack = {start}, [start]
        while stack:
            for n in adj[stack.pop()] - seen:
                seen.add(n)
                stack.append(n)
        return seen

    start = roads[0].getID()
    assert reach(start, succ) == ids == reach(start, pred), f"{town}: not every road reaches every other"


# ---------------------------------------------------------------- required layouts, across towns


def test_signalised_junction_with_multilane_approaches_and_permissive_left() -> None:
    """A left turn that is green-minor ('g', must yield) while the oncoming straight is green ('G')."""
    found = []
    for net in _nets():
        for tls in net.getTrafficLights():
            node = net.getNode(tls.getID())
            if not any(len(_drive_lanes(e)) >= 2 for e in _incoming_roads(node)):
                continue
            links = {}
            for in_lane, out_lane, index in tls.getConnections():
                conn = next(c for c in in_lane.getOutgoing() if c.getToLane() == out_lane)
                links[index] = conn
            for program in tls.getPrograms().values():
                for phase in program.getPhases():
                    for i, left in links.items():
                        if left.getDirection() != "l" or phase.state[i] != "g":
                            continue
                        h_left = _heading(left.getFrom(), at_end=True)
                        for j, straight in links.items():
                            if straight.getDirection() == "s" and phase.state[j] == "G":
                                if float(h_left @ _heading(straight.getFrom(), at_end=True)) < -0.9:
                                    found.append(tls.getID())
    assert found, "no signalised junction with a permissive (yielding) left turn against oncoming traffic"


@pytest.mark.parametrize("control", ["priority", "allway_stop", "priority_stop", "right_before_left"])
def test_unsignalised_junction_types(control: str) -> None:
    nodes = [n for net in _nets() for n in net.getNodes() if n.getType() == control]
    assert any(len(_incoming_roads(n)) >= 3 for n in nodes), f"no {control} junction with >= 3 approaches"


def test_t_junctions() -> None:
    counts = Counter(len(_legs(n)) for net in _nets() for n in net.getNodes())
    assert counts[3] >= 5 and counts[4] >= 5


def test_two_way_road_with_one_lane_each_way_and_adjacent_opposite_lane() -> None:
    """1+1 roads whose oncoming lane lies directly left of the ego lane (no gap, no median)."""
    found = 0
    for net in _nets():
        for e in _roads(net):
            lanes = _drive_lanes(e)
            reverse = [r for r in e.getToNode().getOutgoing() if r.getToNode() == e.getFromNode()]
            if len(lanes) != 1 or not reverse or len(_drive_lanes(reverse[0])) != 1:
                continue
            lane, opposite = lanes[0], _drive_lanes(reverse[0])[0]
            mid = sumolib.geomhelper.positionAtShapeOffset(lane.getShape(), lane.getLength() / 2)
            gap = sumolib.geomhelper.distancePointToPolygon(mid, opposite.getShape())
            assert gap == pytest.approx((lane.getWidth() + opposite.getWidth()) / 2, abs=0.1), e.getID()
            left = np.array(mid) + _left_normal(lane) * (lane.getWidth() + opposite.getWidth()) / 2
            assert sumolib.geomhelper.distancePointToPolygon(tuple(left), opposite.getShape()) < 0.1
            found += 1
    assert found >= 20


def _left_normal(lane: sumolib.net.lane.Lane) -> np.ndarray:
    shape = np.array(lane.getShape())
    i = int(np.searchsorted(np.cumsum(np.linalg.norm(np.diff(shape, axis=0), axis=1)), lane.getLength() / 2))
    d = shape[min(i, len(shape) - 2) + 1] - shape[min(i, len(shape) - 2)]
    d /= np.linalg.norm(d)
    return np.array([-d[1], d[0]])


def test_one_way_road_with_three_lanes() -> None:
    found = [
        e.getID()
        for net in _nets()
        for e in _roads(net)
        if len(_drive_lanes(e)) >= 3
        and not any(r.getToNode() == e.getFromNode() and _drive_lanes(r) for r in e.getToNode().getOutgoing())
        and e.getSpeed() < MOTORWAY_SPEED
    ]
    assert found, "no urban one-way road with >= 3 lanes"


def _lane_types(path: Path) -> dict[str, str]:
    return {el.get("id", ""): el.get("type", "") for el in ET.parse(path).iter("lane") if el.get("type")}


def test_parking_lanes_are_custom1_and_never_connected() -> None:
    parking = 0
    for town in TOWNS:
        net = _net(town)
        for lane_id, kind in _lane_types(_path(town)).items():
            assert kind == "parking", f"{town}: unexpected lane type {kind!r}"
            lane = net.getLane(lane_id)
            assert lane.getPermissions() == {"custom1"}
            assert not lane.getOutgoing() and not lane.getIncoming(), f"{lane_id} is connected"
            parking += 1
    assert parking >= 10


def test_bike_lanes() -> None:
    bike = [
        lane
        for net in _nets()
        for e in _roads(net)
        for lane in e.getLanes()
        if lane.getPermissions() == {"bicycle"}
    ]
    assert len(bike) >= 10


def test_motorway_with_on_ramp_merge_and_exit() -> None:
    def motorway(e: sumolib.net.edge.Edge) -> bool:
        return len(_drive_lanes(e)) >= 3 and e.getSpeed() >= MOTORWAY_SPEED

    merges, exits, acceleration = 0, 0, 0
    for net in _nets():
        for node in net.getNodes():
            ins = _incoming_roads(node)
            outs = [e for e in node.getOutgoing() if e.getFunction() == "" and _drive_lanes(e)]
            main_in = [e for e in ins if motorway(e)]
            if len(ins) == 2 and len(main_in) == 1 and len(outs) == 1 and motorway(outs[0]):
                ramp = next(e for e in ins if e is not main_in[0])
                if ramp.getSpeed() < MOTORWAY_SPEED and len(_drive_lanes(outs[0])) > len(
                    _drive_lanes(main_in[0])
                ):
                    merges += 1  # the ramp becomes a new right lane
            if len(ins) == 1 and motorway(ins[0]) and len(outs) == 2 and sum(map(motorway, outs)) == 1:
                exits += 1
        acceleration += sum(lane.isAccelerationLane() for e in _roads(net) for lane in e.getLanes())
    assert merges >= 2 and exits >= 2 and acceleration >= 1


def test_interurban_road_with_junctions() -> None:
    found = [
        e.getID()
        for net in _nets()
        for e in _roads(net)
        if len(_drive_lanes(e)) == 2 and 20.0 <= e.getSpeed() <= 25.0 and len(_legs(e.getToNode())) >= 3
    ]
    assert found


def test_sidewalks_and_crossings_in_town_but_not_on_the_motorway() -> None:
    crossings = [e for net in _nets() for e in net.getEdges() if e.getFunction() == "crossing"]
    sidewalks = [
        e for net in _nets() for e in _roads(net) if e.getLanes()[0].getPermissions() == {"pedestrian"}
    ]
    assert len(crossings) >= 20 and len(sidewalks) >= 20
    fast = [e for net in _nets() for e in _roads(net) if e.getSpeed() >= MOTORWAY_SPEED]
    assert fast and not any("pedestrian" in lane.getPermissions() for e in fast for lane in e.getLanes())


# ---------------------------------------------------------------- generator


@pytest.mark.parametrize("town", list(TOWNS))
def test_every_seed_gives_a_valid_road_graph(town: str, tmp_path: Path) -> None:
    spec = TOWNS[town]
    for seed in range(8):
        spec.layout.build(np.random.default_rng(seed)).check(town)
    a = write_plain(spec.layout.build(np.random.default_rng(1)), tmp_path / "a", town)
    b = write_plain(spec.layout.build(np.random.default_rng(1)), tmp_path / "b", town)
    assert a.edges.read_bytes() == b.edges.read_bytes() and a.nodes.read_bytes() == b.nodes.read_bytes()


@pytest.mark.parametrize("town", ["downtown", "highway"])
def test_rebuild_is_byte_identical(town: str, tmp_path: Path) -> None:
    try:
        find_netconvert()
    except NetconvertError as exc:
        pytest.skip(f"netconvert not installed, cannot rebuild towns: {exc}")
    built = build_town(town, tmp_path)
    if netconvert_version(built) != netconvert_version(_path(town)):
        pytest.skip(
            f"committed {town} was built by {netconvert_version(_path(town))}, "
            f"this is {netconvert_version(built)}"
        )
    assert built.read_bytes() == _path(town).read_bytes()


def test_unknown_town_names_the_valid_ones(tmp_path: Path) -> None:
    with pytest.raises(MapError, match="atlantis") as info:
        build_town("atlantis", tmp_path)
    assert all(t in str(info.value) for t in TOWNS)
