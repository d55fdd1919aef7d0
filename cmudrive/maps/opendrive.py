"""Reading OpenDRIVE files and netconvert's networks for the second import pass (``importer.py``).

netconvert ignores OpenDRIVE stop signs and road-level speed limits and cannot guess lights where the
file has none; this module reads the .xodr itself (roads, junctions, signals), reads the network that
the first netconvert pass wrote (edges with their OpenDRIVE origin ids), finds the approach edge of each
sign, guesses signalised junctions, and writes the node/edge patch netconvert applies in the second pass.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path

from cmudrive.maps.errors import MapError

SPEED_UNITS = {"m/s": 1.0, "km/h": 1.0 / 3.6, "mph": 0.44704}  # [m/s per unit]
SPEED_LANE_TYPES = frozenset({"driving", "entry", "exit", "onRamp", "offRamp", "stop"})
JUNCTION_PARAM = "opendrive.junction"  # junction parameter: its OpenDRIVE junction id
STOP_SIGNALS_PARAM = "opendrive.stopSignals"  # junction parameter: its OpenDRIVE stop-sign ids
GUESS_MIN_APPROACHES = 3  # [edges] driving edges entering a junction for a guessed traffic light
GUESS_MIN_EXITS = 2  # [edges] driving edges leaving a junction for a guessed traffic light
GUESS_MAX_SPEED = 25.0  # [m/s] (90 km/h) no guessed light where a faster road enters (highway ramps)


@dataclass(frozen=True)
class XodrSignal:
    id: str
    road: str
    s: float  # [m] along the road
    orientation: str  # "+" (traffic along +s), "-" or "none"
    type: str


@dataclass
class XodrRoad:
    id: str
    junction: str  # "-1" outside junctions
    length: float  # [m]
    links: dict[str, tuple[str, str]] = field(default_factory=dict)  # predecessor/successor -> (type, id)
    speed: float | None = None  # [m/s] the road's first <type><speed>
    lane_speeds: bool = False  # some lane has its own <speed>, which netconvert applies itself


@dataclass
class Xodr:
    roads: dict[str, XodrRoad]
    junctions: set[str]
    signals: list[XodrSignal]  # signals, and signal references resolved to their signal's type
    controllers: int

    def tl_signal_ids(self) -> set[str]:
        return {s.id for s in self.signals if is_traffic_light(s.type)}

    def signs(self, sign_type: str) -> list[XodrSignal]:
        return [s for s in self.signals if s.type == sign_type]


def is_traffic_light(signal_type: str) -> bool:
    """The OpenDRIVE signal types netconvert builds traffic lights from (1000001-1000013, 1000020)."""
    code = int(signal_type) if signal_type.isdigit() else 0
    return (1000001 <= code <= 1000013 and code != 1000008) or code == 1000020


def read_xodr(src: Path) -> Xodr:
    roads: dict[str, XodrRoad] = {}
    placed: list[tuple[ET.Element, str]] = []  # <signal> and <signalReference> elements, with their road
    try:
        root = ET.parse(src).getroot()
        for el in root.iter("road"):
            road = read_road(el)
            roads[road.id] = road
            placed += [(sig, road.id) for sig in el.iterfind("signals/*")]
        types = {el.attrib["id"]: el.get("type", "") for el, _ in placed if el.tag == "signal"}
        signals = [
            XodrSignal(el.attrib["id"], road, float(el.get("s", "0")), el.get("orientation", "none"),
                    types[el.attrib["id"]])
            for el, road in placed if el.get("id") in types
        ]  # fmt: skip
    except (ET.ParseError, OSError, KeyError, ValueError) as exc:
        raise MapError(f"{src} is not a readable OpenDRIVE file: {exc!r}") from exc
    junctions = {el.attrib["id"] for el in root.iter("junction") if "id" in el.attrib}
    return Xodr(roads, junctions, signals, len(root.findall("controller")))


def read_road(el: ET.Element) -> XodrRoad:
    road = XodrRoad(el.attrib["id"], el.get("junction", "-1"), float(el.get("length", "0")))
    for kind in ("predecessor", "successor"):
        link = el.find(f"link/{kind}")
        if link is not None:
            road.links[kind] = (link.get("elementType", "road"), link.get("elementId", ""))
    speed = el.find("type/speed")
    unit = SPEED_UNITS.get(speed.get("unit", "m/s")) if speed is not None else None
    if speed is not None and unit is not None and is_number(speed.get("max", "")):
        road.speed = float(speed.attrib["max"]) * unit
    road.lane_speeds = el.find("lanes/laneSection//lane/speed") is not None
    return road


def is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


# --------------------------------------------------------------------------------------------------
# reading a written network (ElementTree: fast, and independent of sumolib's reading options)


@dataclass(frozen=True)
class NetLane:
    id: str
    index: int
    type: str  # the OpenDRIVE lane type for OpenDRIVE imports
    allow: frozenset[str] | None  # classes in "allow"; None when not given
    deny: frozenset[str]  # classes in "disallow"
    orig: tuple[str, ...]  # origId tokens, "road_lane" for OpenDRIVE imports

    def allows(self, vclass: str) -> bool:
        return permits(self.allow, self.deny, vclass)


def permits(allow: frozenset[str] | None, deny: frozenset[str], vclass: str) -> bool:
    """SUMO's lane permissions: ``vclass`` may use a lane with these "allow" (None: attribute absent) and
    "disallow" classes."""
    if "all" in deny or vclass in deny:
        return False
    return allow is None or "all" in allow or vclass in allow


@dataclass(frozen=True)
class NetEdge:
    id: str
    from_node: str
    to_node: str
    priority: int
    lanes: tuple[NetLane, ...]

    def drivable(self) -> bool:
        return any(lane.allows("passenger") for lane in self.lanes)

    def roads(self) -> set[str]:
        return {tok.rpartition("_")[0] for lane in self.lanes for tok in lane.orig}


@dataclass
class PlainNet:
    edges: dict[str, NetEdge] = field(default_factory=dict)  # normal edges
    functions: Counter[str] = field(default_factory=Counter)  # edge count per special function
    internal_lanes: list[NetLane] = field(default_factory=list)
    junction_types: dict[str, str] = field(default_factory=dict)  # non-internal junctions
    junction_params: dict[str, dict[str, str]] = field(default_factory=dict)
    tls: dict[str, dict[str, str]] = field(default_factory=dict)  # traffic-light id -> parameters


def params_of(el: ET.Element) -> dict[str, str]:
    return {p.attrib["key"]: p.get("value", "") for p in el.iterfind("param")}


def read_net(path: Path) -> PlainNet:
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as exc:
        raise MapError(f"{path} is not a readable SUMO network: {exc}") from exc
    net = PlainNet()
    for el in root.iterfind("edge"):
        lanes = tuple(
            NetLane(ln.attrib["id"], int(ln.get("index", "0")), ln.get("type", ""),
                  frozenset(ln.attrib["allow"].split()) if "allow" in ln.attrib else None,
                  frozenset(ln.get("disallow", "").split()), tuple(params_of(ln).get("origId", "").split()))
            for ln in el.iterfind("lane")
        )  # fmt: skip
        function = el.get("function", "")
        if function:
            net.functions[function] += 1
            net.internal_lanes += lanes if function == "internal" else ()
        else:
            edge = NetEdge(
                el.attrib["id"], el.get("from", ""), el.get("to", ""), int(el.get("priority", "0")), lanes
            )
            net.edges[edge.id] = edge
    for el in root.iterfind("junction"):
        if el.get("type") != "internal":
            net.junction_types[el.attrib["id"]] = el.get("type", "")
            net.junction_params[el.attrib["id"]] = params_of(el)
    for el in root.iterfind("tlLogic"):
        net.tls.setdefault(el.attrib["id"], {}).update(params_of(el))
    return net


def edges_by_road(net: PlainNet) -> dict[str, list[NetEdge]]:
    """OpenDRIVE road id -> the normal edges built from it."""
    by_road: dict[str, list[NetEdge]] = defaultdict(list)
    for edge in net.edges.values():
        for road in edge.roads():
            by_road[road].append(edge)
    return by_road


def section_of(edge_id: str, road: str) -> tuple[bool, int] | None:
    """(right-hand side?, lane section index) of an edge netconvert named after ``road``, else None."""
    sides = [(False, edge_id)] + ([(True, edge_id[1:])] if edge_id.startswith("-") else [])
    for right, base in sides:
        head, _, index = base.rpartition("#")
        if base == road or (head == road and index.isdigit()):
            return right, int(index) if base != road else 0
    return None


# --------------------------------------------------------------------------------------------------
# pass 2: signs, guessed traffic lights, road speeds, junction ids


def sign_approaches(xodr: Xodr, net: PlainNet, sign_type: str) -> dict[str, dict[str, list[str]]]:
    """Junction id -> {approach edge id -> sign ids} for the signs of ``sign_type`` in the .xodr."""
    by_road = edges_by_road(net)
    result: dict[str, dict[str, list[str]]] = defaultdict(lambda: defaultdict(list))
    for sign in xodr.signs(sign_type):
        edge = approach_edge(sign, xodr, by_road)
        if edge is not None and edge.drivable() and edge.to_node in net.junction_types:
            result[edge.to_node][edge.id].append(sign.id)
    return result


def approach_edge(sign: XodrSignal, xodr: Xodr, by_road: dict[str, list[NetEdge]]) -> NetEdge | None:
    """The edge whose traffic a sign faces, at the end that leads into a junction."""
    road = xodr.roads.get(sign.road)
    if road is None:
        return None
    if road.junction != "-1":  # on a connecting road: the incoming road's edge into that junction
        kind, other = road.links.get("predecessor" if sign.orientation != "-" else "successor", ("", ""))
        edges = [e for e in by_road.get(other, []) if kind == "road" and e.to_node == road.junction]
        return edges[0] if edges else None
    forward = sign.orientation == "+" or (sign.orientation != "-" and sign.s > road.length / 2)
    sections = [
        (sec[1], e)
        for e in by_road.get(road.id, [])
        if (sec := section_of(e.id, road.id)) and sec[0] == forward
    ]
    if not sections:
        return None
    # right-hand traffic (+s) leaves the road through its last section, left-hand through its first
    return (max if forward else min)(sections, key=lambda item: item[0])[1]


def guess_tls(xodr: Xodr, net: PlainNet, skip: set[str]) -> list[str]:
    """OpenDRIVE junctions that look like intersections and have no signals or signs."""
    entering: Counter[str] = Counter()
    leaving: Counter[str] = Counter()
    fastest: dict[str, float] = defaultdict(float)  # [m/s] fastest road entering the junction
    for edge in net.edges.values():
        if edge.drivable():
            entering[edge.to_node] += 1
            leaving[edge.from_node] += 1
            speeds = [xodr.roads[r].speed or 0.0 for r in edge.roads() if r in xodr.roads]
            fastest[edge.to_node] = max([fastest[edge.to_node], *speeds])
    return sorted(
        j for j in xodr.junctions & set(net.junction_types) - skip
        if not net.junction_types[j].startswith("traffic_light") and fastest[j] <= GUESS_MAX_SPEED
        and entering[j] >= GUESS_MIN_APPROACHES and leaving[j] >= GUESS_MIN_EXITS
    )  # fmt: skip


def write_patches(
    nodes_path: Path, edges_path: Path, xodr: Xodr, net: PlainNet, stops: dict[str, dict[str, list[str]]],
    road_speeds: bool, removed: frozenset[str] = frozenset(),
) -> None:  # fmt: skip
    """Node patch: OpenDRIVE junction ids, stop junctions. Edge patch: minor stop approaches, speeds
    (never for the ``removed`` edges: a patch entry would make netconvert define them anew)."""
    nodes, edges = ET.Element("nodes"), ET.Element("edges")
    node_el: dict[str, ET.Element] = {}
    edge_el: dict[str, ET.Element] = {}

    def node(junction: str) -> ET.Element:
        if junction not in node_el:
            node_el[junction] = ET.SubElement(nodes, "node", id=junction)
        return node_el[junction]

    def edge(edge_id: str) -> ET.Element:
        if edge_id in removed:
            return ET.Element("edge")  # written nowhere
        if edge_id not in edge_el:
            edge_el[edge_id] = ET.SubElement(edges, "edge", id=edge_id)
        return edge_el[edge_id]

    for junction in sorted(xodr.junctions & set(net.junction_types)):
        ET.SubElement(node(junction), "param", key=JUNCTION_PARAM, value=junction)
    for junction, approaches in sorted(stops.items()):
        if net.junction_types[junction].startswith("traffic_light"):
            continue  # the light rules; its signs are for when it is off
        entering = [e for e in net.edges.values() if e.to_node == junction and e.drivable()]
        others = [e.priority for e in entering if e.id not in approaches]
        el = node(junction)
        el.set("type", "priority_stop" if others else "allway_stop")
        signs = sorted({s for ids in approaches.values() for s in ids})
        ET.SubElement(el, "param", key=STOP_SIGNALS_PARAM, value=" ".join(signs))
        for edge_id in sorted(approaches) if others else ():  # stop approaches become the minor roads
            edge(edge_id).set("priority", str(min(others) - 1))
    for road_id, edges_of_road in edges_by_road(net).items() if road_speeds else ():
        road = xodr.roads.get(road_id)
        if road is None or road.speed is None or road.lane_speeds:
            continue
        for e in edges_of_road:
            for lane in (ln for ln in e.lanes if ln.type in SPEED_LANE_TYPES):
                ET.SubElement(edge(e.id), "lane", index=str(lane.index), speed=f"{road.speed:.2f}")
    ET.ElementTree(nodes).write(nodes_path, encoding="UTF-8", xml_declaration=True)
    ET.ElementTree(edges).write(edges_path, encoding="UTF-8", xml_declaration=True)


# --------------------------------------------------------------------------------------------------
# degenerate roads

STUB_LENGTH = 1.0  # [m] an edge shorter than this that ends in a dead end is a candidate stub


@dataclass(frozen=True)
class DeadEndStub:
    """A sub-metre edge ending in a dead end beside a sibling edge with the same lanes that leaves the same
    junction: netconvert's rendering of a degenerate OpenDRIVE road (CARLA's Town06 road 54 is 0.00002 m
    long). SUMO vehicles routed onto the stub are stuck; CARLA drives on into the sibling's road."""

    stub: str
    sibling: str
    into: tuple[tuple[str, int, int], ...]  # connections into the stub: (from edge, from lane, to lane)


def dead_end_stubs(path: Path) -> list[DeadEndStub]:
    """The dead-end stubs of the network at ``path`` (see :class:`DeadEndStub`), sorted by id."""
    root = ET.parse(path).getroot()
    dead_ends = {j.attrib["id"] for j in root.iterfind("junction") if j.get("type") == "dead_end"}
    edges = {e.attrib["id"]: e for e in root.iterfind("edge") if not e.get("function")}
    stubs = []
    for eid, el in sorted(edges.items()):
        lanes = el.findall("lane")
        if el.get("to") not in dead_ends or max(float(ln.get("length", "0")) for ln in lanes) >= STUB_LENGTH:
            continue
        types = [ln.get("type", "") for ln in lanes]
        siblings = [
            oid for oid, other in sorted(edges.items())
            if oid != eid and other.get("from") == el.get("from")
            and [ln.get("type", "") for ln in other.findall("lane")] == types
        ]  # fmt: skip
        into = tuple(
            (c.attrib["from"], int(c.attrib["fromLane"]), int(c.attrib["toLane"]))
            for c in root.iterfind("connection")
            if c.get("to") == eid and not c.attrib["from"].startswith(":")
        )
        if len(siblings) == 1 and into:
            stubs.append(DeadEndStub(eid, siblings[0], into))
    return stubs


def write_stub_connections(path: Path, stubs: list[DeadEndStub]) -> None:
    """A connection file that sends every connection into a stub to its sibling instead."""
    root = ET.Element("connections")
    for stub in stubs:
        for src, from_lane, to_lane in stub.into:
            ET.SubElement(
                root, "connection", attrib={
                    "from": src, "to": stub.sibling, "fromLane": str(from_lane), "toLane": str(to_lane)
                },
            )  # fmt: skip
    ET.ElementTree(root).write(path, encoding="UTF-8", xml_declaration=True)
