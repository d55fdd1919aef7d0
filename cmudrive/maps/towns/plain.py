"""Write a RoadGraph as SUMO plain XML: ``.nod.xml``, ``.edg.xml``, ``.con.xml`` and ``.typ.xml``.

Numbers are written with fixed precision and elements in graph order, so equal graphs give equal files.
Parking lanes must not be linked through junctions, but netconvert adds such links for class ``custom1``
even against ``<delete>`` entries (straight on at T-junctions and corners). So a town is converted twice:
first with parking lanes closed to every class (``close_parking``), then with every lane-to-lane connection
of that first network (``read_connections``) given explicitly, which netconvert keeps as they are.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

from cmudrive.maps.towns.graph import Edge, LaneLink, RoadGraph
from cmudrive.maps.towns.roads import Lane

XML_HEAD = '<?xml version="1.0" encoding="UTF-8"?>\n'


@dataclass(frozen=True)
class PlainFiles:
    """Paths of the plain-XML files of one town."""

    nodes: Path
    edges: Path
    connections: Path
    types: Path

    def netconvert_args(self) -> list[str]:
        return [
            "--node-files", str(self.nodes),
            "--edge-files", str(self.edges),
            "--connection-files", str(self.connections),
            "--type-files", str(self.types),
        ]  # fmt: skip


def _f(v: float) -> str:
    return f"{v:.2f}"


def _lane_xml(index: int, lane: Lane, bicycles: bool, close_parking: bool) -> str:
    attrs = [f'index="{index}"']
    if lane.kind == "sidewalk":
        attrs.append('allow="pedestrian"')
    elif lane.kind == "parking":
        attrs += ['disallow="all"' if close_parking else 'allow="custom1"', 'type="parking"']
    elif lane.kind == "bike":
        attrs.append('allow="bicycle"')
    else:
        # custom1 is the parking class: keeping it off driving lanes leaves parking lanes unconnected
        attrs.append('disallow="pedestrian custom1"' if bicycles else 'disallow="pedestrian bicycle custom1"')
    attrs.append(f'width="{_f(lane.width)}"')
    if lane.acceleration:
        attrs.append('acceleration="true"')
    return f"        <lane {' '.join(attrs)}/>\n"


def _edge_xml(edge: Edge, close_parking: bool) -> str:
    attrs = [
        f"id={quoteattr(edge.id)}",
        f"from={quoteattr(edge.src)}",
        f"to={quoteattr(edge.dst)}",
        f"type={quoteattr(edge.kind.name)}",
        f'priority="{edge.kind.priority}"',
        f'numLanes="{len(edge.lanes)}"',
        f'speed="{_f(edge.speed)}"',
    ]
    if edge.name:
        attrs.append(f"name={quoteattr(edge.name)}")
    if edge.shape:
        attrs.append('shape="' + " ".join(f"{_f(x)},{_f(y)}" for x, y in edge.shape) + '"')
    lanes = "".join(
        _lane_xml(i, lane, edge.kind.bicycles, close_parking) for i, lane in enumerate(edge.lanes)
    )
    return f"    <edge {' '.join(attrs)}>\n{lanes}    </edge>\n"


def read_connections(net_file: Path) -> list[LaneLink]:
    """Lane-to-lane connections between normal edges of a built network, in file order."""
    out: list[LaneLink] = []
    for _, el in ET.iterparse(net_file):
        if (
            el.tag == "connection"
            and not el.get("from", ":").startswith(":")
            and not el.get("to", ":").startswith(":")
        ):
            out.append(
                LaneLink(
                    el.get("from", ""),
                    el.get("to", ""),
                    int(el.get("fromLane", -1)),
                    int(el.get("toLane", -1)),
                )
            )
        el.clear()
    return out


def _link_xml(tag: str, link: LaneLink) -> str:
    return (
        f"    <{tag} from={quoteattr(link.src_edge)} to={quoteattr(link.dst_edge)} "
        f'fromLane="{link.src_lane}" toLane="{link.dst_lane}"/>\n'
    )


def write_plain(graph: RoadGraph, directory: Path, stem: str, close_parking: bool = False) -> PlainFiles:
    """Write the four plain-XML files of ``graph`` into ``directory`` and return their paths."""
    directory.mkdir(parents=True, exist_ok=True)
    files = PlainFiles(
        directory / f"{stem}.nod.xml",
        directory / f"{stem}.edg.xml",
        directory / f"{stem}.con.xml",
        directory / f"{stem}.typ.xml",
    )
    nodes = "".join(
        f'    <node id={quoteattr(n.id)} x="{_f(n.x)}" y="{_f(n.y)}" type="{n.control}"/>\n'
        for n in graph.nodes.values()
    )
    files.nodes.write_text(f"{XML_HEAD}<nodes>\n{nodes}</nodes>\n")
    edges = "".join(_edge_xml(e, close_parking) for e in graph.edges.values())
    files.edges.write_text(f"{XML_HEAD}<edges>\n{edges}</edges>\n")
    links = "".join(_link_xml("connection", link) for link in graph.links)
    files.connections.write_text(f"{XML_HEAD}<connections>\n{links}</connections>\n")
    kinds = {e.kind.name: e.kind for e in graph.edges.values()}
    types = "".join(
        f'    <type id="{k.name}" priority="{k.priority}" numLanes="{k.lanes}" speed="{_f(k.speed)}"/>\n'
        for k in kinds.values()
    )
    files.types.write_text(f"{XML_HEAD}<types>\n{types}</types>\n")
    return files
