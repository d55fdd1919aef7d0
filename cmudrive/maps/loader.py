"""Read a SUMO network (``.net.xml``) with sumolib and flatten it into a :class:`RoadMap`.

This runs once per network file; ``cache.load_map`` stores the result keyed by the file's content hash.
Bad input (missing file, not a network, no driving lanes) raises :class:`MapError` naming the file.
"""

from __future__ import annotations

import hashlib
import itertools
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from cmudrive.maps.errors import MapError
from cmudrive.maps.model import (
    NO_INDEX,
    SUMO_JUNCTION_KINDS,
    SUMO_TURN_DIRS,
    JunctionKind,
    LaneKind,
    RoadMap,
    StopKind,
    TurnDir,
)

CAR_CLASS = "passenger"
# Lateral tolerance when pairing a lane with the opposite-direction lane on its left [m].
OPPOSITE_GAP_TOLERANCE = 1.0


def file_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def _check_is_network(path: Path) -> None:
    if not path.is_file():
        raise MapError(f"map file not found: {path}")
    with open(path, "rb") as fh:
        head = fh.read(4096)
    if head[:2] == b"\x1f\x8b":  # gzip: sumolib reads it, trust the content check below
        return
    if b"<net" not in head:
        raise MapError(f"{path} is not a SUMO network (no <net> element near the start of the file)")


def _lane_types(path: Path) -> dict[str, str]:
    """Lane ``type`` attributes (sumolib does not keep them), e.g. ``"parking"``."""
    import gzip
    import xml.etree.ElementTree as ET

    types: dict[str, str] = {}
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rb") as fh:
        for _, elem in ET.iterparse(fh, events=("end",)):
            if elem.tag == "lane" and "type" in elem.attrib:
                types[elem.attrib["id"]] = elem.attrib["type"]
            elif elem.tag == "edge":
                elem.clear()
    return types


# A normal lane whose shape is shorter than this share of its SUMO length has collapsed: netconvert offsets
# a tight curve's inner lanes from the road's centreline until they fold (the inner lanes of CARLA Town06's
# 7-lane teardrop loops are 3-6 m of shape for 50-58 m of road), and a plan along them jumps across the
# median. Such a lane is kept as a non-driving lane, so routes take the loop's intact lanes.
COLLAPSED_FRACTION = 0.5


def _lane_kind(lane: Any, edge_function: str, lane_type: str) -> LaneKind:
    if edge_function == "crossing":
        return LaneKind.CROSSING
    if edge_function == "walkingarea":
        return LaneKind.WALKINGAREA
    if "parking" in lane_type.lower():
        return LaneKind.PARKING
    allowed = lane.getPermissions()
    if CAR_CLASS in allowed:
        return LaneKind.DRIVING
    if allowed == {"pedestrian"}:
        return LaneKind.SIDEWALK
    if "bicycle" in allowed and allowed <= {"bicycle", "pedestrian"}:
        return LaneKind.BIKE
    return LaneKind.SHOULDER


def _polyline(shape: list[tuple[float, ...]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points (P, 2), arc length (P,) in the ground plane and elevation (P,) of a SUMO shape; points
    without a z (the whole shape, in a flat network) are at 0 m."""
    xyz = np.asarray([(p[0], p[1], p[2] if len(p) > 2 else 0.0) for p in shape], np.float64).reshape(-1, 3)
    if len(xyz) > 1:  # drop repeated points so every segment has a direction
        keep = np.concatenate([[True], np.linalg.norm(np.diff(xyz[:, :2], axis=0), axis=1) > 1e-6])
        xyz = xyz[keep]
    if len(xyz) == 1:
        xyz = np.vstack([xyz, xyz + np.array([1e-3, 0.0, 0.0])])  # a 1 mm stub keeps one-point shapes usable
    xy = xyz[:, :2].copy()
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
    return xy, s, xyz[:, 2].copy()


def _geometric_opposites(m: RoadMap) -> np.ndarray:
    """Complete ``lane_opposite`` for two-way roads without netconvert ``<neigh>`` elements.

    The leftmost driving lane of every normal edge is paired with the nearest driving lane running the
    other way (heading within 30 degrees of opposite) whose centreline lies on its left at about half the
    sum of both widths (+ ``OPPOSITE_GAP_TOLERANCE``) from the lane's midpoint. Pairing by geometry rather
    than by edge pairs also works where the two directions are split at different places (turn pockets).
    """
    opposite = m.lane_opposite.copy()
    driving = m.driving & ~m.lane_internal
    left = m.lane_left
    leftmost = driving & ((left < 0) | (m.lane_kind[np.maximum(left, 0)] != LaneKind.DRIVING))
    lanes = np.flatnonzero(leftmost & (opposite < 0) & (m.lane_length > 1.0))
    if len(lanes) == 0:
        return opposite
    s = 0.5 * m.lane_length[lanes]
    mid = m.index.frenet_to_xy(lanes, s)
    heading = m.index.heading_at(lanes, s)
    proj = m.index.nearest_lane(mid, heading=heading + np.pi, max_heading_diff=np.radians(30.0))
    cand = proj.lane
    ok = cand >= 0
    ok[ok] &= leftmost[cand[ok]] & (proj.d[ok] > 0.0)  # we lie on the candidate's left, it on ours
    expected = 0.5 * (m.lane_width[lanes] + m.lane_width[np.maximum(cand, 0)])
    ok &= np.abs(proj.d - expected) < OPPOSITE_GAP_TOLERANCE
    opposite[lanes[ok]] = cand[ok]
    # where the two directions are split at different places, a lane's midpoint may lie beside a turn
    # pocket while the other lane's midpoint lies beside it: complete such pairs both ways
    back = cand[ok][opposite[cand[ok]] < 0]
    opposite[back] = lanes[ok][opposite[cand[ok]] < 0]
    return opposite


def _csr(rows: list[list[int]], dtype: type = np.int32) -> tuple[np.ndarray, np.ndarray]:
    ptr = np.zeros(len(rows) + 1, dtype=np.int64)
    ptr[1:] = np.cumsum([len(r) for r in rows])
    flat: np.ndarray = np.fromiter((v for r in rows for v in r), dtype=dtype, count=int(ptr[-1]))
    return ptr, flat


def read_sumo_net(path: str | Path, name: str | None = None) -> RoadMap:
    """Parse ``path`` with sumolib and build a :class:`RoadMap` (no caching; see ``load_map``)."""
    import sumolib

    path = Path(path)
    _check_is_network(path)
    try:
        net = sumolib.net.readNet(
            str(path), withInternal=True, withPedestrianConnections=True, withLatestPrograms=True
        )
    except Exception as exc:  # sumolib raises bare parser errors; name the file
        raise MapError(f"{path} could not be read as a SUMO network: {exc}") from exc
    name = name or path.name.removesuffix(".gz").removesuffix(".xml").removesuffix(".net")
    builder = _Builder(net, name, _lane_types(path))
    road_map = builder.build(file_sha256(path))
    if not np.any(road_map.driving & ~road_map.lane_internal):
        raise MapError(f"{path} has no driving lanes (no lane allows passenger cars)")
    return road_map


class _Builder:
    """Flattens a sumolib ``Net``. One pass per concept; only runs at conversion time."""

    def __init__(self, net: Any, name: str, lane_types: dict[str, str]) -> None:
        self.net = net
        self.name = name
        self.lane_types = lane_types
        self.edges = list(net.getEdges(withInternal=True))
        self.nodes = list(net.getNodes())
        self.node_idx = {n.getID(): i for i, n in enumerate(self.nodes)}
        self.edge_idx = {e.getID(): i for i, e in enumerate(self.edges)}
        self.lanes = [lane for e in self.edges for lane in e.getLanes()]
        self.lane_idx = {lane.getID(): i for i, lane in enumerate(self.lanes)}
        self.tls = list(net.getTrafficLights())
        self.tls_idx = {t.getID(): i for i, t in enumerate(self.tls)}

    def build(self, sha: str) -> RoadMap:
        arrays: dict[str, Any] = {"name": self.name, "source_sha256": sha}
        arrays.update(self._edges())
        arrays.update(self._lanes())
        arrays.update(self._links(arrays))
        arrays.update(self._neighbours(arrays))
        arrays.update(self._junctions())
        arrays.update(self._traffic_lights())
        arrays.update(self._stop_lines(arrays))
        xy = arrays["pt_xy"]
        arrays["bounds"] = np.array([*xy.min(axis=0), *xy.max(axis=0)], dtype=np.float64)
        road_map = RoadMap(**arrays)
        return replace(road_map, lane_opposite=_geometric_opposites(road_map))

    def _node_index(self, node: Any) -> int:
        return self.node_idx.get(node.getID(), NO_INDEX) if node is not None else NO_INDEX

    def _edges(self) -> dict[str, np.ndarray]:
        return {
            "edge_ids": np.array([e.getID() for e in self.edges], dtype=str),
            "edge_from_junction": np.array([self._node_index(e.getFromNode()) for e in self.edges], np.int32),
            "edge_to_junction": np.array([self._node_index(e.getToNode()) for e in self.edges], np.int32),
        }

    def _lanes(self) -> dict[str, np.ndarray]:
        n = len(self.lanes)
        kind = np.zeros(n, np.int8)
        lane_edge = np.zeros(n, np.int32)
        index = np.zeros(n, np.int8)
        internal = np.zeros(n, bool)
        junction = np.full(n, NO_INDEX, np.int32)
        width = np.zeros(n)
        speed = np.zeros(n)
        polylines, arclens, elevations = [], [], []
        for i, lane in enumerate(self.lanes):
            edge = lane.getEdge()
            function = edge.getFunction()
            kind[i] = _lane_kind(lane, function, self.lane_types.get(lane.getID(), ""))
            lane_edge[i] = self.edge_idx[edge.getID()]
            index[i] = lane.getIndex()
            internal[i] = function in ("internal", "crossing", "walkingarea")
            if internal[i]:
                node_id = edge.getID()[1:].rsplit("_", 1)[0]
                junction[i] = self.node_idx.get(node_id, NO_INDEX)
            width[i] = lane.getWidth()
            speed[i] = lane.getSpeed()
            xy, s, z = _polyline(lane.getShape3D())
            if not internal[i] and s[-1] < COLLAPSED_FRACTION * lane.getLength():
                kind[i] = LaneKind.SHOULDER  # collapsed: see COLLAPSED_FRACTION
            polylines.append(xy)
            arclens.append(s)
            elevations.append(z)
        ptr = np.zeros(n + 1, np.int64)
        ptr[1:] = np.cumsum([len(p) for p in polylines])
        return {
            "lane_ids": np.array([lane.getID() for lane in self.lanes], dtype=str),
            "lane_kind": kind,
            "lane_edge": lane_edge,
            "lane_index": index,
            "lane_internal": internal,
            "lane_junction": junction,
            "lane_width": width,
            "lane_speed": speed,
            "lane_length": np.array([s[-1] for s in arclens]),
            "lane_pt_ptr": ptr,
            "pt_xy": np.concatenate(polylines),
            "pt_s": np.concatenate(arclens),
            "pt_z": np.concatenate(elevations),
        }

    def _links(self, arrays: dict[str, Any]) -> dict[str, np.ndarray]:
        conns = []
        for lane in self.lanes:
            conns.extend(lane.getOutgoing())
        frm, to, via, dirs, states, junc, jidx, tls, tls_index = [], [], [], [], [], [], [], [], []
        for c in conns:
            frm.append(self.lane_idx[c.getFromLane().getID()])
            to.append(self.lane_idx[c.getToLane().getID()])
            via.append(self.lane_idx.get(c.getViaLaneID() or "", NO_INDEX))
            dirs.append(SUMO_TURN_DIRS.get(c.getDirection(), TurnDir.INVALID))
            states.append(c.getState() or "M")
            node = c.getJunction()
            junc.append(self._node_index(node))
            internal_from = c.getFrom().getFunction() != ""
            jidx.append(NO_INDEX if internal_from else int(c.getJunctionIndex()))
            tls.append(self.tls_idx.get(c.getTLSID() or "", NO_INDEX))
            tls_index.append(int(c.getTLLinkIndex()) if c.getTLSID() else NO_INDEX)
        link_from = np.array(frm, np.int32)
        link_to = np.array(to, np.int32)
        link_via = np.array(via, np.int32)
        link_junction = np.array(junc, np.int32)
        link_jidx = np.array(jidx, np.int32)
        # lane graph: from -> via (or to, when the link has no internal lane)
        step_target = np.where(link_via >= 0, link_via, link_to)
        n = len(self.lanes)
        succ_rows: list[list[int]] = [[] for _ in range(n)]
        link_rows: list[list[int]] = [[] for _ in range(n)]
        pred_rows: list[list[int]] = [[] for _ in range(n)]
        for k in range(len(link_from)):
            a, b = int(link_from[k]), int(step_target[k])
            if b in succ_rows[a]:
                continue
            succ_rows[a].append(b)
            link_rows[a].append(k)
            pred_rows[b].append(a)
        succ_ptr, succ_lane = _csr(succ_rows)
        _, succ_link = _csr(link_rows)
        pred_ptr, pred_lane = _csr(pred_rows)
        yield_ptr, yield_link, foe_ptr, foe_link = self._right_of_way(link_junction, link_jidx)
        return {
            "succ_ptr": succ_ptr,
            "succ_lane": succ_lane,
            "succ_link": succ_link,
            "pred_ptr": pred_ptr,
            "pred_lane": pred_lane,
            "link_from": link_from,
            "link_to": link_to,
            "link_via": link_via,
            "link_dir": np.array(dirs, np.int8),
            "link_state": np.array(states, dtype="<U1"),
            "link_junction": link_junction,
            "link_junction_index": link_jidx,
            "link_tls": np.array(tls, np.int32),
            "link_tls_index": np.array(tls_index, np.int32),
            "yield_ptr": yield_ptr,
            "yield_link": yield_link,
            "foe_ptr": foe_ptr,
            "foe_link": foe_link,
        }

    def _right_of_way(
        self, link_junction: np.ndarray, link_jidx: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Decode SUMO's ``<request index response foes>`` bit strings (rightmost char = link 0)."""
        by_request: dict[tuple[int, int], int] = {}
        for k, (j, r) in enumerate(zip(link_junction.tolist(), link_jidx.tolist(), strict=True)):
            if j >= 0 and r >= 0:
                by_request.setdefault((j, r), k)
        yields: list[list[int]] = []
        foes: list[list[int]] = []
        for j, r in zip(link_junction.tolist(), link_jidx.tolist(), strict=True):
            if j < 0 or r < 0:
                yields.append([])
                foes.append([])
                continue
            node = self.nodes[j]
            response = node._prohibits.get(r, "")
            foe_bits = node._foes.get(r, "")
            yields.append(self._bits_to_links(response, j, by_request))
            foes.append(self._bits_to_links(foe_bits, j, by_request))
        yield_ptr, yield_link = _csr(yields)
        foe_ptr, foe_link = _csr(foes)
        return yield_ptr, yield_link, foe_ptr, foe_link

    @staticmethod
    def _bits_to_links(bits: str, junction: int, by_request: dict[tuple[int, int], int]) -> list[int]:
        out = []
        for pos, ch in enumerate(reversed(bits)):
            if ch == "1" and (junction, pos) in by_request:
                out.append(by_request[(junction, pos)])
        return out

    def _neighbours(self, arrays: dict[str, Any]) -> dict[str, np.ndarray]:
        n = len(self.lanes)
        left = np.full(n, NO_INDEX, np.int32)
        right = np.full(n, NO_INDEX, np.int32)
        opposite = np.full(n, NO_INDEX, np.int32)
        kind = arrays["lane_kind"]
        for edge in self.edges:
            if edge.getFunction() in ("crossing", "walkingarea"):
                continue
            ids = [self.lane_idx[lane.getID()] for lane in edge.getLanes()]
            for a, b in itertools.pairwise(ids):  # b is left of a
                if kind[a] == kind[b]:
                    left[a], right[b] = b, a
        for edge in self.edges:
            if edge.getFunction() != "":
                continue
            for lane in edge.getLanes():  # explicit <neigh> elements written by netconvert (opposites.guess)
                neigh = lane.getNeigh()  # sumolib gives the neighbour lane's id
                neigh_id = neigh if isinstance(neigh, str) or neigh is None else neigh.getID()
                if neigh_id in self.lane_idx and kind[self.lane_idx[neigh_id]] == LaneKind.DRIVING:
                    opposite[self.lane_idx[lane.getID()]] = self.lane_idx[neigh_id]
        return {"lane_left": left, "lane_right": right, "lane_opposite": opposite}

    def _junctions(self) -> dict[str, np.ndarray]:
        shapes = []
        for node in self.nodes:
            shape = node.getShape() or [node.getCoord()]
            shapes.append(np.asarray([(p[0], p[1]) for p in shape], np.float64).reshape(-1, 2))
        ptr = np.zeros(len(shapes) + 1, np.int64)
        ptr[1:] = np.cumsum([len(s) for s in shapes])
        kinds = np.array(
            [SUMO_JUNCTION_KINDS.get(n.getType(), JunctionKind.OTHER) for n in self.nodes], np.int8
        )
        tls_of_node: dict[int, int] = {}
        for t_i, t in enumerate(self.tls):
            for conn in t.getConnections():
                in_lane = conn[0]
                node = in_lane.getEdge().getToNode()
                tls_of_node.setdefault(self.node_idx[node.getID()], t_i)
        return {
            "junction_ids": np.array([n.getID() for n in self.nodes], dtype=str),
            "junction_kind": kinds,
            "junction_xy": np.array([n.getCoord()[:2] for n in self.nodes], np.float64).reshape(-1, 2),
            "junction_shape_ptr": ptr,
            "junction_shape_xy": np.concatenate(shapes) if shapes else np.zeros((0, 2)),
            "junction_tls": np.array(
                [tls_of_node.get(i, NO_INDEX) for i in range(len(self.nodes))], np.int32
            ),
        }

    def _traffic_lights(self) -> dict[str, np.ndarray]:
        programs: list[str] = []
        durations: list[float] = []
        states: list[str] = []
        offsets: list[float] = []
        rows: list[int] = []
        for t in self.tls:
            progs = t.getPrograms()
            prog_id = next(iter(progs)) if progs else ""
            program = progs.get(prog_id)
            phases = program.getPhases() if program is not None else []
            programs.append(prog_id)
            offsets.append(float(getattr(program, "_offset", 0.0) or 0.0))
            rows.append(len(phases))
            durations.extend(float(p.duration) for p in phases)
            states.extend(p.state for p in phases)
        ptr = np.zeros(len(self.tls) + 1, np.int64)
        ptr[1:] = np.cumsum(rows)
        return {
            "tls_ids": np.array([t.getID() for t in self.tls], dtype=str),
            "tls_program": np.array(programs, dtype=str),
            "tls_offset": np.array(offsets, np.float64),
            "tls_phase_ptr": ptr,
            "phase_duration": np.array(durations, np.float64),
            "phase_state": np.array(states, dtype=str),
        }

    def _stop_lines(self, arrays: dict[str, Any]) -> dict[str, np.ndarray]:
        """One stop line per (incoming normal lane, junction) with a light, stop or all-way-stop link."""
        link_from, link_tls, link_state = arrays["link_from"], arrays["link_tls"], arrays["link_state"]
        link_junction, internal = arrays["link_junction"], arrays["lane_internal"]
        found: dict[tuple[int, int], tuple[StopKind, int]] = {}
        for k in range(len(link_from)):
            lane = int(link_from[k])
            if internal[lane]:
                continue
            key = (lane, int(link_junction[k]))
            if link_tls[k] >= 0:
                found[key] = (StopKind.TRAFFIC_LIGHT, int(link_tls[k]))
            elif link_state[k] == "s":
                found.setdefault(key, (StopKind.STOP_SIGN, NO_INDEX))
            elif link_state[k] == "w":
                found.setdefault(key, (StopKind.ALLWAY_STOP, NO_INDEX))
        ptr, xy, width = arrays["lane_pt_ptr"], arrays["pt_xy"], arrays["lane_width"]
        lanes, kinds, juncs, tls, lines = [], [], [], [], []
        for (lane, junction), (kind, t) in sorted(found.items()):
            end, before = xy[ptr[lane + 1] - 1], xy[ptr[lane + 1] - 2]
            direction = (end - before) / max(np.linalg.norm(end - before), 1e-9)
            normal_left = np.array([-direction[1], direction[0]])
            half = 0.5 * width[lane]
            lines.append([end - half * normal_left, end + half * normal_left])
            lanes.append(lane)
            kinds.append(kind)
            juncs.append(junction)
            tls.append(t)
        return {
            "stop_lane": np.array(lanes, np.int32),
            "stop_kind": np.array(kinds, np.int8),
            "stop_junction": np.array(juncs, np.int32),
            "stop_tls": np.array(tls, np.int32),
            "stop_xy": np.array(lines, np.float64).reshape(-1, 2, 2),
        }
