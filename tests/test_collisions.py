"""Oriented-box collisions: named hand-built scenes, edge cases at 1 cm, and randomized cross-checks."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cmudrive.sim.collisions import CollisionEvents, detect_collisions
from cmudrive.sim.snapshot import ActorKind, Role, Snapshot

CAR_LENGTH, CAR_WIDTH = 4.5, 1.9  # [m]


def scene(**columns: object) -> Snapshot:
    return Snapshot.from_rows(0, 0.0, np.array([], str), **{k: np.asarray(v) for k, v in columns.items()})


def pair_at(offset_long: float, offset_lat: float, heading: float, rel_yaw: float = 0.0) -> Snapshot:
    """Car A at (10, -5) heading ``heading``; car B offset by (long, lat) in A's frame, yawed by rel_yaw."""
    ax, ay = 10.0, -5.0
    c, s = math.cos(heading), math.sin(heading)
    bx, by = ax + offset_long * c - offset_lat * s, ay + offset_long * s + offset_lat * c
    return scene(x=[ax, bx], y=[ay, by], yaw=[heading, heading + rel_yaw])


def pair_keys(events: CollisionEvents) -> list[tuple[int, int]]:
    return list(zip(events.a.tolist(), events.b.tolist(), strict=True))


# ---- named scenes -----------------------------------------------------------------------------------


def test_overlapping_cars_collide_with_penetration_and_contact_point() -> None:
    snap = scene(x=[0.0, 3.5], y=[0.0, 0.0])  # 1 m nose-to-tail overlap
    events = detect_collisions(snap)
    assert pair_keys(events) == [(0, 1)]
    assert events.id_a.tolist() == ["a0"] and events.id_b.tolist() == ["a1"]
    assert events.penetration[0] == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(events.point[0], [1.75, 0.0], atol=1e-12)  # middle of the overlap strip


HEADINGS = [0.0, math.radians(30.0), math.radians(45.0), math.radians(-120.0)]


@pytest.mark.parametrize("heading", HEADINGS)
@pytest.mark.parametrize("arrangement", ["nose_to_tail", "side_by_side"])
@pytest.mark.parametrize("gap", [0.01, -0.01])  # [m] 1 cm apart / 1 cm overlap
def test_one_centimetre_decides(heading: float, arrangement: str, gap: float) -> None:
    if arrangement == "nose_to_tail":
        snap = pair_at(CAR_LENGTH + gap, 0.0, heading)
    else:
        snap = pair_at(0.0, CAR_WIDTH + gap, heading)
    events = detect_collisions(snap)
    if gap > 0:
        assert len(events) == 0
    else:
        assert pair_keys(events) == [(0, 1)]
        assert events.penetration[0] == pytest.approx(-gap, abs=1e-9)


@pytest.mark.parametrize("heading", HEADINGS)
@pytest.mark.parametrize("rel_yaw_deg", [30.0, 45.0, 90.0])
@pytest.mark.parametrize("gap", [0.01, -0.01])
def test_rotated_corner_one_centimetre_from_front_face(
    heading: float, rel_yaw_deg: float, gap: float
) -> None:
    rel = math.radians(rel_yaw_deg)
    reach = 0.5 * CAR_LENGTH * abs(math.cos(rel)) + 0.5 * CAR_WIDTH * abs(math.sin(rel))  # B's corner [m]
    snap = pair_at(0.5 * CAR_LENGTH + reach + gap, 0.3, heading, rel)
    events = detect_collisions(snap)
    assert len(events) == (0 if gap > 0 else 1)
    if gap < 0:
        assert events.penetration[0] == pytest.approx(-gap, abs=1e-9)


def test_penetration_is_the_push_that_separates_even_when_contained() -> None:
    # a pedestrian standing wholly inside a bus's box: pushing it out sideways takes 1.25 + 0.25 m
    snap = scene(x=[0.0, 1.0], y=[0.0, 0.0], length=[12.0, 0.5], width=[2.5, 0.5])
    events = detect_collisions(snap)
    assert events.penetration[0] == pytest.approx(1.5)
    np.testing.assert_allclose(events.point[0], [1.0, 0.0], atol=1e-12)


def test_touching_exactly_is_not_a_collision() -> None:
    snap = scene(x=[0.0, 4.0, 0.0], y=[0.0, 0.0, 2.0], length=[4.0, 4.0, 4.0], width=[2.0, 2.0, 2.0])
    assert len(detect_collisions(snap)) == 0  # flush nose-to-tail and flush side-by-side


def test_pedestrian_touching_car_front_collides_and_reports_kinds() -> None:
    # pedestrian 0.5 m box whose back overlaps the car's front bumper by 5 cm
    snap = scene(
        x=[0.0, 0.5 * CAR_LENGTH + 0.25 - 0.05],
        y=[0.0, 0.4],
        kind=np.array([ActorKind.CAR, ActorKind.PEDESTRIAN], np.int8),
        role=np.array([Role.CAV, Role.BACKGROUND], np.int8),
        length=[CAR_LENGTH, 0.5],
        width=[CAR_WIDTH, 0.5],
        speed=[5.0, 1.2],
        yaw=[0.0, math.pi / 2],
    )
    events = detect_collisions(snap)
    assert pair_keys(events) == [(0, 1)]
    assert events.kind_a[0] == ActorKind.CAR and events.kind_b[0] == ActorKind.PEDESTRIAN
    assert events.role_a[0] == Role.CAV and events.role_b[0] == Role.BACKGROUND
    assert events.penetration[0] == pytest.approx(0.05, abs=1e-9)
    assert events.point[0, 0] == pytest.approx(0.5 * CAR_LENGTH - 0.025, abs=1e-9)
    assert events.relative_speed[0] == pytest.approx(math.hypot(5.0, 1.2))


def test_static_prop_collides_like_any_actor() -> None:
    snap = scene(
        x=[0.0, 2.4],
        y=[0.0, 0.0],
        kind=np.array([ActorKind.CAR, ActorKind.PROP], np.int8),
        role=np.array([Role.CAV, Role.PROP], np.int8),
        length=[CAR_LENGTH, 0.4],
        width=[CAR_WIDTH, 0.4],
    )
    events = detect_collisions(snap)
    assert pair_keys(events) == [(0, 1)] and events.kind_b[0] == ActorKind.PROP


def test_relative_speed_rear_end_and_head_on() -> None:
    rear_end = scene(x=[0.0, 4.0], y=[0.0, 0.0], speed=[10.0, 0.0])
    assert detect_collisions(rear_end).relative_speed[0] == pytest.approx(10.0)
    head_on = scene(x=[0.0, 4.0], y=[0.0, 0.0], yaw=[0.0, math.pi], speed=[10.0, 10.0])
    assert detect_collisions(head_on).relative_speed[0] == pytest.approx(20.0)
    side = scene(x=[0.0, 3.0], y=[0.0, 0.5], yaw=[0.0, math.pi / 2], speed=[3.0, 4.0])
    assert detect_collisions(side).relative_speed[0] == pytest.approx(5.0)


def test_active_mask_keeps_pairs_with_an_active_actor() -> None:
    # pairs (0, 1) and (2, 3) overlap, far apart from each other
    snap = scene(x=[0.0, 3.0, 100.0, 103.0], y=[0.0, 0.0, 0.0, 0.0])
    assert pair_keys(detect_collisions(snap)) == [(0, 1), (2, 3)]
    assert pair_keys(detect_collisions(snap, np.array([False, False, False, True]))) == [(2, 3)]
    assert pair_keys(detect_collisions(snap, np.array([True, False, True, False]))) == [(0, 1), (2, 3)]
    assert len(detect_collisions(snap, np.zeros(4, bool))) == 0
    with pytest.raises(ValueError, match="active"):
        detect_collisions(snap, np.ones(3, bool))


def test_invalid_rows_are_ignored_and_non_finite_valid_rows_rejected() -> None:
    snap = scene(x=[0.0, 3.0, np.nan], y=[0.0, 0.0, 0.0], valid=[True, False, False])
    assert len(detect_collisions(snap)) == 0
    bad = scene(x=[0.0, np.nan], y=[0.0, 0.0])
    with pytest.raises(ValueError, match="a1"):
        detect_collisions(bad)


@pytest.mark.parametrize("n", [0, 1])
def test_zero_and_one_actor_give_no_events(n: int) -> None:
    events = detect_collisions(scene(x=np.zeros(n), y=np.zeros(n)))
    assert len(events) == 0
    assert events.a.shape == (0,) and events.point.shape == (0, 2) and events.penetration.shape == (0,)


# ---- randomized cross-checks ------------------------------------------------------------------------


def random_boxes(n: int, seed: int, side: float = 60.0) -> Snapshot:
    """n boxes of mixed actor sizes (pedestrian to bus) in a side x side [m] square: many overlaps."""
    rng = np.random.default_rng(seed)
    sizes = np.array([[0.5, 0.5], [1.8, 0.7], [4.5, 1.9], [5.2, 2.1], [12.0, 2.5], [0.4, 0.4]])
    pick = rng.integers(0, len(sizes), n)
    return scene(
        x=rng.uniform(0.0, side, n),
        y=rng.uniform(0.0, side, n),
        yaw=rng.uniform(-math.pi, math.pi, n),
        speed=rng.uniform(0.0, 15.0, n),
        length=sizes[pick, 0],
        width=sizes[pick, 1],
        valid=rng.random(n) > 0.05,
    )


def reference_penetration(corners_a: np.ndarray, corners_b: np.ndarray) -> float:
    """Per-pair SAT from corner projections on the edge normals of both boxes (a generic polygon SAT):
    the smallest push, over the axes and both directions, that separates the boxes [m]."""
    best = math.inf
    for poly in (corners_a, corners_b):
        for k in range(4):
            edge = poly[(k + 1) % 4] - poly[k]
            axis = np.array([-edge[1], edge[0]]) / math.hypot(edge[0], edge[1])
            pa, pb = corners_a @ axis, corners_b @ axis
            best = min(best, pa.max() - pb.min(), pb.max() - pa.min())
    return best


def cross(u: np.ndarray, v: np.ndarray) -> float:
    return float(u[0] * v[1] - u[1] * v[0])


def clip_polygon(subject: list[np.ndarray], clipper: np.ndarray) -> list[np.ndarray]:
    """Sutherland-Hodgman clip of a polygon by a convex polygon (counter-clockwise or clockwise)."""
    orient = np.sign(cross(clipper[1] - clipper[0], clipper[2] - clipper[1]))
    out = subject
    for k in range(len(clipper)):
        p, q = clipper[k], clipper[(k + 1) % len(clipper)]
        side = [orient * cross(q - p, v - p) for v in out]
        kept: list[np.ndarray] = []
        for m in range(len(out)):
            v, w, sv, sw = out[m], out[(m + 1) % len(out)], side[m], side[(m + 1) % len(out)]
            if sv >= 0:
                kept.append(v)
            if (sv >= 0) != (sw >= 0):
                kept.append(v + (w - v) * (sv / (sv - sw)))
        out = kept
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_matches_brute_force_pairwise_sat_on_200_boxes(seed: int) -> None:
    snap = random_boxes(200, seed)
    events = detect_collisions(snap)
    corners = snap.corners()
    # every valid pair except those whose bounding circles are more than 1 m apart (cannot overlap)
    half_diagonal = 0.5 * np.hypot(snap.length, snap.width)
    distance = np.linalg.norm(snap.xy[:, None, :] - snap.xy[None, :, :], axis=-1)
    maybe = distance <= half_diagonal[:, None] + half_diagonal[None, :] + 1.0
    maybe &= snap.valid[:, None] & snap.valid[None, :]
    expected: dict[tuple[int, int], float] = {}
    for a, b in zip(*np.nonzero(np.triu(maybe, k=1)), strict=True):
        pen = reference_penetration(corners[a], corners[b])
        if pen > 1e-9:
            expected[(int(a), int(b))] = pen
    assert len(expected) > 20  # the scene really exercises the narrow phase
    assert pair_keys(events) == sorted(expected)
    np.testing.assert_allclose(events.penetration, [expected[k] for k in pair_keys(events)], atol=1e-9)
    for e, (a, b) in enumerate(pair_keys(events)):
        overlap = clip_polygon(list(corners[a]), corners[b])
        np.testing.assert_allclose(events.point[e], np.mean(overlap, axis=0), atol=1e-6)
    speed_a = snap.speed[events.a] * np.stack([np.cos(snap.yaw[events.a]), np.sin(snap.yaw[events.a])])
    speed_b = snap.speed[events.b] * np.stack([np.cos(snap.yaw[events.b]), np.sin(snap.yaw[events.b])])
    np.testing.assert_allclose(events.relative_speed, np.linalg.norm(speed_a - speed_b, axis=0))


@pytest.mark.parametrize("seed", [3, 4])
def test_matches_shapely_polygons(seed: int) -> None:
    geometry = pytest.importorskip("shapely.geometry")
    snap = random_boxes(200, seed)
    events = detect_collisions(snap)
    corners = snap.corners()
    polys = [geometry.Polygon(c) for c in corners]
    expected = set()
    for a in range(snap.num_actors):
        for b in range(a + 1, snap.num_actors):
            if snap.valid[a] and snap.valid[b] and polys[a].intersection(polys[b]).area > 1e-9:
                expected.add((a, b))
    assert pair_keys(events) == sorted(expected)
    for e, (a, b) in enumerate(pair_keys(events)):
        assert polys[a].intersection(polys[b]).buffer(1e-6).contains(geometry.Point(events.point[e]))


def test_order_is_deterministic_and_independent_of_row_order() -> None:
    snap = random_boxes(150, seed=7)
    first, second = detect_collisions(snap), detect_collisions(snap)
    assert np.array_equal(first.a, second.a) and np.array_equal(first.b, second.b)
    keys = pair_keys(first)
    assert keys == sorted(keys) and all(a < b for a, b in keys)
    perm = np.random.default_rng(0).permutation(snap.num_actors)
    shuffled = snap.select(perm)  # fancy indexing reorders every per-actor array
    ids = {frozenset(p) for p in zip(first.id_a.tolist(), first.id_b.tolist(), strict=True)}
    got = detect_collisions(shuffled)
    assert {frozenset(p) for p in zip(got.id_a.tolist(), got.id_b.tolist(), strict=True)} == ids
