"""Background activity: density around standing CAVs, out-of-sight spawns, removal, the BA commands and
determinism, on a committed town (the ``mini`` fixture network when no town is committed)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import libsumo
import numpy as np
import pytest

from cmudrive.maps import LaneKind, LanePos, RoadMap, RoutePlanner, available_towns, load_map
from cmudrive.sim.actor_types import ACTOR_TYPES
from cmudrive.sim.background import BackgroundActivity, BackgroundConfig
from cmudrive.sim.background_geometry import upstream_windows
from cmudrive.sim.dynamics import Controls
from cmudrive.sim.snapshot import ActorKind, Role, Snapshot
from cmudrive.sim.world import World, WorldConfig

TOWN = "downtown"
CAV0_S = 20.0  # [m] CAV 0 stands this far along its lane, with the rest of the (straight) lane ahead
MAX_BG_SPEED = 16.0  # [m/s] no background vehicle in the town drives faster (speed limits + factor)


@pytest.fixture(scope="module")
def town(mini_net: Path) -> tuple[str | Path, RoadMap]:
    net: str | Path = TOWN if TOWN in available_towns() else mini_net
    return net, load_map(net)


def _straight(m: RoadMap, lane: int) -> bool:
    xy = m.polyline(lane)
    heading = np.arctan2(*np.diff(xy, axis=0)[:, ::-1].T)
    return bool(np.ptp(np.unwrap(heading)) < 0.01)


def cav_lanes(m: RoadMap) -> tuple[int, int]:
    """Two long straight driving lanes near the map centre whose CAV spots are 60-150 m apart."""
    cand = np.flatnonzero(m.driving & ~m.lane_internal & (m.lane_length > 110.0))
    cand = np.array([c for c in cand.tolist() if _straight(m, c)])
    spot = m.index.frenet_to_xy(cand, np.full(len(cand), CAV0_S))
    off_centre = np.linalg.norm(spot - 0.5 * (m.bounds[:2] + m.bounds[2:]), axis=1)
    apart = np.linalg.norm(spot[:, None] - spot[None], axis=-1)
    score = np.where((apart > 60.0) & (apart < 150.0), off_centre[:, None] + off_centre[None], np.inf)
    i, j = np.unravel_index(np.argmin(score), score.shape)
    assert np.isfinite(score[i, j]), "no pair of CAV lanes found"
    return int(cand[i]), int(cand[j])


@contextmanager
def standing_world(
    town: tuple[str | Path, RoadMap], config: BackgroundConfig, seed: int = 7, populate: bool = True
) -> Iterator[tuple[World, BackgroundActivity]]:
    """A world with 2 standing CAVs and background activity (populated unless told otherwise)."""
    net, m = town
    planner = RoutePlanner(m)
    with World(WorldConfig(net, seed=seed), road_map=m) as world:
        for lane in cav_lanes(m):
            world.add_cav(planner.plan_lanes(LanePos(lane, CAV0_S), LanePos(lane, CAV0_S + 10.0)))
        bg = BackgroundActivity(config)
        world.background = bg
        if populate:
            bg.populate(world)
        yield world, bg


def run(world: World, ticks: int) -> Snapshot:
    brake = Controls(np.zeros(2), np.zeros(2), np.ones(2))
    snap = world.last_snapshot
    for _ in range(ticks):
        snap = world.tick(brake)
    assert snap is not None
    return snap


def cav_xy(world: World) -> np.ndarray:
    return np.stack([world.cav_state.x, world.cav_state.y], axis=1)


def background_vehicles(snap: Snapshot) -> np.ndarray:
    return (snap.role == Role.BACKGROUND) & (snap.kind != ActorKind.PEDESTRIAN)


def nearest_cav_distance(world: World, xy: np.ndarray) -> np.ndarray:
    return np.min(np.linalg.norm(np.asarray(xy)[:, None, :] - cav_xy(world)[None], axis=-1), axis=1)


def add_background_car(world: World, vid: str, lane: int, s: float | str, speed: float | str = 0.0) -> None:
    m = world.map
    edge = str(m.edge_ids[m.lane_edge[lane]])
    world.sumo.add_vehicle(
        vid,
        "car",
        [edge],
        int(Role.BACKGROUND),
        depart_pos=s,
        depart_lane=int(m.lane_index[lane]),
        depart_speed=speed,
    )


# ---------------------------------------------------------------------------------------------------


def test_density_near_target_and_later_spawns_out_of_sight(town: tuple[str | Path, RoadMap]) -> None:
    cfg = BackgroundConfig(vehicles=40, pedestrians=20)
    with standing_world(town, cfg) as (world, bg):
        m = world.map
        initial = list(bg.spawns)
        assert sum(r.type_name != "pedestrian" for r in initial) >= 0.9 * cfg.vehicles
        snap = run(world, 200)
        veh = background_vehicles(snap)
        near = nearest_cav_distance(world, snap.xy[veh])
        assert 0.75 * cfg.vehicles <= np.count_nonzero(near <= cfg.radius) <= 1.25 * cfg.vehicles
        ped = (snap.role == Role.BACKGROUND) & (snap.kind == ActorKind.PEDESTRIAN)
        near_ped = nearest_cav_distance(world, snap.xy[ped])
        n_ped = np.count_nonzero(near_ped <= cfg.pedestrian_radius)
        assert 0.75 * cfg.pedestrians <= n_ped <= 1.25 * cfg.pedestrians

        xy = np.array([[r.x, r.y] for r in bg.spawns])
        dist = nearest_cav_distance(world, xy)  # the CAVs never moved
        is_initial = np.array([r.initial for r in bg.spawns])
        assert len(bg.spawns) > len(initial), "no spawn after the initial fill"
        assert np.all(dist[~is_initial] >= cfg.spawn_min_distance)
        assert np.all(dist[is_initial] >= cfg.fill_clearance)
        assert np.all(dist[is_initial] <= cfg.radius)
        # lane permissions: pedestrians on sidewalks, each vehicle type only where SUMO allows its class
        for r in bg.spawns:
            if r.type_name == "pedestrian":
                assert m.lane_kind[r.lane] == LaneKind.SIDEWALK
            else:
                allowed = libsumo.lane.getAllowed(str(m.lane_ids[r.lane]))
                assert not allowed or ACTOR_TYPES[r.type_name].vclass in allowed
        # the initial fill is spread out: no two spawns within 10 m on one lane
        lanes = np.array([r.lane for r in initial])
        pts = np.array([[r.x, r.y] for r in initial])
        gap = np.linalg.norm(pts[:, None] - pts[None], axis=-1) + np.eye(len(pts)) * 1e9
        assert not np.any((lanes[:, None] == lanes[None]) & (gap < 10.0 - 1e-6))
        assert bg.stats["spawned"] == len(bg.spawns)


def test_vehicles_driving_away_are_removed(town: tuple[str | Path, RoadMap]) -> None:
    cfg = BackgroundConfig(
        vehicles=15, pedestrians=0, radius=60.0, removal_margin=10.0, spawn_min_distance=40.0
    )
    with standing_world(town, cfg) as (world, bg):
        for _ in range(20):
            snap = run(world, cfg.update_period)  # an update just ran (snapshot one tick of motion later)
            veh = background_vehicles(snap)
            far = nearest_cav_distance(world, snap.xy[veh])
            assert np.all(far <= cfg.radius + cfg.removal_margin + MAX_BG_SPEED * world.dt + 3.0)
        assert bg.stats["removed_far"] > 0


def test_leave_space_clears_the_lane_corridor_ahead(town: tuple[str | Path, RoadMap]) -> None:
    with standing_world(town, BackgroundConfig(), populate=False) as (world, bg):
        m = world.map
        lane = cav_lanes(m)[0]
        for i, ahead in enumerate((10.0, 22.0, 36.0, 75.0)):  # front bumpers, metres ahead of the CAV centre
            add_background_car(world, f"ahead{i}", lane, CAV0_S + ahead)
        run(world, 3)
        bg.populate(world)  # the cars above are in the snapshot now: the fill leaves room for them
        snap = run(world, 3)
        assert {"ahead0", "ahead1", "ahead2", "ahead3"} <= set(snap.ids.tolist())
        removed = bg.leave_space(0, 40.0)
        assert removed >= 3
        snap = run(world, 1)
        veh = background_vehicles(snap)
        yaw = world.cav_state.yaw[0]
        rel = snap.xy[veh] - cav_xy(world)[0]
        lon = rel[:, 0] * np.cos(yaw) + rel[:, 1] * np.sin(yaw)
        lat = -rel[:, 0] * np.sin(yaw) + rel[:, 1] * np.cos(yaw)
        in_corridor = (lon > 0.0) & (lon <= 40.0) & (np.abs(lat) < 0.5 * m.lane_width[lane])
        assert not in_corridor.any(), snap.ids[veh][in_corridor]
        assert "ahead3" in world.sumo.actors  # beyond the 40 m: kept


def test_remove_lane_clears_it_and_stops_spawns_there(town: tuple[str | Path, RoadMap]) -> None:
    with standing_world(town, BackgroundConfig()) as (world, bg):
        run(world, 200)
        later = [r.lane for r in bg.spawns if not r.initial]
        lane = int(np.bincount(later).argmax())  # the lane most used by out-of-sight spawns so far
        add_background_car(world, "victim", lane, "random_free", speed="max")  # the lane is never empty
        snap = run(world, 2)
        on_lane = [a for a in snap.ids[background_vehicles(snap) & (snap.lane == lane)].tolist()]
        assert on_lane
        n_before = len(bg.spawns)
        assert bg.remove_lane([lane]) >= len(on_lane)
        assert not set(on_lane) & set(world.sumo.actors)
        run(world, 200)
        after = bg.spawns[n_before:]
        assert after, "no spawns at all after remove_lane"
        assert all(r.lane != lane for r in after)
        bg.readd_lane([lane])


def test_max_speed_caps_background_vehicles(town: tuple[str | Path, RoadMap]) -> None:
    with standing_world(town, BackgroundConfig()) as (world, bg):
        run(world, 20)
        bg.max_speed(5.0)
        snap = run(world, 100)
        veh = background_vehicles(snap)
        assert veh.sum() > 20
        assert snap.speed[veh].max() <= 5.5
        bg.max_speed(None)
        vid = next(a for a in bg.background_ids() if a.startswith("bgv"))
        type_name = next(r.type_name for r in bg.spawns if r.actor_id == vid)
        assert libsumo.vehicle.getMaxSpeed(vid) == pytest.approx(ACTOR_TYPES[type_name].max_speed)


def test_stop_lane_halts_and_release_lane_lets_go(town: tuple[str | Path, RoadMap]) -> None:
    with standing_world(town, BackgroundConfig(vehicles=0, pedestrians=0)) as (world, bg):
        m = world.map
        lane = cav_lanes(m)[1]
        s0 = CAV0_S + 15.0  # ahead of CAV 1, which blocks nothing in front of it
        for i in range(3):
            add_background_car(world, f"halt{i}", lane, s0 + 20.0 * i, speed=8.0)
        snap = run(world, 6)
        ids = [f"halt{i}" for i in range(3)]
        assert all(snap.speed[snap.index_of(a)] > 5.0 for a in ids)
        assert bg.stop_lane([lane]) >= 3
        snap = run(world, 80)
        assert all(snap.speed[snap.index_of(a)] < 0.1 for a in ids)
        assert bg.release_lane([lane]) >= 3
        snap = run(world, 40)
        assert snap.speed[snap.index_of("halt2")] > 1.0  # the front car drives on


def test_stop_back_halts_only_what_is_behind_the_point(town: tuple[str | Path, RoadMap]) -> None:
    """StopBack (``before``): of three cars 20 m apart at 8 m/s, the two behind the point halt; the one
    ahead of it drives on (VehicleOpensDoorTwoWays once halted the car ahead of CAV 0 at the junction,
    and CAV 0 waited behind it until time-out)."""
    with standing_world(town, BackgroundConfig(vehicles=0, pedestrians=0)) as (world, bg):
        lane = cav_lanes(world.map)[1]
        s0 = CAV0_S + 15.0
        for i in range(3):
            add_background_car(world, f"halt{i}", lane, s0 + 20.0 * i, speed=8.0)
        run(world, 6)
        assert bg.stop_lane([lane], before=s0 + 35.0) == 2
        snap = run(world, 80)
        assert snap.speed[snap.index_of("halt0")] < 0.1 and snap.speed[snap.index_of("halt1")] < 0.1
        assert snap.speed[snap.index_of("halt2")] > 5.0


def test_clear_junction_and_opposite_traffic_off(town: tuple[str | Path, RoadMap]) -> None:
    cfg = BackgroundConfig(vehicles=60)
    with standing_world(town, cfg) as (world, bg):
        m = world.map
        snap = run(world, 100)
        veh = background_vehicles(snap) & (snap.lane >= 0)
        junction = m.lane_junction[snap.lane[veh]]
        busiest = int(np.bincount(junction[junction >= 0]).argmax())
        assert bg.clear_junction(busiest, approach=30.0) > 0
        snap = run(world, 1)
        veh = background_vehicles(snap) & (snap.lane >= 0)
        assert not np.any(m.lane_junction[snap.lane[veh]] == busiest)

        def oncoming(snap: Snapshot, min_distance: float, slack: float = 0.0) -> list[str]:
            """Background vehicles ahead of their nearest CAV, heading against it, within the radius.
            With ``slack`` [m, deg] vehicles near a boundary of the rule are left out: the update works on
            the previous tick's snapshot, so a vehicle may cross a boundary in between."""
            veh = background_vehicles(snap)
            d = np.sort(np.linalg.norm(snap.xy[veh][:, None] - cav_xy(world)[None], axis=-1), axis=1)
            k = np.linalg.norm(snap.xy[veh][:, None] - cav_xy(world)[None], axis=-1).argmin(axis=1)
            yaw = world.cav_state.yaw[k]
            rel = snap.xy[veh] - cav_xy(world)[k]
            ahead = rel[:, 0] * np.cos(yaw) + rel[:, 1] * np.sin(yaw) > slack
            against = np.abs((snap.yaw[veh] - yaw + np.pi) % (2 * np.pi) - np.pi) > np.radians(120.0 + slack)
            near = (d[:, 0] <= cfg.radius - slack) & (d[:, 0] >= min_distance + slack)
            near &= d[:, 1] - d[:, 0] > slack  # the nearest CAV is clear
            return snap.ids[veh][ahead & against & near].tolist()

        assert oncoming(snap, 0.0)
        assert bg.opposite_traffic(False) > 0
        n_before = len(bg.spawns)
        assert oncoming(run(world, 1), 0.0) == []
        for _ in range(10):  # later, oncoming vehicles (turning in) are removed once out of sight
            assert oncoming(run(world, cfg.update_period), cfg.spawn_min_distance, slack=2.0) == []
        for r in bg.spawns[n_before:]:
            k = int(np.argmin(np.linalg.norm(cav_xy(world) - [r.x, r.y], axis=1)))
            diff = abs((r.heading - world.cav_state.yaw[k] + np.pi) % (2 * np.pi) - np.pi)
            assert diff <= np.radians(120.0)


def test_stuck_vehicles_out_of_sight_are_removed(town: tuple[str | Path, RoadMap]) -> None:
    cfg = BackgroundConfig(vehicles=0, pedestrians=0, stuck_time=2.0)
    with standing_world(town, cfg) as (world, bg):
        m = world.map
        lane0 = cav_lanes(m)[0]
        add_background_car(world, "near", lane0, CAV0_S + 20.0)  # within sight of CAV 0
        far_lanes = np.flatnonzero(m.driving & ~m.lane_internal & (m.lane_length > 40.0))
        mid = m.index.frenet_to_xy(far_lanes, 0.5 * m.lane_length[far_lanes])
        dist = nearest_cav_distance(world, mid)
        far = int(far_lanes[np.argmax((dist > 80.0) & (dist < 140.0))])  # out of sight, inside the radius
        add_background_car(world, "far", far, 0.5 * m.lane_length[far])
        run(world, 2)
        for vid in ("near", "far"):
            libsumo.vehicle.setSpeed(vid, 0.0)
        run(world, 100)
        assert "far" not in world.sumo.actors
        assert "near" in world.sumo.actors
        assert bg.stats["removed_stuck"] == 1 and bg.stats["removed_far"] == 0


def test_same_seed_same_background(town: tuple[str | Path, RoadMap]) -> None:
    results = []
    for _ in range(2):
        with standing_world(town, BackgroundConfig(), seed=11) as (world, bg):
            snap = run(world, 100)
            rows = snap.role == Role.BACKGROUND
            results.append((snap.ids[rows].tolist(), snap.xy[rows].copy(), dict(bg.stats)))
    (ids_a, xy_a, stats_a), (ids_b, xy_b, stats_b) = results
    assert ids_a == ids_b
    np.testing.assert_array_equal(xy_a, xy_b)
    assert stats_a == stats_b


def test_config_rejects_bad_values() -> None:
    with pytest.raises(ValueError):
        BackgroundConfig(vehicle_mix={"hovercraft": 1.0})
    with pytest.raises(ValueError):
        BackgroundConfig(update_period=0)
    with pytest.raises(TypeError):
        BackgroundConfig(vehicle=3)  # type: ignore[call-arg]


def assert_room_to_stop_behind_cavs(world: World, bg: BackgroundActivity, cfg: BackgroundConfig) -> None:
    """No vehicle started behind a standing CAV on its road closer than it needs to stop from the lane's
    speed at fill_decel, plus fill_stop_gap; "behind" measured along the chord between the two (the mean
    of the two headings), so that curved roads count."""
    m = world.map
    yaw = world.cav_state.yaw
    assert bg.spawns
    for rec in bg.spawns:
        rel = cav_xy(world) - np.array([rec.x, rec.y])
        chord = np.arctan2(np.sin(yaw) + np.sin(rec.heading), np.cos(yaw) + np.cos(rec.heading))
        along = rel[:, 0] * np.cos(chord) + rel[:, 1] * np.sin(chord)
        across = -rel[:, 0] * np.sin(chord) + rel[:, 1] * np.cos(chord)
        reach = m.lane_speed[rec.lane] ** 2 / (2.0 * cfg.fill_decel) + cfg.fill_stop_gap
        same_way = np.cos(yaw - rec.heading) > 0.5
        behind = same_way & (along > 0.0) & (along < reach) & (np.abs(across) < cfg.fill_behind_width)
        assert not behind.any(), (rec.actor_id, rec.initial, along, across)


def test_spawns_leave_room_to_stop_behind_a_standing_cav(town: tuple[str | Path, RoadMap]) -> None:
    """At tick 0 SUMO cannot see the CAVs yet: the background must leave them room."""
    cfg = BackgroundConfig(vehicles=80, pedestrians=0)
    with standing_world(town, cfg) as (world, bg):
        for _ in range(40):  # later spawns too, while the CAVs stand
            world.tick(Controls(np.zeros(2), np.zeros(2), np.ones(2)))
        assert_room_to_stop_behind_cavs(world, bg, cfg)


def test_room_behind_a_cav_on_a_curved_highway() -> None:
    """Town04's highway curves through ~30 deg in 30 m at (-453, -41): a car spawned 32 m behind a standing
    CAV there at 29 m/s ran into it within 1.2 s (ConstructionObstacle_1)."""
    m = load_map("Town04")
    lane = m.lane("41_2")
    s, _ = m.index.project(np.array([[-453.4, -41.5]]), np.array([lane]))
    cfg = BackgroundConfig(vehicles=80, pedestrians=0)
    with World(WorldConfig("Town04", seed=7), road_map=m) as world:
        world.add_cav(
            RoutePlanner(m).plan_lanes(LanePos(lane, float(s[0])), LanePos(lane, float(s[0]) + 10.0))
        )
        bg = BackgroundActivity(cfg)
        world.background = bg
        bg.populate(world)
        assert_room_to_stop_behind_cavs(world, bg, cfg)


def test_no_spawn_upstream_of_a_cav_round_a_bend() -> None:
    """Town05's lane 24_3 turns ~70 deg in the 30 m before (-249, -94): a car spawned there at 25 m/s
    behind a standing CAV was not "behind" it by headings and ran into it at tick 38 (Accident_4, CAV 13).
    No spawn lies on the lanes leading to the CAV within its stopping reach."""
    m = load_map("Town05")
    lane = m.lane("24_3")
    s, _ = m.index.project(np.array([[-248.9, -94.0]]), np.array([lane]))
    cfg = BackgroundConfig(vehicles=120, pedestrians=0)
    reach = float(m.lane_speed[lane]) ** 2 / (2.0 * cfg.fill_decel) + cfg.fill_stop_gap
    windows = upstream_windows(m, lane, float(s[0]), reach)
    assert sum(hi - lo for _, lo, hi in windows) >= reach - 1.0
    with World(WorldConfig("Town05", seed=3), road_map=m) as world:
        world.add_cav(
            RoutePlanner(m).plan_lanes(LanePos(lane, float(s[0])), LanePos(lane, float(s[0]) + 10.0))
        )
        bg = BackgroundActivity(cfg)
        world.background = bg
        bg.populate(world)
        for _ in range(40):
            world.tick(Controls(np.zeros(1), np.zeros(1), np.ones(1)))
        assert bg.spawns
        for rec in bg.spawns:
            s_rec = m.index.project(np.array([[rec.x, rec.y]]), np.array([rec.lane]))[0][0]
            inside = [lo - 0.5 <= s_rec <= hi + 0.5 for up, lo, hi in windows if up == rec.lane]
            assert not any(inside), (rec.actor_id, m.lane_ids[rec.lane], s_rec)


def test_background_car_deadlocked_in_front_of_a_standing_cav_is_removed(
    town: tuple[str | Path, RoadMap],
) -> None:
    """A background car standing inside a junction just ahead of a standing CAV goes after deadlock_time;
    the same car standing on the CAV's lane ahead of it (a queue) stays."""
    net, m = town
    cfg = BackgroundConfig(vehicles=0, pedestrians=0, deadlock_time=2.0)
    lanes = np.flatnonzero(m.driving & ~m.lane_internal & (m.lane_length > 40.0))
    links = [(int(a), int(k)) for a in lanes for k in m.successor_links(int(a)) if m.link_via[k] >= 0]
    lane, link = links[0]
    out = int(m.link_to[link])
    route = RoutePlanner(m).plan_lanes(LanePos(lane, m.lane_length[lane] - 8.0), LanePos(out, 5.0))
    edges = [str(m.edge_ids[m.lane_edge[x]]) for x in (lane, out)]
    with World(WorldConfig(net, seed=3), road_map=m) as world:
        world.add_cav(route)
        bg = BackgroundActivity(cfg)
        world.background = bg
        bg.populate(world)
        world.sumo.add_vehicle(
            "blocker",
            "car",
            edges,
            int(Role.BACKGROUND),
            depart_pos=float(m.lane_length[lane] - 1.0),
            depart_lane=int(m.lane_index[lane]),
            depart_speed=0.0,
        )
        brake = Controls(np.zeros(1), np.zeros(1), np.ones(1))
        world.tick(brake)
        libsumo.vehicle.setSpeed("blocker", 0.0)  # standing on the CAV's lane just ahead: a queue
        for _ in range(80):
            world.tick(brake)
        assert "blocker" in world.sumo.actors and bg.stats["removed_deadlock"] == 0
        libsumo.vehicle.setSpeed("blocker", 2.0)  # into the junction, then it stands there
        for _ in range(200):
            snap = world.tick(brake)
            row = np.flatnonzero(snap.ids == "blocker")
            if len(row) and m.lane_internal[snap.lane[row[0]]]:
                libsumo.vehicle.setSpeed("blocker", 0.0)
                break
        else:
            pytest.fail("the car never entered the junction")
        for _ in range(80):
            world.tick(brake)
        assert "blocker" not in world.sumo.actors and bg.stats["removed_deadlock"] == 1
