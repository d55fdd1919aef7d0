"""The occupancy safety brake: a CAV brakes for what lies on its own path within its stopping distance,
and for nothing beside the path, behind a bend it does not take, or its own box."""

from __future__ import annotations

import numpy as np
import pytest

from cmudrive.agents.shield import SafetyBrake
from cmudrive.sensors.occupancy import OccupancyClass, OccupancyConfig

CONFIG = OccupancyConfig()


def grid_with(*boxes: tuple[float, float, float, float, OccupancyClass]) -> np.ndarray:
    """(1, C, H, W): axis-aligned boxes (centre x, centre y, length, width [m], class) in the ego frame."""
    grid = np.zeros((1, 4, *CONFIG.shape), bool)
    xs, ys = CONFIG.cell_centres()
    for x, y, length, width, cls in boxes:
        grid[0, cls] |= (np.abs(xs - x)[:, None] < length / 2) & (np.abs(ys - y)[None, :] < width / 2)
    return grid


STRAIGHT = np.stack([np.arange(20.0), np.zeros(20)], axis=1)[None]  # 1 m apart, from the centre
THETA = np.arange(20.0) / 15.0
LEFT_BEND = np.stack([15 * np.sin(THETA), 15 * (1 - np.cos(THETA))], axis=1)[None]  # radius 15 m


def car_ahead(gap: float, y: float = 0.0) -> np.ndarray:
    """A 4.6 m car whose rear is ``gap`` m ahead of the ego's front bumper (2.45 m from its centre)."""
    return grid_with((2.45 + gap + 2.3, y, 4.6, 1.9, OccupancyClass.VEHICLE))


def test_the_stopping_distance_grows_with_the_square_of_the_speed() -> None:
    brake = SafetyBrake()
    d = brake.stopping_distance(np.array([0.0, 10.0]))
    assert d[0] == pytest.approx(brake.gap)
    assert d[1] == pytest.approx(brake.gap + 10 * brake.reaction + 100 / (2 * brake.decel))  # 14.0 m


@pytest.mark.parametrize(
    ("speed", "gap", "brakes"),
    [
        (8.0, 6.0, True),  # stopping distance 9.9 m at 8 m/s: a car 6 m ahead is too close
        (8.0, 15.0, False),  # 15 m ahead: room to brake later
        (0.0, 1.0, True),  # standing 1 m behind a car: stay
        (0.0, 5.0, False),  # standing 5 m behind: may move up
    ],
)
def test_a_car_in_the_lane_brakes_within_the_stopping_distance(
    speed: float, gap: float, brakes: bool
) -> None:
    assert SafetyBrake()(car_ahead(gap), STRAIGHT, np.array([speed])).tolist() == [brakes]


def test_the_clearance_reads_the_gap_to_within_the_corridor_half_width() -> None:
    brake = SafetyBrake()
    clearance = brake.clearance(car_ahead(8.0), STRAIGHT, np.array([30.0]))[0]
    assert 8.0 - brake.half_width - CONFIG.resolution <= clearance <= 8.0


def test_nothing_beside_the_path_behind_an_untaken_bend_or_in_the_own_box_brakes() -> None:
    brake = SafetyBrake()
    fast = np.array([12.0])
    assert not brake(car_ahead(6.0, y=3.5), STRAIGHT, fast)[0]  # the next lane, 3.5 m to the left
    assert not brake(car_ahead(12.0), LEFT_BEND, fast)[0]  # straight ahead of a left bend
    own = grid_with((0.0, 0.0, 4.9, 2.1, OccupancyClass.VEHICLE))  # the partner's view of the ego itself
    assert np.isinf(brake.clearance(own, STRAIGHT, np.array([30.0])))[0]
    x, y = LEFT_BEND[0, 10]
    on_bend = grid_with((x, y, 0.6, 0.6, OccupancyClass.PEDESTRIAN))  # on the bend, 10 m along it
    assert brake(on_bend, LEFT_BEND, fast)[0]


def test_a_short_path_is_continued_straight() -> None:
    short = STRAIGHT[:, :5]  # 4 m of path: the car 10 m ahead of the bumper is still found
    assert SafetyBrake().clearance(car_ahead(10.0), short, np.array([30.0]))[0] < 10.0


@pytest.mark.parametrize(
    ("y", "static_half_width", "brakes"),
    [
        (-0.25, 1.1, True),  # a cone in the lane, 8 m ahead at 10 m/s
        (-1.25, 1.1, False),  # a pole in the cell 1.25 m right of the path (the CAV's side: 1.05 m)
        (-1.25, 1.4, True),  # ... inside the road users' wider corridor
        (-0.25, None, False),  # the static class not checked
    ],
)
def test_static_objects_have_a_corridor_of_the_cars_own_width(
    y: float, static_half_width: float | None, brakes: bool
) -> None:
    pole = grid_with((10.25, y, 0.4, 0.4, OccupancyClass.STATIC))  # one cell, 7.8 m ahead of the bumper
    brake = SafetyBrake(static_half_width=static_half_width)
    assert brake(pole, STRAIGHT, np.array([10.0])).tolist() == [brakes]


def test_each_cav_reads_its_own_grid_and_bad_input_is_refused() -> None:
    grids = np.concatenate([car_ahead(3.0), grid_with()])
    paths = np.concatenate([STRAIGHT, STRAIGHT])
    assert SafetyBrake()(grids, paths, np.array([5.0, 5.0])).tolist() == [True, False]
    with pytest.raises(ValueError, match="2 grids for 1 paths"):
        SafetyBrake()(grids, STRAIGHT, np.array([5.0]))
    with pytest.raises(ValueError, match="decel must be positive"):
        SafetyBrake(decel=0.0)
    with pytest.raises(ValueError, match="its own corridor"):
        SafetyBrake(classes=(OccupancyClass.VEHICLE, OccupancyClass.STATIC))
