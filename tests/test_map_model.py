"""The map model read from the mini network: lanes, kinds, graph, neighbours, junctions, lights, stops."""

from __future__ import annotations

import numpy as np
import pytest

from cmudrive.maps import JunctionKind, LaneKind, RoadMap, StopKind, TurnDir

LANE_WIDTH = 3.2  # [m] netconvert's default


def test_lanes_have_geometry_kind_width_and_speed(mini: RoadMap) -> None:
    right, left, walk = mini.lane("WC_1"), mini.lane("WC_2"), mini.lane("WC_0")
    assert mini.lane_kind[right] == mini.lane_kind[left] == LaneKind.DRIVING
    assert mini.lane_kind[walk] == LaneKind.SIDEWALK
    # two-way road: the node line is the centre line, lanes lie to its right, 3.2 m apart
    assert mini.polyline(left)[0] == pytest.approx([0.0, -1.6])
    assert mini.polyline(right)[0] == pytest.approx([0.0, -4.8])
    assert mini.lane_width[left] == pytest.approx(LANE_WIDTH)
    assert mini.lane_width[walk] == pytest.approx(2.0)
    assert mini.lane_speed[left] == pytest.approx(13.89)
    # the road stops at the junction's edge: 200 m node distance minus the junction radius
    assert 185.0 < mini.lane_length[left] < 200.0
    assert mini.polyline_s(left)[-1] == pytest.approx(mini.lane_length[left])
    assert not mini.lane_internal[left]


def test_internal_crossing_and_walking_area_lanes(mini: RoadMap) -> None:
    internal = mini.lane_internal & (mini.lane_kind == LaneKind.DRIVING)
    assert internal.sum() > 10
    assert np.all(mini.lane_junction[internal] >= 0)
    crossings = np.flatnonzero(mini.lane_kind == LaneKind.CROSSING)
    assert len(crossings) >= 4  # at C and N, where sidewalks meet
    assert np.any(mini.lane_kind == LaneKind.WALKINGAREA)
    assert set(mini.junction_ids[mini.lane_junction[crossings]]) <= {"C", "N"}


def test_neighbours_left_right_and_opposite(mini: RoadMap) -> None:
    right, left = mini.lane("WC_1"), mini.lane("WC_2")
    assert mini.lane_left[right] == left and mini.lane_right[left] == right
    assert mini.lane_left[left] == -1  # no same-direction lane beyond the leftmost
    assert mini.lane_opposite[left] == mini.lane("CW_2")  # opposite direction, directly on the left
    assert mini.lane_opposite[right] == -1
    assert mini.lane_opposite[mini.lane("CE_1")] == mini.lane("EC_1")
    assert mini.lane_opposite[mini.lane("I_0")] == -1  # one-way road


def test_successors_go_through_junction_lanes(mini: RoadMap) -> None:
    """The left turn W->N leaves from the left lane through internal lanes of C and arrives on CN."""
    left = mini.lane("WC_2")
    links = mini.successor_links(left)
    assert [TurnDir(int(mini.link_dir[k])) for k in links] == [TurnDir.LEFT]
    path, lane = [], left
    while True:
        nxt = mini.successors(lane)
        assert len(nxt) >= 1
        lane = int(nxt[0])
        path.append(str(mini.lane_ids[lane]))
        if not mini.lane_internal[lane]:
            break
    assert path[0].startswith(":C_") and path[-1] == "CN_1"
    assert left in mini.predecessors(mini.lane(path[0]))


def test_junction_kinds_and_outlines(mini: RoadMap) -> None:
    kinds = dict(zip(mini.junction_ids.tolist(), mini.junction_kind.tolist(), strict=True))
    assert kinds["C"] == JunctionKind.TRAFFIC_LIGHT
    assert kinds["N"] == JunctionKind.PRIORITY_STOP
    shape = mini.junction_shape(mini.junction("C"))
    assert len(shape) >= 4
    # the outline encloses the junction centre and is about as wide as the roads that meet there
    assert shape[:, 0].min() < 200.0 < shape[:, 0].max()
    assert 10.0 < np.ptp(shape[:, 0]) < 25.0


def test_right_of_way_minor_road_yields_at_priority_stop(mini: RoadMap) -> None:
    minor = mini.successor_links(mini.lane("CN_1"))
    major_from = {mini.lane("NWN_1"), mini.lane("NEN_1")}
    for k in minor:
        assert mini.link_state[k] == "s"  # stop, then yield
        assert {int(mini.link_from[y]) for y in mini.yields_to(k)} <= major_from
        assert len(mini.yields_to(k)) >= 1
    for k in mini.successor_links(mini.lane("NWN_1")):  # the priority road yields to nobody on the minor road
        assert mini.lane("CN_1") not in {int(mini.link_from[y]) for y in mini.yields_to(k)}


def test_traffic_light_program_and_stop_lines(mini: RoadMap) -> None:
    tls = mini.tls("C")
    durations, states = mini.tls_phases(tls)
    assert len(durations) >= 4 and 60.0 <= durations.sum() <= 120.0
    n_signals = len(states[0])
    controlled = mini.link_tls == tls
    assert mini.link_tls_index[controlled].max() == n_signals - 1
    # each approach lane of C has a traffic-light stop line at its end, as wide as the lane
    for lane_id in ("WC_1", "WC_2", "EC_1", "NC_1", "SC_0"):
        k = np.flatnonzero(mini.stop_lane == mini.lane(lane_id))
        assert len(k) == 1 and mini.stop_kind[k[0]] == StopKind.TRAFFIC_LIGHT
        line = mini.stop_xy[k[0]]
        assert np.linalg.norm(line[1] - line[0]) == pytest.approx(LANE_WIDTH)
        end = mini.polyline(mini.lane(lane_id))[-1]
        assert np.allclose(line.mean(axis=0), end)
    k = np.flatnonzero(mini.stop_lane == mini.lane("CN_1"))
    assert mini.stop_kind[k[0]] == StopKind.STOP_SIGN and mini.stop_tls[k[0]] == -1
    assert not np.any(mini.stop_lane == mini.lane("NWN_1"))  # the priority road does not stop


def test_summary_counts(mini: RoadMap) -> None:
    s = mini.summary()
    assert s["traffic_lights"] == 1 and s["junctions_priority_stop"] == 1
    assert 2.0 < s["driving_km"] < 3.0


def test_committed_town_lane_kinds_and_opposites() -> None:
    """On downtown: parking lanes (lane type "parking") are PARKING, bike lanes BIKE, and the opposite
    lanes of two-way streets are paired by geometry (the town has no netconvert <neigh> elements)."""
    from cmudrive.maps import load_map

    m = load_map("downtown")
    normal = ~m.lane_internal
    assert np.count_nonzero(normal & (m.lane_kind == LaneKind.PARKING)) >= 10
    assert np.count_nonzero(normal & (m.lane_kind == LaneKind.BIKE)) >= 10
    paired = np.flatnonzero(m.lane_opposite >= 0)
    assert len(paired) >= 40
    assert np.array_equal(m.lane_opposite[m.lane_opposite[paired]], paired)  # the pairing is symmetric
    # a pair runs the other way, one lane width apart
    s = 0.5 * m.lane_length[paired]
    heading = m.index.heading_at(paired, s)
    mid = m.index.frenet_to_xy(paired, s)
    proj_s, proj_d = m.index.project(mid, m.lane_opposite[paired])
    other = m.index.heading_at(m.lane_opposite[paired], proj_s)
    assert np.all(np.cos(heading - other) < -0.85)
    assert np.allclose(proj_d, 0.5 * (m.lane_width[paired] + m.lane_width[m.lane_opposite[paired]]), atol=1.0)
