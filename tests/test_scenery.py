"""Static scenery: derived on every committed town, never on a lane, cached, drawn, and hit as layout.

The no-overlap test checks the boxes against lane areas built independently of the builder: the drawn
lane polygons of :mod:`cmudrive.viz.map_plot` (centrelines offset by half the width), the walking-area
outlines, the crossings' strips and the junction outlines.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import shapely

from cmudrive.bench.criteria import RouteCriteria
from cmudrive.bench.criteria.layout import SceneryIndex, box_table, scenery_contacts
from cmudrive.maps import (
    LaneKind,
    RoadMap,
    RoutePlanner,
    SceneryKind,
    StaticScenery,
    available_towns,
    load_map,
    load_scenery,
)
from cmudrive.maps.routing import Route
from cmudrive.maps.scenery_build import build_scenery
from cmudrive.maps.surfaces import junction_polygons
from cmudrive.sim.collisions import detect_collisions
from cmudrive.sim.dynamics import CavState, Controls, VehicleParams, step_bicycle
from cmudrive.sim.snapshot import ActorKind, Role, Snapshot
from cmudrive.viz.bev import BevRenderer
from cmudrive.viz.map_plot import SCENERY_COLOURS, lane_polygons

TOWNS = available_towns()
FAST_TOWNS = {"highway", "interurban", "Town04", "Town06"}  # towns with fast roads without sidewalks
CLEARANCE = 0.2  # [m] every box keeps at least this far from any lane area (the builder's margin is 0.3)
DT = 0.05  # [s]
CAV_LENGTH, CAV_WIDTH = 4.89, 2.10  # [m]


@pytest.fixture(scope="module")
def maps() -> dict[str, RoadMap]:
    return {town: load_map(town) for town in TOWNS}


@pytest.fixture(scope="module")
def sceneries(maps: dict[str, RoadMap]) -> dict[str, StaticScenery]:
    return {town: build_scenery(m) for town, m in maps.items()}


def counts(scenery: StaticScenery) -> np.ndarray:
    return np.bincount(scenery.kind, minlength=len(SceneryKind))


def lane_areas(m: RoadMap) -> list[shapely.Geometry]:
    polys, _, _ = lane_polygons(m)  # every lane but crossings (walking areas are their outline)
    areas = [shapely.make_valid(shapely.Polygon(p)) for p in [*polys, *junction_polygons(m)]]
    for lane in np.flatnonzero(m.lane_kind == LaneKind.CROSSING).tolist():
        if len(m.polyline(lane)) >= 2:
            strip = shapely.LineString(m.polyline(lane)).buffer(0.5 * m.lane_width[lane], cap_style="flat")
            areas.append(strip)
    return areas


# ---- what is derived ---------------------------------------------------------------------------------


@pytest.mark.parametrize("town", TOWNS)
def test_every_town_has_buildings_and_its_roads_furniture(
    town: str, maps: dict[str, RoadMap], sceneries: dict[str, StaticScenery]
) -> None:
    m, scenery = maps[town], sceneries[town]
    n = counts(scenery)
    assert n[SceneryKind.BUILDING] >= 50
    has_sidewalks = bool(np.any(m.lane_kind == LaneKind.SIDEWALK))
    assert (n[SceneryKind.POLE] >= 20) == has_sidewalks  # street lights stand beside sidewalks only
    if town in FAST_TOWNS:
        assert n[SceneryKind.GUARDRAIL] >= 100
    # physical sizes
    building = scenery.kind == SceneryKind.BUILDING
    assert np.all((scenery.height[building] >= 4.0) & (scenery.height[building] <= 30.0))
    assert np.all(scenery.length[building] >= 6.99) and np.all(scenery.width[building] >= 6.99)
    pole = scenery.kind == SceneryKind.POLE
    assert np.allclose(scenery.length[pole], 0.3) and np.all(scenery.height[pole] >= 6.0)
    rail = scenery.kind == SceneryKind.GUARDRAIL
    assert np.all(scenery.length[rail] <= 4.01) and np.allclose(scenery.height[rail], 0.8)


def test_downtown_buildings_are_taller_than_rural_ones(sceneries: dict[str, StaticScenery]) -> None:
    def tallest(town: str) -> float:
        s = sceneries[town]
        return float(s.height[s.kind == SceneryKind.BUILDING].max())

    assert tallest("downtown") > 20.0  # multi-lane streets with sidewalks: up to 30 m
    assert tallest("interurban") <= 10.0  # no sidewalks anywhere: farms and sheds


def test_highway_guardrails_follow_the_carriageway_edge(
    maps: dict[str, RoadMap], sceneries: dict[str, StaticScenery]
) -> None:
    """Guardrail boxes stand just outside a fast lane: 0.3-1.5 m from the lane's edge, heading along it."""
    m, s = maps["highway"], sceneries["highway"]
    rail = s.kind == SceneryKind.GUARDRAIL
    xy, yaw = np.column_stack([s.x[rail], s.y[rail]]), s.yaw[rail]
    proj = m.index.nearest_lane(xy, kinds=(LaneKind.DRIVING,))
    gap = np.abs(proj.d) - 0.5 * m.lane_width[proj.lane]  # [m] rail centre beyond the lane edge
    assert np.median(gap) == pytest.approx(0.5, abs=0.1)
    assert np.mean((gap > 0.3) & (gap < 1.5)) > 0.95
    along = np.abs(np.cos(yaw - proj.heading))
    assert np.mean(along > 0.98) > 0.95


@pytest.mark.parametrize("town", TOWNS)
def test_no_box_comes_near_a_lane_or_junction(
    town: str, maps: dict[str, RoadMap], sceneries: dict[str, StaticScenery]
) -> None:
    tree = shapely.STRtree(lane_areas(maps[town]))
    boxes = shapely.polygons(sceneries[town].corners())
    hit, _ = tree.query(boxes, predicate="dwithin", distance=CLEARANCE)
    assert len(hit) == 0, f"{len(np.unique(hit))} boxes within {CLEARANCE} m of a lane, e.g. {hit[:5]}"


@pytest.mark.parametrize("town", TOWNS)
def test_a_car_centred_on_any_driving_lane_touches_no_scenery(
    town: str, maps: dict[str, RoadMap], sceneries: dict[str, StaticScenery]
) -> None:
    """A CAV-sized box every metre along every driving lane (junction lanes too), at the lane's heading."""
    m = maps[town]
    index = m.index
    lane = index.seg_lane[index.sample_seg]
    driving = m.lane_kind[lane] == LaneKind.DRIVING
    xy, yaw = index.sample_xy[driving], index.seg_heading[index.sample_seg][driving]
    n = len(xy)
    boxes = box_table(xy[:, 0], xy[:, 1], yaw, np.full(n, CAV_LENGTH), np.full(n, CAV_WIDTH))
    row, _ = scenery_contacts(boxes, SceneryIndex.build(sceneries[town]))
    assert len(row) == 0, f"cars on lanes {np.unique(m.lane_ids[lane[driving][row]])[:5]} touch scenery"


def test_buildings_do_not_overlap_each_other(sceneries: dict[str, StaticScenery]) -> None:
    s = sceneries["downtown"]
    boxes = shapely.polygons(s.corners()[s.kind == SceneryKind.BUILDING])
    i, j = shapely.STRtree(boxes).query(boxes, predicate="intersects")
    assert np.all(i == j)


# ---- determinism and cache ---------------------------------------------------------------------------


def test_same_seed_same_arrays_other_seed_other_town(maps: dict[str, RoadMap]) -> None:
    m = maps["suburb"]
    a, b, c = build_scenery(m, seed=0), build_scenery(m, seed=0), build_scenery(m, seed=1)
    for name, value in a.arrays().items():
        np.testing.assert_array_equal(value, b.arrays()[name])
    assert len(a) != len(c) or not np.array_equal(a.x, c.x)


def test_cache_round_trips(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, maps: dict[str, RoadMap]) -> None:
    monkeypatch.setenv("CMUDRIVE_CACHE", str(tmp_path))
    built = load_scenery("Town02")
    files = list((tmp_path / "maps" / "scenery").glob("Town02-*.npz"))
    assert len(files) == 1
    again = load_scenery(maps["Town02"])  # a RoadMap: the same key
    for name, value in built.arrays().items():
        np.testing.assert_array_equal(value, again.arrays()[name])
        assert value.dtype == again.arrays()[name].dtype
    files[0].write_bytes(b"not an npz")  # a corrupt entry is rebuilt with a warning
    with pytest.warns(UserWarning, match="unreadable scenery cache"):
        rebuilt = load_scenery("Town02")
    np.testing.assert_array_equal(rebuilt.x, built.x)


# ---- contacts ----------------------------------------------------------------------------------------


def test_scenery_contacts_on_hand_built_boxes() -> None:
    """A car box against a pole it overlaps, a building it touches flush, and a pole 1 m away."""
    scenery = StaticScenery(
        kind=np.array([SceneryKind.POLE, SceneryKind.BUILDING, SceneryKind.POLE], np.int8),
        x=np.array([2.3, 0.0, 0.0]),  # the car's front bumper is at x = 2.5
        y=np.array([0.0, 6.05, -2.35]),  # the building's near face at y = 1.05 (the car's left side)
        yaw=np.zeros(3),
        length=np.array([0.3, 20.0, 0.3]),
        width=np.array([0.3, 10.0, 0.3]),
        height=np.array([7.0, 12.0, 7.0]),
    )
    cars = box_table(np.array([0.0, 50.0]), np.zeros(2), np.zeros(2), np.full(2, 5.0), np.full(2, 2.1))
    row, obj = scenery_contacts(cars, SceneryIndex.build(scenery))
    assert row.tolist() == [0] and obj.tolist() == [0]
    empty = scenery_contacts(cars, SceneryIndex.build(StaticScenery.empty()))
    assert len(empty[0]) == 0


def route_on(m: RoadMap) -> Route:
    """~340 m eastbound on downtown's third street (y ~ 278), through two junctions."""
    return RoutePlanner(m).plan(np.array([200.0, 276.0]), np.array([540.0, 276.0]), start_heading=0.0)


def cav_snapshot(step: int, state: CavState) -> Snapshot:
    return Snapshot.from_rows(
        step,
        step * DT,
        np.array([""]),
        ids=np.array(["cav0"]),
        x=state.x,
        y=state.y,
        yaw=state.yaw,
        speed=state.speed,
        kind=np.array([ActorKind.CAR], np.int8),
        role=np.array([Role.CAV], np.int8),
        length=np.array([CAV_LENGTH]),
        width=np.array([CAV_WIDTH]),
    )


def test_cav_steering_into_the_roadside_has_one_layout_collision(maps: dict[str, RoadMap]) -> None:
    """Full throttle and full right steer from 10 m/s on downtown's third street: the CAV leaves the road
    over the bike lane and sidewalk and hits a street light or a building within a few seconds; braking
    hard from then on, it records exactly one collisions_layout (factor 0.65)."""
    m = maps["downtown"]
    route = route_on(m)
    criteria = RouteCriteria(m, [route], ["cav0"], dt=DT)
    state = CavState(*(np.array([v]) for v in (*route.xy[0], float(route.heading[0]), 10.0, 0.0, 0.0)))
    params = VehicleParams()
    hit_at = None
    for step in range(1, 200):  # 10 s at most
        braking = hit_at is not None
        full = np.array([0.0 if braking else 1.0])
        controls = Controls(steer=full, throttle=full, brake=1.0 - full)
        state = step_bicycle(state, controls, params, DT)
        snap = cav_snapshot(step, state)
        criteria.update(snap, detect_collisions(snap))
        layout = criteria.results()[0].infractions["collisions_layout"]
        if hit_at is None and layout:
            hit_at = step
        if hit_at is not None and state.speed[0] == 0.0:
            break
    assert hit_at is not None and hit_at * DT < 4.0, "the CAV never hit the roadside scenery"
    result = criteria.results()[0]
    layout = result.infractions["collisions_layout"]
    assert len(layout) == 1
    assert layout[0].factor == pytest.approx(0.65)
    assert layout[0].actor is not None and layout[0].actor.split(":")[1] in ("building", "pole")
    others = [r.factor for k, v in result.infractions.items() if k != "collisions_layout" for r in v]
    assert result.infraction_score == pytest.approx(0.65 * float(np.prod(others)))


def test_cav_following_its_lane_hits_nothing(maps: dict[str, RoadMap]) -> None:
    m = maps["downtown"]
    route = route_on(m)
    criteria = RouteCriteria(m, [route], ["cav0"], dt=DT)
    speed = 12.0  # [m/s]
    for step, d in enumerate(np.arange(0.0, route.length, speed * DT), start=1):
        x, y = (np.interp(d, route.distance, route.xy[:, k]) for k in (0, 1))
        yaw = np.interp(d, route.distance, np.unwrap(route.heading))
        snap = cav_snapshot(step, CavState(*(np.array([v]) for v in (x, y, yaw, speed, 0.0, 0.0))))
        criteria.update(snap, detect_collisions(snap))
    result = criteria.results()[0]
    assert result.infractions["collisions_layout"] == []
    assert result.route_completion > 95.0


# ---- drawing -----------------------------------------------------------------------------------------


def test_bev_background_shows_buildings(
    maps: dict[str, RoadMap], sceneries: dict[str, StaticScenery]
) -> None:
    m, s = maps["downtown"], sceneries["downtown"]
    big = np.flatnonzero((s.kind == SceneryKind.BUILDING) & (s.length > 12.0) & (s.width > 12.0))[0]
    x, y = float(s.x[big]), float(s.y[big])
    bounds = (x - 30.0, y - 30.0, x + 30.0, y + 30.0)
    with_scenery = BevRenderer(m, 4.0, bounds=bounds, scenery=s)
    without = BevRenderer(m, 4.0, bounds=bounds, scenery=False)
    r, c = with_scenery.full_view.pixel_index(np.array([[x, y]]))[0]
    colour = SCENERY_COLOURS[SceneryKind.BUILDING]
    expected = np.array([int(colour[k : k + 2], 16) for k in (1, 3, 5)])
    assert np.abs(with_scenery.background[r, c].astype(int) - expected).max() <= 3
    assert np.abs(without.background[r, c].astype(int) - expected).max() > 20
