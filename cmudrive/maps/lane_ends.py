"""Repair of vehicle lanes whose last points netconvert's OpenDRIVE import places past the next road.

Where one OpenDRIVE road runs on into the next without a junction (netconvert's ``A.B`` nodes),
netconvert (1.28) sometimes ends a lane's shape beyond the join: the last segment runs on, and the
join's internal lane leads straight back to the start of the next road. On CARLA's Town03 the driving
lane of the loop road 66 (``-66_5``) ends 17.5 m past its join with road 53, inside the next junction,
and ``:66.53_0_5`` comes 10.4 m back; the OpenDRIVE lane ends at (90.95, -66.04), 0.2 m from the
repaired connection below. A route through the join goes forward, back and forward again; the expert's
CAVs on such routes left them (7 CAVs of ``cmudrive220``). The same defect, 0.5-7 m long, exists at two
joins of Town06 (one on lanes that collapse anyway, see ``loader.COLLAPSED_FRACTION``) and two of
Town07. SUMO's own remedy, a custom lane shape in an edge patch, does not help: netconvert recomputes the
lane end when it re-reads the network. So the importer repairs the network it wrote
(:func:`repair_lane_ends`), the same for SUMO's traffic and for our layer.

The rule, for every connection from a normal vehicle lane L through an internal lane I whose first segment
turns more than ``REVERSAL`` from L's last one (not a turnaround): drop L's last points while the end of I
(the start of the next lane) lies behind L's end, keeping at least two points; I becomes the straight
segment from L's new end to the end of I. Only the ``shape`` and ``length`` attributes of L and I change
(L's SUMO length keeps its ratio to its shape's length: the piece cut off was never road; I's is its
shape's); nothing else in the file moves, and a network without such a lane comes back unchanged. A lane
whose two points both lie past the next road (Town01's 0.9 m lane ``11_2``) cannot lose a point and is
left as it is (a route through it goes back 1 m).
"""

from __future__ import annotations

import itertools
import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass

from cmudrive.maps.errors import MapError
from cmudrive.maps.opendrive import permits

REVERSAL = math.radians(100.0)  # turn between a lane's last segment and its internal lane's first


@dataclass(frozen=True)
class LaneEndRepair:
    """One repaired connection: ``lane`` lost ``dropped`` end points, ``internal`` became one segment."""

    lane: str
    internal: str
    dropped: int
    new_end: tuple[float, float]  # [m] the lane's new last point


Point = tuple[float, ...]  # (x, y) or (x, y, z) as the file writes it


def _shape(text: str) -> list[Point]:
    return [tuple(float(v) for v in pair.split(",")) for pair in text.split()]


def _heading(a: Point, b: Point) -> float:
    return math.atan2(b[1] - a[1], b[0] - a[0])


def _turn(h0: float, h1: float) -> float:
    return abs((h1 - h0 + math.pi) % (2.0 * math.pi) - math.pi)


def _allows_cars(lane: ET.Element) -> bool:
    allow = frozenset(lane.attrib["allow"].split()) if "allow" in lane.attrib else None
    return permits(allow, frozenset(lane.get("disallow", "").split()), "passenger")


def _length(points: list[Point]) -> float:
    return sum(math.dist(a[:2], b[:2]) for a, b in itertools.pairwise(points))


def _format(points: list[Point]) -> str:
    return " ".join(",".join(f"{v:.2f}" for v in p) for p in points)


def _find_repairs(
    root: ET.Element,
) -> tuple[list[LaneEndRepair], dict[str, list[Point]]]:
    """The repairs :func:`repair_lane_ends` makes to the network ``root``, and every changed lane's new
    shape by lane id. Turnarounds (``dir`` t/T) turn back by design and are never touched."""
    lanes: dict[str, ET.Element] = {}
    internal: set[str] = set()
    for edge in root.iterfind("edge"):
        for lane in edge.iterfind("lane"):
            lanes[lane.attrib["id"]] = lane
            if edge.get("function") == "internal":
                internal.add(lane.attrib["id"])
    shapes = {lane_id: _shape(lane.get("shape", "")) for lane_id, lane in lanes.items()}
    repairs: list[LaneEndRepair] = []
    changed: dict[str, list[Point]] = {}
    for conn in root.iterfind("connection"):
        via = conn.get("via")
        lane_id = f"{conn.get('from')}_{conn.get('fromLane')}"
        if not via or via not in internal or lane_id in internal or lane_id not in lanes:
            continue
        if conn.get("dir") in ("t", "T"):
            continue
        if not _allows_cars(lanes[lane_id]):
            continue
        own = changed.get(lane_id, shapes[lane_id])
        link = shapes[via]
        if len(own) < 2 or len(link) < 2:
            continue
        if _turn(_heading(own[-2], own[-1]), _heading(link[0], link[1])) <= REVERSAL:
            continue
        goal = link[-1]
        kept = list(own)
        while len(kept) > 2:
            (ax, ay), (bx, by) = kept[-2][:2], kept[-1][:2]
            if (goal[0] - bx) * (bx - ax) + (goal[1] - by) * (by - ay) >= 0.0:
                break  # the next road starts ahead of the lane's end
            kept.pop()
        dropped = len(own) - len(kept)
        if dropped == 0:
            continue
        changed[lane_id] = kept
        changed[via] = [kept[-1], goal]
        repairs.append(LaneEndRepair(lane_id, via, dropped, (kept[-1][0], kept[-1][1])))
    return repairs, changed


def repair_lane_ends(text: str) -> tuple[str, list[LaneEndRepair]]:
    """The SUMO network ``text`` with the lane ends of this module's rule repaired, and the repairs."""
    root = ET.fromstring(text)
    repairs, changed = _find_repairs(root)
    old = {
        lane_id: _shape(lane.get("shape", ""))
        for lane in root.iter("lane")
        if (lane_id := lane.attrib["id"]) in changed
    }
    for lane_id, points in changed.items():
        pattern = re.compile(r'(<lane id="' + re.escape(lane_id) + r'"[^>]*? length="([^"]*)"[^>]*?)>', re.S)
        match = pattern.search(text)
        if match is None:  # the parser found it, so the text has it unless written unusually
            raise MapError(f"lane {lane_id!r} to repair not found as <lane id=... length=...> in the network")
        element = match.group(1)
        shape_length = _length(points)
        if lane_id.startswith(":"):
            length = shape_length
        else:  # SUMO's length keeps its ratio to the shape's: the cut-off piece was never road
            length = float(match.group(2)) * shape_length / max(_length(old[lane_id]), 1e-6)
        element = re.sub(r' shape="[^"]*"', f' shape="{_format(points)}"', element, count=1)
        element = re.sub(r' length="[^"]*"', f' length="{max(length, 0.1):.2f}"', element, count=1)
        text = text[: match.start(1)] + element + text[match.end(1) :]
    return text, repairs
