"""BEV occupancy in the ego frame, partner selection, warping a partner's map, merging, the link model."""

import numpy as np
import pytest

from cmudrive.maps.scenery import SceneryKind, StaticScenery
from cmudrive.sensors import (
    DetectionNoise,
    OccupancyClass,
    OccupancyConfig,
    PerceptionFrame,
    SimulatedOccupancy,
    compute_visibility,
    occupancy_to_rgb,
)
from cmudrive.sim import ActorKind, Snapshot
from cmudrive.v2v import (
    NO_PARTNER,
    LinkConfig,
    V2VNetwork,
    merge,
    message_bytes,
    select_partners,
    warp_and_merge,
    warp_to_ego,
)

CFG = OccupancyConfig()
CAR, PED, BIKE = ActorKind.CAR, ActorKind.PEDESTRIAN, ActorKind.BICYCLE


def snapshot(rows):
    """rows: (x, y, yaw, kind, length, width)."""
    a = np.array(rows, float)
    return Snapshot.from_rows(
        0,
        0.0,
        [],
        x=a[:, 0],
        y=a[:, 1],
        yaw=a[:, 2],
        kind=a[:, 3].astype(np.int8),
        length=a[:, 4],
        width=a[:, 5],
    )


def grids(snap, cav_rows, scenery=None, noise=None, rng=120.0):
    scenery = scenery if scenery is not None else StaticScenery.empty()
    rows = np.asarray(cav_rows)
    vis = compute_visibility(snap, rows, rng, scenery)
    return SimulatedOccupancy(CFG, noise, np.random.default_rng(0))(PerceptionFrame(snap, rows, vis, scenery))


def occupied_xy(grid_2d):
    """Ego-frame centres of the occupied cells of one class grid."""
    xs, ys = CFG.cell_centres()
    r, c = np.nonzero(grid_2d)
    return xs[r], ys[c]


def test_grid_shape_and_cell_conventions():
    assert CFG.shape == (192, 128)
    xs, ys = CFG.cell_centres()
    assert xs[0] == pytest.approx(63.75) and xs[-1] == pytest.approx(-31.75)
    assert ys[0] == pytest.approx(31.75) and ys[-1] == pytest.approx(-31.75)
    r, c = CFG.cell_of(np.array([0.1]), np.array([0.1]))
    assert (r[0], c[0]) == (127, 63)
    with pytest.raises(ValueError, match="whole number"):
        OccupancyConfig(resolution=0.7)


def test_a_car_ahead_lands_in_front_and_one_to_the_left_lands_left():
    # ego at (100, 50) heading north; a car 20 m ahead (north), a pedestrian 10 m to its left (west)
    snap = snapshot(
        [
            (100, 50, np.pi / 2, CAR, 4.9, 2.1),
            (100, 70, np.pi / 2, CAR, 4.5, 1.9),
            (90, 62, 0.0, PED, 0.5, 0.5),
        ]
    )
    g = grids(snap, [0])[0]
    x, y = occupied_xy(g[OccupancyClass.VEHICLE])
    assert x.min() == pytest.approx(17.75, abs=0.01) and x.max() == pytest.approx(22.25, abs=0.01)
    assert np.abs(y).max() <= 1.0  # 1.9 m wide: cell centres within +-0.95 m
    x, y = occupied_xy(g[OccupancyClass.PEDESTRIAN])
    assert len(x) >= 1 and np.all(np.abs(x - 12) <= 0.5) and np.all(np.abs(y - 10) <= 0.5)
    assert not g[OccupancyClass.CYCLIST].any() and not g[OccupancyClass.STATIC].any()


def test_only_visible_objects_are_in_the_grid():
    # a pedestrian right behind a car ahead is hidden; a bicycle behind the ego is outside the camera
    snap = snapshot(
        [
            (0, 0, 0, CAR, 4.9, 2.1),
            (10, 0, 0, CAR, 4.5, 1.9),
            (14, 0, 0, PED, 0.5, 0.5),
            (-8, 0, 0, BIKE, 1.8, 0.6),
        ]
    )
    g = grids(snap, [0])[0]
    assert g[OccupancyClass.VEHICLE].any()
    assert not g[OccupancyClass.PEDESTRIAN].any() and not g[OccupancyClass.CYCLIST].any()


def test_scenery_is_static_class():
    wall = StaticScenery(
        np.array([SceneryKind.BUILDING], np.int8),
        np.array([20.0]),
        np.array([12.0]),
        np.array([0.0]),
        np.array([10.0]),
        np.array([6.0]),
        np.array([8.0]),
    )
    g = grids(snapshot([(0, 0, 0, CAR, 4.9, 2.1)]), [0], wall)[0]
    x, y = occupied_xy(g[OccupancyClass.STATIC])
    assert x.min() >= 15 - 0.25 and x.max() <= 25 + 0.25 and y.min() >= 9 - 0.25 and y.max() <= 15 + 0.25
    assert len(x) == 20 * 12  # 10 x 6 m at 0.5 m cells


def test_detection_noise_misses_far_objects_more_often_than_near_ones():
    rows = [(0, 0, 0, CAR, 4.9, 2.1)]
    rows += [(10, y, 0, PED, 0.5, 0.5) for y in np.linspace(-6, 6, 9)]
    rows += [(55, y, 0, PED, 0.5, 0.5) for y in np.linspace(-30, 30, 9)]
    snap = snapshot(rows)
    noise = DetectionNoise(miss_at_range=0.9)
    near, far = 0, 0
    for seed in range(20):
        scenery = StaticScenery.empty()
        vis = compute_visibility(snap, np.array([0]), 60.0, scenery)
        model = SimulatedOccupancy(CFG, noise, np.random.default_rng(seed))
        g = model(PerceptionFrame(snap, np.array([0]), vis, scenery))[0, OccupancyClass.PEDESTRIAN]
        x, _ = occupied_xy(g)
        near += np.count_nonzero(x < 30)
        far += np.count_nonzero(x > 30)
    assert near > 0.8 * 20 * 9  # at 10/60 of the range: miss probability 2.5 %
    assert far < 0.5 * 20 * 9  # at ~57/60: about 81 %


def test_partner_is_the_closest_cav_in_front_else_the_closest_in_range():
    # CAV 0 at the origin heading east; CAV 1 30 m ahead, CAV 2 10 m behind, CAV 3 20 m at 80 deg left
    x = np.array([0.0, 30.0, -10.0, 20 * np.cos(np.radians(80))])
    y = np.array([0.0, 0.0, 0.0, 20 * np.sin(np.radians(80))])
    yaw = np.zeros(4)
    p = select_partners(x, y, yaw, np.array([0, 1, 2, 3]))
    assert p[0] == 1  # the closest *in front*, though CAV 2 and 3 are closer
    assert p[1] in (0, 2, 3) and p[1] != 1
    far = select_partners(np.array([0.0, 100.0]), np.zeros(2), np.zeros(2), np.array([0, 5]))
    assert far.tolist() == [NO_PARTNER, NO_PARTNER]  # 100 m apart: beyond the 70 m range
    # a request overrides the default when in range, else the default stands
    req = select_partners(x, y, yaw, np.array([0, 1, 2, 3]), requested=np.array([2, -1, -1, 7]))
    assert req[0] == 2 and req[3] != 7


def ego_pose(x, y, yaw):
    return np.array([[x, y, yaw]])


def one_cell(x, y):
    g = np.zeros((1, 4, *CFG.shape), bool)
    r, c = CFG.cell_of(np.array([x]), np.array([y]))
    g[0, OccupancyClass.PEDESTRIAN, r[0], c[0]] = True
    return g


def warped_xy(partner_grid, partner, ego):
    w = warp_to_ego(partner_grid, partner, ego)[0, OccupancyClass.PEDESTRIAN]
    return occupied_xy(w)


@pytest.mark.parametrize(
    ("partner", "ped_in_partner", "ped_in_ego"),
    [
        ((0, 0, 0), (10.25, 3.25), (10.25, 3.25)),  # identity
        ((20, 0, 0), (10.25, 3.25), (30.25, 3.25)),  # partner 20 m ahead, same heading
        ((0, 0, np.pi / 2), (10.25, 3.25), (-3.25, 10.25)),  # partner turned 90 deg left
        ((30, 0, np.pi), (10.25, 3.25), (19.75, -3.25)),  # partner facing the ego, 30 m ahead
    ],
)
def test_an_object_seen_only_by_the_partner_lands_in_the_right_ego_cell(partner, ped_in_partner, ped_in_ego):
    x, y = warped_xy(one_cell(*ped_in_partner), np.array([partner], float), ego_pose(0, 0, 0))
    assert len(x) == 1
    assert x[0] == pytest.approx(ped_in_ego[0], abs=0.26) and y[0] == pytest.approx(ped_in_ego[1], abs=0.26)


def test_warp_is_invariant_to_where_both_cavs_are_in_the_map():
    g = one_cell(12.25, -4.75)
    base = warp_to_ego(g, np.array([[15.0, 5.0, 0.3]]), ego_pose(0, 0, 0.0))
    theta = 1.1
    c, s = np.cos(theta), np.sin(theta)
    moved = lambda x, y, yaw: [500 + c * x - s * y, -200 + s * x + c * y, yaw + theta]  # noqa: E731
    again = warp_to_ego(g, np.array([moved(15.0, 5.0, 0.3)]), np.array([moved(0.0, 0.0, 0.0)]))
    assert (base == again).all()


def test_round_trip_returns_the_cells_that_stay_in_both_grids():
    rng = np.random.default_rng(1)
    g = rng.random((1, 4, *CFG.shape)) < 0.05
    a, b = np.array([[0.0, 0.0, 0.0]]), np.array([[6.0, -2.0, np.radians(90)]])
    there = warp_to_ego(g, a, b)
    back = warp_to_ego(there, b, a)
    # a 90 degree turn and whole-cell offsets map cells one to one: what survives comes back unchanged
    assert back.sum() > 0.3 * g.sum()
    assert (back <= g).all()


def test_link_merges_the_partners_map_with_latency_noise_drop_and_counts_bytes():
    own = np.zeros((2, 4, *CFG.shape), bool)
    own[1] = one_cell(10.25, 0.25)[0]  # CAV 1 sees a pedestrian 10 m ahead of itself
    pose = np.array([[0.0, 0.0, 0.0], [20.0, 0.0, 0.0]])
    net = V2VNetwork()
    ex = net.exchange(0, np.array([0, 1]), pose, own)
    assert ex.partner.tolist() == [1, 0] and ex.received.tolist() == [True, True]
    x, y = occupied_xy(ex.merged[0, OccupancyClass.PEDESTRIAN])
    assert x.tolist() == [30.25] and y.tolist() == [0.25]
    assert net.stats.messages == 2 and net.stats.bytes == 2 * message_bytes(CFG) == 2 * 12316
    assert (net.stats.cav_ticks, net.stats.named, net.stats.named_taken) == (2, 0, 0)
    # CAV 0 names CAV 1 (in range: used), CAV 1 names CAV 7 (not on the road: the default stands)
    net.exchange(1, np.array([0, 1]), pose, own, requested=np.array([1, 7]))
    assert (net.stats.cav_ticks, net.stats.named, net.stats.named_taken) == (4, 2, 1)

    late = V2VNetwork(link=LinkConfig(latency_ticks=2))
    assert not late.exchange(0, np.array([0, 1]), pose, own).received.any()
    late.exchange(1, np.array([0, 1]), pose, own)
    assert late.exchange(2, np.array([0, 1]), pose, own).received.all()
    assert late.stats.not_yet == 4

    lost = V2VNetwork(link=LinkConfig(drop_rate=1.0))
    ex = lost.exchange(0, np.array([0, 1]), pose, own)
    assert not ex.received.any() and (ex.merged == own).all() and lost.stats.dropped == 2

    short = V2VNetwork(link=LinkConfig(range_m=15.0))
    assert not short.exchange(0, np.array([0, 1]), pose, own).received.any()
    assert short.stats.out_of_range == 2

    noisy = V2VNetwork(link=LinkConfig(pose_noise_m=0.5, pose_noise_deg=1.0), rng=np.random.default_rng(0))
    offsets = []
    for t in range(30):
        x, _ = occupied_xy(
            noisy.exchange(t, np.array([0, 1]), pose, own).merged[0, OccupancyClass.PEDESTRIAN]
        )
        offsets.extend(x - 30.25)
    assert 0.1 < np.std(offsets) < 1.5  # ~0.5 m (x noise) plus ~0.17 m of yaw lever arm


def test_occupancy_image_colours_classes_and_the_ego():
    snap = snapshot([(0, 0, 0, CAR, 4.9, 2.1), (20, 0, 0, CAR, 4.5, 1.9)])
    img = occupancy_to_rgb(grids(snap, [0]))
    assert img.shape == (1, 192, 128, 3) and img.dtype == np.uint8
    r, c = CFG.cell_of(np.array([20.0, 0.0]), np.array([0.0, 0.0]))
    assert tuple(img[0, r[0], c[0]]) == (70, 140, 255)  # vehicle blue
    assert tuple(img[0, r[1], c[1]]) == (80, 255, 120)  # ego green


def test_occupancy_image_draws_vehicles_over_people_over_static_and_leaves_the_rest_dark():
    grid = np.zeros((2, 4, *CFG.shape), bool)
    grid[0, OccupancyClass.STATIC, 10:20, 10:20] = True  # static alone, then each class stacked on it
    grid[0, OccupancyClass.CYCLIST, 12:20, 10:20] = True
    grid[0, OccupancyClass.PEDESTRIAN, 14:20, 10:20] = True
    grid[0, OccupancyClass.VEHICLE, 16:20, 10:20] = True
    img = occupancy_to_rgb(grid, ego=False)
    assert [tuple(img[0, r, 15]) for r in (10, 12, 14, 16, 30)] == [
        (150, 150, 150),  # static grey
        (255, 200, 40),  # cyclist amber over static
        (255, 80, 80),  # pedestrian red over both
        (70, 140, 255),  # vehicle blue over everything
        (20, 20, 24),  # background
    ]
    assert (img[1] == (20, 20, 24)).all()  # an empty grid is all background, no ego when ego=False


def test_fused_warp_and_merge_equals_warp_then_or():
    rng = np.random.default_rng(4)
    own = rng.random((3, 4, *CFG.shape)) < 0.03
    partner = rng.random((3, 4, *CFG.shape)) < 0.03
    pp, ep = rng.uniform(-20, 20, (3, 3)), rng.uniform(-20, 20, (3, 3))
    has = np.array([True, False, True])
    fused = warp_and_merge(own, partner, pp, ep, has)
    assert (fused == merge(own, warp_to_ego(partner, pp, ep), has)).all()
    assert (fused[1] == own[1]).all()
