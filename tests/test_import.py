"""OpenDRIVE / OpenStreetMap import (cmudrive.maps.importer, cmudrive.maps.coords) on CARLA's Town01-07.

The towns are read from ``shared/data/opendrive`` beside the repository and imported once per session
into a temporary folder. These 2019 CARLA files carry no signals at all, so the towns get guessed traffic
lights; OpenDRIVE signals and stop signs are tested by adding them to a temporary copy of Town01.
"""

from __future__ import annotations

import math
import os
import subprocess
import warnings
import xml.etree.ElementTree as ET
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import pytest
import sumolib

from cmudrive.maps.coords import carla_to_map, carla_yaw_to_map, map_to_carla, map_yaw_to_carla
from cmudrive.maps.errors import MapError, NetconvertError
from cmudrive.maps.importer import (
    ImportOptions,
    ImportReport,
    import_map,
    opendrive_id_map,
    summarise_warnings,
)
from cmudrive.maps.netconvert import find_netconvert

OPENDRIVE_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "opendrive"
TOWNS = [f"Town0{i}" for i in range(1, 8)]
# traffic lights guessed at junctions where >= 3 driving edges enter and 2 leave, no road > 90 km/h enters
GUESSED_LIGHTS = {"Town01": 12, "Town02": 8}  # every junction of these two towns is a 3-way intersection

try:
    find_netconvert()
    HAVE_NETCONVERT = True
except NetconvertError:
    HAVE_NETCONVERT = False
needs_netconvert = pytest.mark.skipif(
    not HAVE_NETCONVERT, reason="netconvert missing: pip install eclipse-sumo"
)
needs_towns = pytest.mark.skipif(
    not OPENDRIVE_DIR.is_dir(), reason=f"CARLA OpenDRIVE towns not found in {OPENDRIVE_DIR}"
)


@dataclass
class Imported:
    report: ImportReport

    @cached_property
    def net(self) -> sumolib.net.Net:
        with warnings.catch_warnings():  # sumolib warns when rtree is missing
            warnings.simplefilter("ignore")
            return sumolib.net.readNet(
                str(self.report.dst), withInternal=True, withPedestrianConnections=True
            )

    @cached_property
    def lane_types(self) -> dict[str, str]:
        """Lane id -> OpenDRIVE lane type (sumolib does not read it)."""
        root = ET.parse(self.report.dst).getroot()
        return {lane.attrib["id"]: lane.get("type", "") for lane in root.iter("lane")}

    def driving_edges(self) -> list[sumolib.net.edge.Edge]:
        return [e for e in self.net.getEdges(withInternal=False) if e.allows("passenger")]


@pytest.fixture(scope="session")
def town(tmp_path_factory: pytest.TempPathFactory) -> Callable[[str], Imported]:
    """town(name): the town imported with default options, once per session."""
    if not OPENDRIVE_DIR.is_dir():
        pytest.skip(f"CARLA OpenDRIVE towns not found in {OPENDRIVE_DIR}")
    out = tmp_path_factory.mktemp("towns")
    cache: dict[str, Imported] = {}

    def get(name: str) -> Imported:
        if name not in cache:
            cache[name] = Imported(import_map(OPENDRIVE_DIR / f"{name}.xodr", out / f"{name}.net.xml"))
        return cache[name]

    return get


# --------------------------------------------------------------------------------------------------
# coordinates


def test_carla_to_map_mirrors_y_and_reverses_yaw() -> None:
    xy, yaw = carla_to_map(np.array([[338.98, 226.75, 0.5]]), np.array([-90.0]))
    np.testing.assert_allclose(xy, [[338.98, -226.75, 0.5]])
    np.testing.assert_allclose(yaw, [math.pi / 2])  # CARLA yaw -90 deg: towards -y_carla = north
    np.testing.assert_allclose(carla_yaw_to_map([0.0, 90.0, 180.0]), [0.0, -math.pi / 2, -math.pi])
    np.testing.assert_allclose(map_yaw_to_carla([0.0, math.pi / 2, -math.pi]), [0.0, -90.0, -180.0])


def test_coordinate_round_trip() -> None:
    rng = np.random.default_rng(0)
    points = rng.uniform(-500.0, 500.0, size=(100, 3))
    yaws = rng.uniform(-180.0, 180.0, size=100)
    there, yaw_rad = carla_to_map(points, yaws)
    back, yaw_deg = map_to_carla(there, yaw_rad)
    np.testing.assert_allclose(back, points)
    np.testing.assert_allclose((yaw_deg - yaws + 180.0) % 360.0 - 180.0, 0.0, atol=1e-9)
    assert np.all((yaw_rad >= -math.pi) & (yaw_rad < math.pi))
    np.testing.assert_allclose(map_to_carla(carla_to_map(points[:, :2])), points[:, :2])


def test_coordinates_reject_bad_shapes() -> None:
    with pytest.raises(ValueError, match="shape"):
        carla_to_map(np.zeros((4, 4)))
    with pytest.raises(ValueError, match="shape"):
        map_to_carla(1.0)


# --------------------------------------------------------------------------------------------------
# the CARLA towns


@needs_netconvert
@needs_towns
@pytest.mark.parametrize("name", TOWNS)
def test_town_imports_unshifted(town: Callable[[str], Imported], name: str) -> None:
    imported = town(name)
    report = imported.report
    print(
        f"{name}: {report.seconds:.2f} s, {report.edges} edges, {report.driving_lanes} driving lanes, "
        f"{report.tls} tls ({report.tls_source}), {report.stop_junctions} stop junctions, "
        f"{report.sidewalks} sidewalks, {report.crossings} crossings"
    )
    assert report.kind == "opendrive" and report.dst.is_file()
    assert report.edges > 0 and report.driving_lanes > 0 and report.seconds > 0.0
    assert tuple(imported.net.getLocationOffset()) == (0.0, 0.0)  # no shift: net x, y == OpenDRIVE x, y
    _assert_sumo_loads(report.dst, validate=name == "Town01")
    # the innermost right lane of long straight roads lies half its width right of the reference line
    errors = _reference_line_errors(name, imported)
    assert errors, f"{name}: no straight road to check"
    assert max(errors) < 0.1, f"{name}: lanes are {max(errors):.2f} m off their OpenDRIVE position"


def _assert_sumo_loads(net: Path, validate: bool = False) -> None:
    """SUMO loads the network (optionally validating it against its schema, ~2 s) and runs 60 s."""
    home = find_netconvert().resolve().parent.parent
    if not (home / "bin" / "sumo").is_file():
        return
    validation = "always" if validate else "never"
    cmd = [str(home / "bin" / "sumo"), "-n", str(net), "--end", "60", "--xml-validation.net", validation]
    proc = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, "SUMO_HOME": str(home)})
    assert proc.returncode == 0 and "Error" not in proc.stderr, proc.stderr[-2000:]


def _reference_line_errors(name: str, imported: Imported) -> list[float]:
    """|distance(reference-line midpoint, SUMO lane -1) - expected| [m] over the straight roads of a town.

    Lane -1 is the innermost right-hand lane: its centre lies at t = laneOffset(s) - width/2.
    """
    id_map = opendrive_id_map(imported.report.dst)
    errors = []
    for road in ET.parse(OPENDRIVE_DIR / f"{name}.xodr").getroot().iter("road"):
        sections = road.findall("lanes/laneSection")
        lane = sections[0].find("right/lane[@id='-1']") if len(sections) == 1 else None
        width = lane.find("width") if lane is not None else None
        mid = float(road.attrib["length"]) / 2
        if (
            road.get("junction") != "-1"
            or mid < 10.0
            or width is None
            or lane is None
            or lane.get("type") == "none"
        ):
            continue
        lines = [g for g in road.iterfind("planView/geometry") if g.find("line") is not None]
        lines = [
            g
            for g in lines
            if float(g.attrib["s"]) <= mid <= float(g.attrib["s"]) + float(g.attrib["length"])
        ]
        if not lines or any(float(width.get(k, "0")) for k in "bcd"):
            continue
        s0, hdg = float(lines[0].attrib["s"]), float(lines[0].attrib["hdg"])
        x = float(lines[0].attrib["x"]) + math.cos(hdg) * (mid - s0)
        y = float(lines[0].attrib["y"]) + math.sin(hdg) * (mid - s0)
        offset = 0.0
        for rec in road.iterfind("lanes/laneOffset"):
            ds = mid - float(rec.attrib["s"])
            if ds >= 0.0:
                a, b, c, d = (float(rec.attrib[k]) for k in "abcd")
                offset = a + b * ds + c * ds**2 + d * ds**3
        shapes = [imported.net.getLane(i).getShape() for i in id_map.lanes_of(road.attrib["id"], -1)]
        dist = min(sumolib.geomhelper.distancePointToPolygon((x, y), shape) for shape in shapes)
        errors.append(abs(dist - abs(offset - float(width.attrib["a"]) / 2)))
    return errors


@needs_netconvert
@needs_towns
def test_town01_driving_lanes_are_about_four_metres_wide(town: Callable[[str], Imported]) -> None:
    widths = [lane.getWidth() for e in town("Town01").driving_edges() for lane in e.getLanes()]
    assert 3.5 <= float(np.median(widths)) <= 4.5


@needs_netconvert
@needs_towns
@pytest.mark.parametrize("name", TOWNS)
def test_traffic_lights(town: Callable[[str], Imported], name: str) -> None:
    report = town(name).report
    tls_junctions = [n for n in town(name).net.getNodes() if n.getType().startswith("traffic_light")]
    assert len(tls_junctions) == report.tls
    # CARLA's 2019 town files carry no signals or controllers, so every light is guessed (OpenDRIVE
    # signals are tested on an amended Town01 below)
    assert report.source_tl_signals == report.source_controllers == 0
    assert report.tls_source == ("guessed" if report.tls else "none")
    assert report.tls == GUESSED_LIGHTS.get(name, report.tls)
    if name != "Town06":  # each of Town06's three intersections has a 65 mph road entering: no light
        assert report.tls >= 1


@needs_netconvert
@needs_towns
@pytest.mark.parametrize("name", TOWNS)
def test_sidewalks_are_pedestrian_only_with_crossings(town: Callable[[str], Imported], name: str) -> None:
    imported = town(name)
    xodr_sidewalks = sum(
        lane.get("type") == "sidewalk"
        for lane in ET.parse(OPENDRIVE_DIR / f"{name}.xodr").getroot().iter("lane")
    )
    lanes = [lane for e in imported.net.getEdges(withInternal=False) for lane in e.getLanes()]
    sidewalks = [ln for ln in lanes if ln.allows("pedestrian") and not ln.allows("passenger")]
    assert all(not ln.allows("bicycle") for ln in sidewalks)
    assert all(not ln.allows("pedestrian") for ln in lanes if ln.allows("passenger"))
    types = imported.lane_types
    parking = [ln for ln in lanes if types[ln.getID()] == "parking"]  # custom1 (emergency when < 1.8 m wide)
    assert all(not ln.allows("passenger") and not ln.allows("pedestrian") for ln in parking)
    assert all(ln.getPermissions() == {"custom1"} for ln in parking if ln.getWidth() >= 1.8)
    assert all(not ln.getPermissions() for ln in lanes if types[ln.getID()] == "shoulder")
    crossings = [e for e in imported.net.getEdges(withInternal=True) if e.getFunction() == "crossing"]
    assert len(sidewalks) == imported.report.sidewalks
    assert len(crossings) == imported.report.crossings
    if xodr_sidewalks:  # every town with sidewalks has them meeting at junctions
        assert sidewalks and crossings and imported.report.walking_areas > 0
    else:
        assert not sidewalks and not crossings


@needs_netconvert
@needs_towns
@pytest.mark.filterwarnings("ignore:Module 'rtree' not available")
def test_carla_spawn_point_lies_on_a_driving_lane(town: Callable[[str], Imported]) -> None:
    # CARLA 0.9 Town01 spawn point: Location(x=338.98, y=226.75), Rotation(yaw=-90)
    (x, y), yaw = carla_to_map([338.98, 226.75], -90.0)
    net = town("Town01").net
    lanes = [(d, lane) for lane, d in net.getNeighboringLanes(x, y, 3.0) if lane.allows("passenger")]
    assert lanes, "no driving lane within 3 m"
    dist, lane = min(lanes, key=lambda item: item[0])
    assert dist < 1.0
    offset, _ = sumolib.geomhelper.polygonOffsetAndDistanceToPoint((x, y), lane.getShape())
    heading = sumolib.geomhelper.rotationAtShapeOffset(lane.getShape(), offset)  # [rad] CCW from +x
    assert abs((heading - float(yaw) + math.pi) % (2 * math.pi) - math.pi) < math.radians(5.0)


@needs_netconvert
@needs_towns
def test_id_map_links_opendrive_roads_and_lanes(town: Callable[[str], Imported]) -> None:
    imported = town("Town01")
    id_map = opendrive_id_map(imported.report.dst)
    assert id_map.road_edges["0"] == ("-0", "0")  # road 0: right-hand lanes "-0", left-hand "0"
    (lane_id,) = id_map.lanes_of("0", -1)
    lane = imported.net.getLane(lane_id)
    assert lane.allows("passenger") and lane.getParam("origId") == "0_-1"
    (sidewalk,) = id_map.lanes_of("0", -3)
    assert imported.lane_types[sidewalk] == "sidewalk"
    assert imported.net.getLane(sidewalk).getPermissions() == {"pedestrian"}
    xodr = ET.parse(OPENDRIVE_DIR / "Town01.xodr").getroot()
    assert set(id_map.junctions) == {j.attrib["id"] for j in xodr.iter("junction")}
    connecting = {r.attrib["id"] for r in xodr.iter("road") if r.get("junction") != "-1"}
    assert set(id_map.connecting_roads) <= connecting and len(id_map.connecting_roads) > 0.9 * len(connecting)
    internal = {lane.getID() for e in imported.net.getEdges(withInternal=True) for lane in e.getLanes()}
    assert all(set(ids) <= internal for ids in id_map.connecting_roads.values())


@needs_netconvert
@needs_towns
@pytest.mark.parametrize("name", TOWNS)
def test_no_car_lane_runs_past_the_road_it_joins(town: Callable[[str], Imported], name: str) -> None:
    """Where a car lane hands over to a junction's internal lane, that lane leads on, not back: netconvert
    ran Town03's road 66 17.5 m past its join and back (cmudrive.maps.lane_ends)."""
    imported = town(name)
    backward = []
    for edge in imported.net.getEdges(withInternal=False):
        for lane in edge.getLanes():
            shape = np.array(lane.getShape())[:, :2]
            if not lane.allows("passenger") or len(shape) < 3:  # a 2-point lane cannot be cut back
                continue
            end = math.atan2(*(shape[-1] - shape[-2])[::-1])
            for conn in lane.getOutgoing():
                via = conn.getViaLaneID()
                if not via:
                    continue
                link = np.array(imported.net.getLane(via).getShape())[:, :2]
                start = math.atan2(*(link[1] - link[0])[::-1])
                if abs((start - end + math.pi) % (2 * math.pi) - math.pi) > math.radians(100):
                    backward.append(f"{lane.getID()} -> {via}")
    assert backward == []
    if name == "Town03":
        assert any(r.startswith("-66_5 ") for r in imported.report.lane_end_repairs)


@needs_netconvert
@needs_towns
@pytest.mark.parametrize("name", TOWNS)
def test_route_across_the_town(town: Callable[[str], Imported], name: str) -> None:
    imported = town(name)
    edges = imported.driving_edges()
    centres = np.array([np.mean(e.getShape(), axis=0) for e in edges])
    dist = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
    i, j = np.unravel_index(np.argmax(dist), dist.shape)
    path, cost = imported.net.getShortestPath(edges[i], edges[j], vClass="passenger")
    assert path is not None, f"no route from {edges[i].getID()} to {edges[j].getID()}"
    assert path[0] == edges[i] and path[-1] == edges[j] and cost >= dist[i, j]


# --------------------------------------------------------------------------------------------------
# OpenDRIVE signals and stop signs, added to a copy of Town01


def _approaches(root: ET.Element, junction: str) -> Iterator[tuple[ET.Element, str]]:
    """(road, "predecessor"/"successor") for each road that ends at ``junction``."""
    for road in root.iter("road"):
        for end in ("predecessor", "successor"):
            link = road.find(f"link/{end}")
            if road.get("junction") == "-1" and link is not None and link.get("elementType") == "junction":
                if link.get("elementId") == junction:
                    yield road, end


def _add_signal(road: ET.Element, end: str, signal_id: str, signal_type: str) -> None:
    """A signal facing the traffic that drives towards ``end`` of ``road``, 1 m before it."""
    length = float(road.attrib["length"])
    s, orientation, lane = (length - 1.0, "+", "-1") if end == "successor" else (1.0, "-", "1")
    signals = road.find("signals")
    if signals is None:
        signals = ET.SubElement(road, "signals")
    dynamic = "no" if signal_type == "206" else "yes"
    attrs = {"s": f"{s}", "t": "0", "id": signal_id, "name": "test", "dynamic": dynamic,
             "orientation": orientation, "zOffset": "0", "country": "OpenDRIVE", "type": signal_type,
             "subtype": "-1", "value": "-1"}  # fmt: skip
    ET.SubElement(ET.SubElement(signals, "signal", attrs), "validity", fromLane=lane, toLane=lane)


@pytest.fixture(scope="session")
def signalled_town01(tmp_path_factory: pytest.TempPathFactory) -> tuple[ImportReport, dict[str, list[str]]]:
    """Town01 with traffic lights (one controller) at junction 111, stop signs on every approach of
    junction 128, on one approach of junction 139 and on one connecting road inside junction 156;
    returns the report and the added signal ids per junction."""
    if not OPENDRIVE_DIR.is_dir():
        pytest.skip(f"CARLA OpenDRIVE towns not found in {OPENDRIVE_DIR}")
    tree = ET.parse(OPENDRIVE_DIR / "Town01.xodr")
    root = tree.getroot()
    ids: dict[str, list[str]] = {"111": [], "128": [], "139": [], "156": []}
    for junction, signal_type, count in (("111", "1000001", 9), ("128", "206", 9), ("139", "206", 1)):
        for k, (road, end) in enumerate(list(_approaches(root, junction))[:count]):
            ids[junction].append(f"{junction}{k}")
            _add_signal(road, end, ids[junction][-1], signal_type)
    inside = next(
        r
        for r in root.iter("road")
        if r.get("junction") == "156" and r.find("lanes//lane[@id='-1']") is not None
    )
    ids["156"].append("1560")
    _add_signal(inside, "successor", "1560", "206")  # faces traffic coming from the predecessor road
    controller = ET.SubElement(root, "controller", id="1", name="junction 111")
    for signal_id in ids["111"]:
        ET.SubElement(controller, "control", signalId=signal_id, type="0")
    out = tmp_path_factory.mktemp("signalled")
    tree.write(out / "Town01_signals.xodr", encoding="UTF-8", xml_declaration=True)
    return import_map(out / "Town01_signals.xodr", out / "Town01_signals.net.xml"), ids


@needs_netconvert
def test_opendrive_signals_become_traffic_lights_and_stop_junctions(
    signalled_town01: tuple[ImportReport, dict[str, list[str]]],
) -> None:
    report, ids = signalled_town01
    _assert_sumo_loads(report.dst, validate=True)
    assert len(ids["111"]) == 3 and len(ids["128"]) == 3 and len(ids["139"]) == 1
    assert report.source_tl_signals == 3 and report.source_stop_signs == 5 and report.source_controllers == 1
    assert report.tls_source == "opendrive" and report.tls == 1  # signals given: nothing is guessed
    assert report.stop_junctions == 3
    net = sumolib.net.readNet(str(report.dst))
    assert net.getNode("111").getType() == "traffic_light"
    assert net.getNode("128").getType() == "allway_stop"
    assert net.getNode("139").getType() == "priority_stop"
    assert net.getNode("156").getType() == "priority_stop"
    # at the priority-stop junction, the approach with the sign is the minor road
    id_map = opendrive_id_map(report.dst)
    assert id_map.tl_signals == {signal: "111" for signal in ids["111"]}
    assert id_map.stop_signals == {s: j for j in ("128", "139", "156") for s in ids[j]}
    road, _ = next(_approaches(ET.parse(OPENDRIVE_DIR / "Town01.xodr").getroot(), "139"))  # the signed road
    entering = {e.getID(): e.getPriority() for e in net.getNode("139").getIncoming() if e.allows("passenger")}
    (stop_edge,) = [e for e in id_map.road_edges[road.attrib["id"]] if e in entering]
    assert entering[stop_edge] < min(p for e, p in entering.items() if e != stop_edge)


@needs_netconvert
@needs_towns
def test_tls_policy_none_builds_no_lights(tmp_path: Path) -> None:
    report = import_map(OPENDRIVE_DIR / "Town01.xodr", tmp_path / "t.net.xml", ImportOptions(tls="none"))
    assert report.tls == 0 and report.tls_source == "none"


# --------------------------------------------------------------------------------------------------
# OpenStreetMap


TINY_OSM = """<?xml version="1.0" encoding="UTF-8"?>
<osm version="0.6" generator="cmudrive tests">
  <bounds minlat="48.9990" minlon="7.9985" maxlat="49.0010" maxlon="8.0015"/>
  <node id="1" lat="49.0000" lon="8.0000"><tag k="highway" v="traffic_signals"/></node>
  <node id="2" lat="49.0000" lon="7.9986"/>
  <node id="3" lat="49.0000" lon="8.0014"/>
  <node id="4" lat="49.0009" lon="8.0000"/>
  <node id="5" lat="48.9991" lon="8.0000"/>
  <way id="10"><nd ref="2"/><nd ref="1"/><nd ref="3"/>
    <tag k="highway" v="residential"/><tag k="sidewalk" v="both"/></way>
  <way id="11"><nd ref="4"/><nd ref="1"/><nd ref="5"/>
    <tag k="highway" v="residential"/><tag k="sidewalk" v="both"/></way>
</osm>
"""


@needs_netconvert
def test_osm_import_keeps_signals_sidewalks_and_crossings(tmp_path: Path) -> None:
    src = tmp_path / "cross.osm.xml"
    src.write_text(TINY_OSM)
    report = import_map(src, tmp_path / "cross.net.xml")
    assert report.kind == "osm" and report.tls == 1 and report.tls_source == "osm"
    assert report.sidewalks > 0 and report.crossings > 0 and report.driving_lanes > 0
    location = ET.parse(report.dst).getroot().find("location")
    assert location is not None and "+proj=utm" in location.attrib["projParameter"]


# --------------------------------------------------------------------------------------------------
# bad input


BAD_INPUTS = {
    "missing.xodr": None,
    "notes.txt": "a plain text file",
    "random.xodr": "this is not\nan OpenDRIVE map\n",
    "garbage.osm": bytes(range(256)) * 8,
    "wrong_root.xodr": '<?xml version="1.0"?><osm version="0.6"/>',
    "wrong_root.osm": "<OpenDRIVE><header revMajor='1' revMinor='4'/></OpenDRIVE>",
}


@needs_netconvert
@pytest.mark.parametrize("name", sorted(BAD_INPUTS))
def test_bad_input_raises_map_error_and_leaves_nothing(tmp_path: Path, name: str) -> None:
    src = tmp_path / "in" / name
    src.parent.mkdir()
    content = BAD_INPUTS[name]
    if isinstance(content, bytes):
        src.write_bytes(content)
    elif content is not None:
        src.write_text(content)
    dst = tmp_path / "out" / "result.net.xml"
    with pytest.raises(MapError, match=name.replace(".", r"\.")):
        import_map(src, dst)
    assert not (tmp_path / "out").exists()


@needs_netconvert
@pytest.mark.parametrize(
    "content",
    [
        "<OpenDRIVE><header/></OpenDRIVE>",  # no roads
        '<OpenDRIVE><header revMajor="1" revMinor="4"/><road id="1" length="10"/></OpenDRIVE>',  # no junction
    ],
)
def test_netconvert_failure_raises_netconvert_error_and_leaves_nothing(tmp_path: Path, content: str) -> None:
    src = tmp_path / "broken.xodr"
    src.write_text(content)
    (tmp_path / "out").mkdir()
    dst = tmp_path / "out" / "broken.net.xml"
    with pytest.raises(NetconvertError, match=r"broken\.xodr"):
        import_map(src, dst)
    assert list((tmp_path / "out").iterdir()) == []


@needs_netconvert
@needs_towns
def test_output_folder_instead_of_file_is_refused(tmp_path: Path) -> None:
    with pytest.raises(MapError, match="Town01"):
        import_map(OPENDRIVE_DIR / "Town01.xodr", tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_warnings_are_summarised_by_kind() -> None:
    lines = [
        "Warning: Lane '-1_2' is not connected from any incoming edge at junction '7'.",
        "Warning: Lane '5_0' is not connected from any incoming edge at junction '12'.",
        "Warning: Edge '3' has a grade of 12.5%.",
        "Success.",
    ]
    assert summarise_warnings(lines) == (
        "2 x Lane '%' is not connected from any incoming edge at junction '%'.",
        "1 x Edge '%' has a grade of #%.",
    )
