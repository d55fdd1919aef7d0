"""The CAV kinematic bicycle model against textbook numbers: braking distance, turning radius, limits."""

from __future__ import annotations

import numpy as np
import pytest

from cmudrive.sim.dynamics import (
    CavState,
    ControlError,
    Controls,
    VehicleParams,
    step_bicycle,
    validate_controls,
)

DT = 0.05  # [s]
P = VehicleParams()


def state(n: int = 1, speed: float = 0.0) -> CavState:
    z = np.zeros(n)
    return CavState(
        x=z.copy(), y=z.copy(), yaw=z.copy(), speed=np.full(n, speed), steer_angle=z.copy(), accel=z.copy()
    )


def run(st: CavState, controls: Controls, seconds: float, friction: float = 1.0) -> list[CavState]:
    out = []
    for _ in range(round(seconds / DT)):
        st = step_bicycle(st, controls, P, DT, friction)
        out.append(st)
    return out


@pytest.mark.parametrize("friction", [1.0, 0.7])
def test_full_brake_from_50_kmh_stops_in_the_textbook_distance(friction: float) -> None:
    """v^2 / (2 a): 13.9 m/s at 8 m/s^2 stops in ~12 m on a dry road, ~17 m on a wet one (friction 0.7)."""
    v0 = 50 / 3.6
    traj = run(state(speed=v0), Controls(np.zeros(1), np.zeros(1), np.ones(1)), 5.0, friction)
    distance = traj[-1].x[0]
    ideal = v0**2 / (2 * P.max_brake * friction)
    assert traj[-1].speed[0] == 0.0
    assert ideal * 0.9 < distance < ideal * 1.05  # rolling resistance and drag shorten it a little


def test_full_throttle_accelerates_like_a_sedan_and_never_reverses() -> None:
    traj = run(state(), Controls(np.zeros(1), np.ones(1), np.zeros(1)), 20.0)
    v = np.array([s.speed[0] for s in traj])
    t_100 = (np.argmax(v >= 100 / 3.6) + 1) * DT
    assert 8.0 < t_100 < 14.0  # 0-100 km/h
    assert np.all(np.diff(v) >= 0)
    coast = run(state(speed=1.0), Controls(np.zeros(1), np.zeros(1), np.zeros(1)), 20.0)
    assert coast[-1].speed[0] == 0.0 and np.all([s.speed[0] >= 0 for s in coast])


def test_full_left_lock_at_walking_pace_drives_the_minimum_turning_circle() -> None:
    """CARLA's steer -1 is full left. At 2 m/s the reference point circles with radius
    sqrt(lr^2 + (L / tan(delta))^2) ~ 4.3 m, counter-clockwise."""
    st = state(speed=2.0)
    controls = Controls(-np.ones(1), np.zeros(1), np.zeros(1))
    xy = []
    for _ in range(400):
        st = step_bicycle(st, controls, P, DT)
        st = CavState(st.x, st.y, st.yaw, np.full(1, 2.0), st.steer_angle, st.accel)  # hold 2 m/s
        xy.append((st.x[0], st.y[0]))
    xy = np.array(xy[100:])
    centre = xy.mean(axis=0)
    radius = np.linalg.norm(xy - centre, axis=1)
    expected = np.hypot(P.rear_to_cg, P.wheelbase / np.tan(P.max_steer))
    assert radius.mean() == pytest.approx(expected, rel=0.03)
    assert centre[1] > 0  # turning left from heading east: the centre lies to the north


def test_steering_is_rate_and_grip_limited() -> None:
    slow = step_bicycle(state(speed=5.0), Controls(np.ones(1), np.zeros(1), np.zeros(1)), P, DT)
    assert abs(slow.steer_angle[0]) == pytest.approx(P.steer_rate * DT)  # one step of the actuator rate
    st = state(speed=30.0)
    for _ in range(40):
        st = step_bicycle(st, Controls(np.ones(1), np.zeros(1), np.zeros(1)), P, DT)
    lateral = st.speed[0] ** 2 * np.tan(abs(st.steer_angle[0])) / P.wheelbase
    assert lateral <= P.max_lateral_accel * 1.01  # full lock at 30 m/s is limited by grip


def test_vectorised_over_cavs_equals_one_by_one() -> None:
    rng = np.random.default_rng(0)
    n = 16
    st = CavState(
        rng.uniform(0, 100, n),
        rng.uniform(0, 100, n),
        rng.uniform(-3, 3, n),
        rng.uniform(0, 15, n),
        np.zeros(n),
        np.zeros(n),
    )
    c = Controls(rng.uniform(-1, 1, n), rng.uniform(0, 1, n), rng.uniform(0, 1, n))
    together = step_bicycle(st, c, P, DT)
    for i in range(n):
        one = step_bicycle(
            CavState(*(getattr(st, f)[i : i + 1] for f in CavState.__dataclass_fields__)),
            Controls(c.steer[i : i + 1], c.throttle[i : i + 1], c.brake[i : i + 1]),
            P,
            DT,
        )
        assert one.x[0] == together.x[i] and one.yaw[0] == together.yaw[i]


def test_validate_controls_rejects_non_finite_and_clips_out_of_range() -> None:
    with pytest.raises(ControlError, match="CAV b: steer is inf"):
        validate_controls(Controls(np.array([0.0, np.inf]), np.zeros(2), np.zeros(2)), ["a", "b"])
    check = validate_controls(Controls(np.array([-2.0, 0.5]), np.array([0.3, 1.5]), np.zeros(2)), ["a", "b"])
    assert check.controls.steer.tolist() == [-1.0, 0.5] and check.controls.throttle.tolist() == [0.3, 1.0]
    assert check.clipped.tolist() == [True, True]
