"""The flow family (EnterActorFlow, HighwayExit, MergerIntoSlowTraffic(V2), InterurbanActorFlow) where a
ramp joins a motorway, on our highway town and CARLA's Town06: SUMO cars run from start_actor_flow to
end_actor_flow at flow_speed [m/s], the next leaving once the last drove a gap in source_dist_interval,
pre-filled at activation where the type says so, removed at the sink; the scenario ends when CAV 0
reached the sink (or left the junction)."""

from __future__ import annotations

import dataclasses
import itertools
from pathlib import Path

import numpy as np
import pytest

from cmudrive.bench import RouteSpec
from cmudrive.bench.scenarios.flows import VehicleFlow
from cmudrive.bench.scenarios.placement import LanePoint
from cmudrive.maps import LanePos, RoadMap, Route, RoutePlanner, load_map
from cmudrive.maps.coords import map_to_carla
from cmudrive.maps.model import LaneKind
from cmudrive.sim import Controls, World, WorldConfig
from cmudrive.sim.snapshot import Snapshot
from tests.scenario_helpers import cav_track, path_cav, run, scenario, track, trigger

# town, ramp lane (CAV 0), s on it (start, trigger), main lane (flow source) and s, exit lane (sink) and s
HW = ("S_entry1-EB_merge1_0", "EB_gore1-EB_merge1_0", "EB_merge1-EB_gore2_1")
SCENES = {
    "highway": (HW[0], 250.0, 270.0, HW[1], 520.0, HW[2], 150.0),
    "Town06": ("75_2", 2.0, 10.0, "-42_3", 30.0, "-43_3", 150.0),
}  # fmt: skip
SPEED, GAP = 12.0, (20.0, 30.0)


def flow_route(town: str, kind: str) -> tuple[RouteSpec, np.ndarray]:
    m = load_map(town)
    ramp, s0, t_s, main, s_src, out, s_dst = SCENES[town]
    r, o = m.lane(ramp), m.lane(out)
    xy = np.array(
        [
            m.index.frenet_to_xy(np.array([r]), np.array([s0]))[0],
            m.index.frenet_to_xy(np.array([r]), np.array([m.lane_length[r] - 2.0]))[0],
            m.index.frenet_to_xy(np.array([o]), np.array([s_dst + 50.0]))[0],
        ]
    )
    src = m.index.frenet_to_xy(np.array([m.lane(main)]), np.array([s_src]))[0]
    dst = m.index.frenet_to_xy(np.array([o]), np.array([s_dst]))[0]

    def loc(p: np.ndarray) -> dict[str, str]:
        c = map_to_carla(p[None])[0]
        return {"x": str(c[0]), "y": str(c[1]), "z": "0"}

    gap = {"from": str(GAP[0]), "to": str(GAP[1])}
    sc = scenario(kind, trigger(m, ramp, t_s), start_actor_flow=loc(src), end_actor_flow=loc(dst),
                  flow_speed=str(SPEED), source_dist_interval=gap)  # fmt: skip
    return RouteSpec(f"{kind}_{town}", town, "ClearNoon", 0, (path_cav(m, 0, xy),), (sc,)), dst


@pytest.mark.parametrize("town", ["highway", "Town06"])
@pytest.mark.parametrize(
    "kind",
    [
        "MergerIntoSlowTraffic",
        "MergerIntoSlowTrafficV2",
        "EnterActorFlow",
        "HighwayExit",
        "InterurbanActorFlow",
    ],
)
def test_flow_cars_run_source_to_sink_at_flow_speed(kind: str, town: str, tmp_path: Path) -> None:
    spec, _ = flow_route(town, kind)
    result, log = run(spec, tmp_path)
    assert result.scenario_simulated is True
    cars = sorted(
        {a for a in log.arrays["actor_id"].tolist() if a.startswith("S1:flow0:")}, key=lambda a: int(a[9:])
    )
    assert len(cars) >= 3
    tracks = {c: track(log, c) for c in cars}
    first = {c: int(np.flatnonzero(~np.isnan(t[:, 0]))[0]) for c, t in tracks.items()}
    last = {c: int(np.flatnonzero(~np.isnan(t[:, 0]))[-1]) for c, t in tracks.items()}
    activation = min(first.values())
    prefilled = [c for c in cars if first[c] == activation]
    if kind in ("InterurbanActorFlow",):
        assert len(prefilled) == 1  # only the car at the source
    else:
        assert len(prefilled) >= 3  # cars all along the path at once
    end = max(last.values())
    speeds = np.concatenate([t[first[c] : last[c] + 1, 3] for c, t in tracks.items()])
    assert np.median(speeds) == pytest.approx(SPEED, abs=0.05)  # imposed speed ...
    assert speeds.max() <= SPEED + 0.05  # ... which SUMO's safe-speed check may only lower (behind a CAV)
    m = load_map(town)
    out = m.lane(SCENES[town][5])
    for c, t in tracks.items():
        if last[c] < end:  # left before the scenario ended: at its sink (abreast the given one)
            s, _ = m.index.project(t[last[c], :2][None], np.array([out]))
            assert SCENES[town][6] - 2.0 - SPEED * 0.05 - 0.1 < s[0] < SCENES[town][6] + 0.1, c
    spawned = [c for c in cars if first[c] > activation]  # from the source, one after another
    order = [c for c in cars if c in spawned or c == prefilled[-1]]
    for a, b in itertools.pairwise(order):
        driven = np.linalg.norm(tracks[a][first[b], :2] - tracks[a][first[a], :2])
        assert GAP[0] - 1.0 <= driven <= GAP[1] + SPEED * 0.1 + 1.0, (a, b, driven)
    if kind == "EnterActorFlow":  # a flow on every lane of the main road that continues to the sink road
        assert {a.split(":")[1] for a in log.arrays["actor_id"].tolist() if a.startswith("S1:flow")} >= {
            "flow0", "flow1"
        }  # fmt: skip
    cav = cav_track(log, 0)
    if kind.startswith("Merger") or kind == "EnterActorFlow":  # ends when CAV 0 reached the sink
        s_cav, _ = m.index.project(cav[end + 1, :2][None], np.array([out]))
        assert s_cav[0] >= SCENES[town][6] - 2.0 - 1.5
    else:  # ends when CAV 0 left the junction (the merge)
        route = spec.dense_routes(m)[0]
        inside = np.flatnonzero(route.in_junction)
        exit_k = int(inside[0]) + int(np.flatnonzero(~route.in_junction[inside[0] :])[0])
        k = int(np.argmin(np.linalg.norm(route.xy - cav[end + 1, :2], axis=1)))
        assert route.distance[exit_k] - 1.5 <= route.distance[k] <= route.distance[exit_k] + 2.0


@pytest.mark.parametrize(
    ("town", "a", "b"), [("suburb", "J1_1-J0_1_1", "J0_1-J0_0_2"), ("Town01", "-24_2", "-6_2")]
)
def test_interurban_advanced_two_flows_on_both_carriageways(
    town: str, a: str, b: str, tmp_path: Path
) -> None:
    """CAV 0 turns left across flow 1 (the near carriageway, from its left) into flow 2 (the far one,
    the oncoming lanes beside flow 1's sink and source); the scenario ends when CAV 0 reached flow 2's
    sink."""
    from cmudrive.maps.model import TurnDir

    m = load_map(town)
    ia, ib = m.lane(a), m.lane(b)
    j = int(m.lane_junction[m.successors(ia)[0]])

    def end_heading(lane: int) -> float:
        p = m.polyline(lane)
        return float(np.arctan2(*(p[-1] - p[-2])[::-1]))

    driving = (m.lane_kind[m.link_from] == 0) & ~m.lane_internal[m.link_from]
    links = np.flatnonzero((m.link_junction == j) & (m.link_dir == TurnDir.STRAIGHT) & driving)
    left = [
        k for k in links
        if abs(np.angle(np.exp(1j * (end_heading(int(m.link_from[k])) - end_heading(ia) + np.pi / 2)))) < 0.6
    ]  # fmt: skip
    src_lane, dst_lane = int(m.link_from[left[0]]), int(m.link_to[left[0]])
    src_s, dst_s = max(1.0, m.lane_length[src_lane] - 60.0), min(50.0, m.lane_length[dst_lane] - 5.0)
    xy = np.array(
        [
            m.index.frenet_to_xy(np.array([ia]), np.array([max(2.0, m.lane_length[ia] - 50.0)]))[0],
            m.index.frenet_to_xy(np.array([ia]), np.array([m.lane_length[ia] - 2.0]))[0],
            m.index.frenet_to_xy(np.array([ib]), np.array([min(90.0, m.lane_length[ib] - 5.0)]))[0],
        ]
    )

    def loc(lane: int, s: float) -> dict[str, str]:
        c = map_to_carla(m.index.frenet_to_xy(np.array([lane]), np.array([s])))[0]
        return {"x": str(c[0]), "y": str(c[1]), "z": "0"}

    sc = scenario(
        "InterurbanAdvancedActorFlow", trigger(m, a, max(3.0, m.lane_length[ia] - 40.0)),
        start_actor_flow=loc(src_lane, src_s), end_actor_flow=loc(dst_lane, dst_s), flow_speed="10",
        source_dist_interval={"from": "20", "to": "30"},
    )  # fmt: skip
    spec = RouteSpec(f"iaaf_{town}", town, "ClearNoon", 0, (path_cav(m, 0, xy),), (sc,))
    result, log = run(spec, tmp_path)
    assert result.scenario_simulated is True
    ids = {x for x in log.arrays["actor_id"].tolist() if x.startswith("S1:flow")}
    one, two = track(log, "S1:flow0:0"), track(log, "S1:flow1:0")
    r1, r2 = np.flatnonzero(~np.isnan(one[:, 0])), np.flatnonzero(~np.isnan(two[:, 0]))
    assert {x.split(":")[1] for x in ids} == {"flow0", "flow1"}
    assert abs(np.angle(np.exp(1j * (one[r1[5], 2] - two[r2[5], 2])))) > 2.5  # opposite directions
    _, d = m.index.project(two[r2[5], :2][None], np.array([int(m.lane_opposite[src_lane])]))
    assert abs(d[0]) < 0.3  # flow 2 on the lane beside flow 1's source (CAV 0's target road)
    end = max(int(np.flatnonzero(~np.isnan(track(log, x)[:, 0]))[-1]) for x in ids)
    sink2 = m.index.frenet_to_xy(np.array([src_lane]), np.array([src_s]))[0]
    assert np.linalg.norm(cav_track(log, 0)[end + 1, :2] - sink2) < 3.5 + 4.0  # CAV 0 reached flow 2's sink


def test_an_actor_flow_drives_into_a_standing_cav_then_follows_cars(mini_net: Path, mini: RoadMap) -> None:
    """On the mini network's one-lane road C-E a CAV stands at s = 120 m in the path of an ActorFlow (12 m/s,
    a car every 30 m from s = 20 m). As upstream's, the flow's cars ignore vehicles until their first
    collision: the first car is still at 12 m/s 1 m before it hits the CAV. From then on the flow follows
    cars: the second car stops behind the first without touching anything."""
    lane = mini.lane("CE_1")
    route = RoutePlanner(mini).plan_lanes(LanePos(lane, 120.0), LanePos(lane, 190.0))
    hits: list[tuple[int, str, str]] = []
    speed: dict[str, list[float]] = {"F:0": [], "F:1": []}
    with World(WorldConfig(town=mini_net, seed=1), road_map=mini) as world:
        world.add_cav(route, speed=0.0)
        rng = np.random.default_rng(0)
        flow = VehicleFlow(
            "F", world, mini, LanePoint(lane, 20.0), LanePoint(lane, 195.0), (30.0, 30.0), 12.0, rng, True
        )
        stand = Controls(np.zeros(1), np.zeros(1), np.ones(1))
        snap = world.tick(stand)
        for k in range(500):  # 25 s
            flow.update(snap)
            snap = world.tick(stand)
            ev = world.collisions
            hits += [(k, str(a), str(b)) for a, b in zip(ev.id_a, ev.id_b, strict=True)]
            for car, v in speed.items():
                r = np.flatnonzero(snap.ids == car)
                v.append(float(snap.speed[r[0]]) if len(r) else np.nan)
    first = [k for k, a, b in hits if {a, b} == {"F:0", "cav0"}]
    assert first, hits  # the first flow car hit the standing CAV ...
    v0 = np.array(speed["F:0"][first[0] - 2 : first[0]])
    assert v0 == pytest.approx(12.0, abs=0.05)  # ... without braking for it
    assert flow.collided
    assert not [h for h in hits if "F:1" in h[1:]]  # the next car never touched anything ...
    v1 = np.array(speed["F:1"])
    assert np.nanmin(v1[first[0] :]) < 0.1  # ... it stopped behind


@pytest.mark.parametrize("town", ["highway", "Town06"])
def test_a_merge_ends_at_any_lane_of_the_road_at_the_sink(town: str) -> None:
    """MergerIntoSlowTraffic's end is CAV 0 within 2 m of any same-direction lane point abreast the sink
    (upstream's), not the flow's sink alone: one end point on each driving lane of the sink's road, all
    abreast the sink (within 0.5 m along the road)."""
    from cmudrive.bench.route_check import build_placed

    m = load_map(town)
    spec, dst = flow_route(town, "MergerIntoSlowTraffic")
    (sc,) = build_placed(spec, m, spec.dense_routes(m))
    out = m.lane(SCENES[town][5])
    road = np.flatnonzero((m.lane_edge == m.lane_edge[out]) & (m.lane_kind == LaneKind.DRIVING))
    assert len(road) >= 2 and len(sc.sinks) == len(road)
    on = m.index.nearest_lane(sc.sinks, max_distance=0.1)
    assert sorted(on.lane.tolist()) == sorted(road.tolist())
    h = sc.sink_heading[0]
    along = (sc.sinks - dst) @ np.array([np.cos(h), np.sin(h)])
    assert np.abs(along).max() < 0.5


def test_a_flow_source_inside_a_junction_starts_where_its_lane_leaves_it() -> None:
    """Bench2Drive's route 26394 (Town06, MergerIntoSlowTrafficV2) puts start_actor_flow 14 m into a
    junction's internal lane as SUMO draws it (CARLA's junction areas are smaller, and CARLA can spawn
    there; SUMO cannot): the flow starts at the beginning of the road that lane leads onto and drives on
    to the sink, instead of the route being refused."""
    from cmudrive.bench import CavSpec
    from cmudrive.bench.route_check import build_placed

    m = load_map("Town06")
    xs = [554.7, 552.7, 550.7, 548.6, 546.6, 544.6, 542.6, 540.6, 538.6, 536.6, 534.6, 532.6]
    xs2 = [444.8, 440.8, 436.8, 432.8, 428.8, 424.8, 420.8, 418.8]
    pts = [(x, -24.3, 0.0) for x in xs] + [(x, -10.5, 0.0) for x in xs2]  # CARLA frame, CAV 0's waypoints
    sc = scenario(
        "MergerIntoSlowTrafficV2",
        (550.7, -24.3, 0.0, -179.6),
        start_actor_flow={"x": "495.7", "y": "36.5", "z": "0"},
        end_actor_flow={"x": "424.8", "y": "-10.5", "z": "0"},
        flow_speed="10",
        source_dist_interval={"from": "14", "to": "30"},
    )
    spec = RouteSpec("26394", "Town06", "ClearNoon", 0, (CavSpec(0, np.array(pts)),), (sc,))
    (placed,) = build_placed(spec, m, spec.dense_routes(m))
    source = placed.flows[0].source
    assert not m.lane_internal[source.lane] and source.s == 0.0
    given = np.array([495.7, -36.5])  # the map frame's y is CARLA's, negated
    path = placed.flows[0].path
    assert np.min(np.linalg.norm(path.xy - given, axis=1)) > 5.0  # it starts past the given point ...
    start_xy = path.xy[0]
    assert np.linalg.norm(start_xy - given) < 10.0  # ... a few metres on, where the junction lane ends


def test_a_car_sumo_discarded_is_dropped_before_the_flow_reacts_to_its_first_collision(
    mini_net: Path, mini: RoadMap, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A car SUMO discarded at insertion is neither running nor pending; when the flow's first collision
    comes in the same tick, the flow must drop that car before commanding its cars to follow traffic
    (cmudrive44's EnterActorFlow_3, seed 1, crashed the route with "Vehicle ... is not known" there)."""
    import libsumo

    lane = mini.lane("CE_1")
    with World(WorldConfig(town=mini_net, seed=1), road_map=mini) as world:
        flow = VehicleFlow(
            "F", world, mini, LanePoint(lane, 20.0), LanePoint(lane, 195.0), (30.0, 30.0), 12.0,
            np.random.default_rng(0), True,
        )  # fmt: skip
        none = Controls(np.zeros(0), np.zeros(0), np.zeros(0))
        snap = world.tick(none)
        for _ in range(80):  # 4 s: two cars out
            flow.update(snap)
            snap = world.tick(none)
        assert flow.cars[:2] == ["F:0", "F:1"]
        listed = libsumo.vehicle.getIDList
        monkeypatch.setattr(libsumo.vehicle, "getIDList", lambda: [c for c in listed() if c != "F:1"])
        monkeypatch.setattr(flow, "_hit_something", lambda: True)
        commanded: list[str] = []
        override = world.sumo.override
        monkeypatch.setattr(
            world.sumo, "override", lambda car, **kw: (commanded.append(car), override(car, **kw))
        )
        flow.update(snap)  # F:1 looks discarded, and a collision came in
    assert flow.collided and "F:1" not in flow.cars and "F:0" in flow.cars
    assert "F:1" not in commanded and "F:0" in commanded


def test_a_flow_car_placed_before_a_stop_sign_departs_no_faster_than_it_could_stop(
    mini_net: Path, mini: RoadMap
) -> None:
    """SUMO inserts a car before a link without right of way (here the mini network's stop sign at N) only
    if it could stop at the line, else it discards it ("unpriorised junction too close";
    cmudrive44's NonSignalizedJunctionRightTurn_1 and MergerIntoSlowTrafficV2_3 lost a flow car so). A
    12 m/s ActorFlow car placed 10 m before the line departs slowly enough to stop there (SUMO's safe
    speed), is in the world from its first tick and then, ignoring the stop sign as an ActorFlow car does,
    drives through the junction and up to speed."""
    cn = mini.lane("CN_1")
    source = LanePoint(cn, float(mini.lane_length[cn]) - 12.5)  # the car's centre 10 m short of the line
    sink = LanePoint(mini.lane("NNE_1"), 100.0)
    v: list[float] = []
    with World(WorldConfig(town=mini_net, seed=1), road_map=mini) as world:
        rng = np.random.default_rng(0)
        flow = VehicleFlow("F", world, mini, source, sink, (500.0, 500.0), 12.0, rng, True)
        none = Controls(np.zeros(0), np.zeros(0), np.zeros(0))
        snap = world.tick(none)
        flow.update(snap)  # the first car
        for _ in range(100):  # 5 s
            snap = world.tick(none)
            flow.update(snap)
            r = np.flatnonzero(snap.ids == "F:0")
            v.append(float(snap.speed[r[0]]) if len(r) else np.nan)
    assert not np.isnan(v[0])  # inserted, not discarded
    assert v[0] < 8.0  # [m/s] it could stop within the 10 m to the line
    assert np.nanmax(v) == pytest.approx(12.0, abs=0.1)  # then the flow speed, through the junction


def _standing_in_junction(mini: RoadMap, flow_xy: np.ndarray, clear: float) -> Route:
    """The mini network's S -> N route through junction C, from its first point where the CAV's box
    (4.89 x 2.1 m) comes within ``clear`` [m] of the path ``flow_xy`` (n, 2)."""
    route = RoutePlanner(mini).plan_lanes(LanePos(mini.lane("SC_0"), 150.0), LanePos(mini.lane("CN_1"), 50.0))
    for k in range(len(route)):
        rel = flow_xy - route.xy[k]
        c, s = np.cos(route.heading[k]), np.sin(route.heading[k])
        out_u = np.maximum(np.abs(rel[:, 0] * c + rel[:, 1] * s) - 4.89 / 2, 0.0)
        out_w = np.maximum(np.abs(-rel[:, 0] * s + rel[:, 1] * c) - 2.1 / 2, 0.0)
        if np.hypot(out_u, out_w).min() < clear:
            break
    fields = ("xy", "heading", "lane", "s", "speed_limit", "in_junction", "option")
    cut = {f: getattr(route, f)[k:] for f in fields}
    return dataclasses.replace(route, **cut, distance=route.distance[k:] - route.distance[k])


def _follow_past_standing_cav(mini_net: Path, mini: RoadMap, clear: float) -> tuple[np.ndarray, list, float]:
    """A 12 m/s ActorFlow W -> E straight through junction C that has collided (it follows cars), and a
    CAV standing on its S -> N lane inside the junction ``clear`` [m] from the flow's path; the CAV
    leaves after 17.5 s. Returns the first car's (x, y, speed) per tick (NaN when absent), the contacts
    and the smallest gap [m] between the two boxes while both stood."""
    source, sink = LanePoint(mini.lane("WC_1"), 100.0), LanePoint(mini.lane("CE_1"), 60.0)
    track_: list[tuple[float, float, float]] = []
    hits: list[tuple[int, str, str]] = []
    gap = np.inf
    with World(WorldConfig(town=mini_net, seed=1), road_map=mini) as world:
        rng = np.random.default_rng(0)
        flow = VehicleFlow("F", world, mini, source, sink, (500.0, 500.0), 12.0, rng, True)
        world.add_cav(_standing_in_junction(mini, flow.path.xy, clear), speed=0.0)
        flow.collided = True  # as after a collision of one of its cars: every car follows traffic
        stand = Controls(np.zeros(1), np.zeros(1), np.ones(1))
        snap = world.tick(stand)
        for k in range(500):  # 25 s
            flow.update(snap)
            if k == 350:
                world.remove_cav(0)
                stand = Controls(np.zeros(0), np.zeros(0), np.zeros(0))
            snap = world.tick(stand)
            ev = world.collisions
            hits += [(k, str(a), str(b)) for a, b in zip(ev.id_a, ev.id_b, strict=True)]
            r, c = np.flatnonzero(snap.ids == "F:0"), np.flatnonzero(snap.ids == "cav0")
            track_.append((snap.x[r[0]], snap.y[r[0]], snap.speed[r[0]]) if len(r) else (np.nan,) * 3)
            if len(r) and len(c) and snap.speed[r[0]] < 0.05:
                gap = min(gap, _box_gap(_box(snap, r[0]), _box(snap, c[0])))
    return np.array(track_), hits, gap


def _box(snap: Snapshot, i: int) -> np.ndarray:
    """Row ``i``'s box as (x, y, cos yaw, sin yaw, half length, half width)."""
    c, s = np.cos(snap.yaw[i]), np.sin(snap.yaw[i])
    return np.array([snap.x[i], snap.y[i], c, s, 0.5 * snap.length[i], 0.5 * snap.width[i]])


def _box_gap(a: np.ndarray, b: np.ndarray) -> float:
    """[m] the distance between two boxes that do not overlap (``_box`` rows): the nearest corner of
    either to the other box."""

    def corners(t: np.ndarray) -> np.ndarray:
        sign = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]])
        lon, lat = sign[:, 0] * t[4], sign[:, 1] * t[5]
        return np.stack([t[0] + lon * t[2] - lat * t[3], t[1] + lon * t[3] + lat * t[2]], axis=1)

    def point_box(p: np.ndarray, t: np.ndarray) -> np.ndarray:
        rel = p - t[:2]
        u = np.maximum(np.abs(rel[:, 0] * t[2] + rel[:, 1] * t[3]) - t[4], 0.0)
        w = np.maximum(np.abs(-rel[:, 0] * t[3] + rel[:, 1] * t[2]) - t[5], 0.0)
        return np.hypot(u, w)

    return float(min(point_box(corners(a), b).min(), point_box(corners(b), a).min()))


def test_a_following_flow_car_stands_short_of_a_cav_reaching_into_its_path(
    mini_net: Path, mini: RoadMap
) -> None:
    """A 12 m/s ActorFlow that has collided (it follows cars) crosses junction C west to east; a CAV stands
    inside the junction on its south-north lane with its nose 0.2 m into the flow car's swept path. The car
    stands 3.5-5 m short of it (``YIELD_STANDOFF``: 4 m to the first path point it would touch; SUMO alone
    stopped it 2.9 m short, at the conflict point of the two internal lanes, which on Town03 lay beside the
    CAV's nose), never touches it, and drives on at the flow speed once the CAV has gone."""
    xyv, hits, gap = _follow_past_standing_cav(mini_net, mini, clear=0.925 - 0.2)
    assert not hits
    assert 3.5 < gap < 5.0  # [m] box to box, while both stood
    assert np.nanmin(xyv[:350, 2]) < 0.05 and np.nanmax(xyv[:350, 0]) < 200.0  # stood, west of the CAV
    assert np.nanmax(xyv[350:, 2]) == pytest.approx(12.0, abs=0.1)  # the flow speed after it left
