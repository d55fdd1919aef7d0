"""Lanes that netconvert ends past the next road (cmudrive.maps.lane_ends), on a tiny network text and on
the committed Town03, where the loop road 66 ran 17.5 m into the next junction and came back."""

from __future__ import annotations

import math

import numpy as np

from cmudrive.bench.route_sets import resolve_routes
from cmudrive.bench.routes import read_routes
from cmudrive.maps import load_map
from cmudrive.maps.lane_ends import repair_lane_ends

# a road heading east (x 0 -> 20) whose driving lane's last point netconvert put 12 m past the join at x 20;
# the join's internal lane leads back to the next road, which starts at x 21; at its end a turnaround
# (dir t) that turns back by design
NET = """<net>
    <edge id=":J_0" function="internal">
        <lane id=":J_0_0" index="0" speed="10.00" length="11.00" shape="32.00,0.00 21.00,0.00"/>
    </edge>
    <edge id=":J_1" function="internal">
        <lane id=":J_1_0" index="0" disallow="all" speed="1.39" length="11.00" shape="32.00,5.00 21.00,5.00"/>
    </edge>
    <edge id="a" from="A" to="J">
        <lane id="a_0" index="0" speed="10.00" length="20.00"
              shape="0.00,0.00 10.00,0.00 19.00,0.00 32.00,0.00"/>
    </edge>
    <edge id="s" from="A" to="J">
        <lane id="s_0" index="0" disallow="all" speed="1.39" length="20.00" shape="0.00,5.00 32.00,5.00"/>
    </edge>
    <edge id="b" from="J" to="B">
        <lane id="b_0" index="0" speed="10.00" length="30.00" shape="21.00,0.00 40.00,0.00 51.00,0.00"/>
    </edge>
    <edge id=":K_0" function="internal">
        <lane id=":K_0_0" index="0" speed="5.00" length="6.00" shape="51.00,0.00 49.00,3.00"/>
    </edge>
    <edge id="c" from="B" to="A">
        <lane id="c_0" index="0" speed="10.00" length="30.00" shape="49.00,3.00 21.00,3.00"/>
    </edge>
    <connection from="a" to="b" fromLane="0" toLane="0" via=":J_0_0" dir="s" state="M"/>
    <connection from="s" to="b" fromLane="0" toLane="0" via=":J_1_0" dir="s" state="M"/>
    <connection from="b" to="c" fromLane="0" toLane="0" via=":K_0_0" dir="t" state="M"/>
</net>
"""


def _attr(text: str, lane: str, name: str) -> str:
    start = text.index(f'<lane id="{lane}"')
    element = text[start : text.index(">", start)]
    return element.split(f' {name}="', 1)[1].split('"', 1)[0]


def test_the_overshooting_end_is_cut_back_and_the_join_goes_forward() -> None:
    text, repairs = repair_lane_ends(NET)
    assert [(r.lane, r.internal, r.dropped) for r in repairs] == [("a_0", ":J_0_0", 1)]
    assert _attr(text, "a_0", "shape") == "0.00,0.00 10.00,0.00 19.00,0.00"
    assert _attr(text, ":J_0_0", "shape") == "19.00,0.00 21.00,0.00"  # 2 m forward, not 11 m back
    assert _attr(text, ":J_0_0", "length") == "2.00"
    # SUMO's length keeps its ratio to the shape's (20 m for 32 m of shape before, 19 m of shape now)
    assert float(_attr(text, "a_0", "length")) == round(20.0 * 19.0 / 32.0, 2)
    # a lane no car may use (a shoulder) and a turnaround are left as they are, and so is every other line
    assert _attr(text, "s_0", "shape") == "0.00,5.00 32.00,5.00"
    assert _attr(text, "b_0", "shape") == "21.00,0.00 40.00,0.00 51.00,0.00"
    changed = [n for n, (a, b) in enumerate(zip(NET.splitlines(), text.splitlines(), strict=True)) if a != b]
    assert changed == [2, 8, 9]  # the internal lane's line, the lane's length and shape lines


def test_a_network_without_such_lanes_comes_back_unchanged() -> None:
    repaired, _ = repair_lane_ends(NET)
    again, repairs = repair_lane_ends(repaired)
    assert repairs == [] and again == repaired


def test_town03_loop_hands_over_to_road_53_where_the_opendrive_lane_ends() -> None:
    m = load_map("Town03")
    ids = list(m.lane_ids)
    lane, link = ids.index("-66_5"), ids.index(":66.53_0_5")
    a, b = m.polyline(link)[0], m.polyline(link)[-1]
    np.testing.assert_allclose(a, m.polyline(lane)[-1])
    # the OpenDRIVE driving lane -2 of road 66 ends 1.75 m left of the reference line's end (92.00, -67.44),
    # heading 0.642 rad: (90.95, -66.04)
    end = np.array([90.95, -66.04])
    t = np.clip(np.dot(end - a, b - a) / np.dot(b - a, b - a), 0.0, 1.0)
    assert np.linalg.norm(a + t * (b - a) - end) < 0.3
    heading = math.atan2(b[1] - a[1], b[0] - a[0])
    assert abs(heading - 0.642) < math.radians(5)  # forward, along the road (was 10.4 m backward)


def test_a_route_through_town03s_loop_never_turns_back() -> None:
    """VehicleTurningRoute_1's CAV 1 drives round the loop of road 66 and on east (its three CAVs of
    cmudrive220 that did so left their route at the join before the repair)."""
    spec = next(s for s in read_routes(resolve_routes("cmudrive220")) if s.id == "VehicleTurningRoute_1")
    route = spec.dense_routes(load_map("Town03"))[1]
    turn = np.abs(np.angle(np.exp(1j * np.diff(route.heading))))
    assert turn.max() < math.radians(45), f"turns {math.degrees(turn.max()):.0f} deg between 1 m steps"
