"""CAV dynamics: a kinematic bicycle model driven by CARLA-style controls, vectorised over CAVs.

Why our own model rather than SUMO's: SUMO moves vehicles along lanes (longitudinal car-following plus
lane changes); it has no steering. An agent under test outputs CARLA controls, so CAVs need a model that
turns steer/throttle/brake into a free 2D motion that can leave its lane, cut corners or hit the kerb.
The kinematic bicycle model (reference point at the centre of the bounding box, slip angle from the
rear-axle geometry) is the standard choice at urban speeds, and cheap enough to vectorise.

Controls follow CARLA's ``VehicleControl`` convention: ``steer`` in [-1, 1] with **+1 = full right**,
``throttle`` and ``brake`` in [0, 1]. There is no reverse gear: speed never drops below 0.

Policy for bad controls: a control that is not one number per CAV (strings, objects, ragged lists,
the wrong shape) or holds NaN or infinity raises :class:`ControlError` naming the control and, for a bad
value, the CAV (``check_controls``; the evaluator calls it on what ``run_step`` returns, before anything
of ours touches the controls, and records the route as "Agent crashed"); finite values outside their
range are clipped and reported per CAV in ``ControlCheck.clipped`` so that runs can log them
(``validate_controls``, the world's step; CARLA's ``VehicleControl`` clamps too). Nothing non-finite
ever reaches the state.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numba
import numpy as np

GRAVITY = 9.81  # [m/s^2]


class ControlError(ValueError):
    """Controls that cannot be applied (NaN or infinite); the message names the CAV."""


@dataclass(frozen=True)
class VehicleParams:
    """Limits of the CAV model (defaults: a mid-size sedan like CARLA's Lincoln MKZ 2020)."""

    wheelbase: float = 2.875  # [m]
    rear_to_cg: float = 1.44  # [m] rear axle to the bounding-box centre (about half the wheelbase)
    max_steer: float = np.radians(35.0)  # [rad] front wheel angle at |steer| = 1
    steer_rate: float = np.radians(120.0)  # [rad/s] how fast the front wheels can turn
    max_accel: float = 4.0  # [m/s^2] full throttle from standstill (0-100 km/h in ~9 s)
    max_speed: float = 45.0  # [m/s] top speed; full-throttle acceleration fades to 0 there
    max_brake: float = 8.0  # [m/s^2] full brake on a dry road (scaled by the weather's friction)
    rolling: float = 0.15  # [m/s^2] rolling resistance
    drag: float = 4.0e-4  # [1/m] aerodynamic drag coefficient: decel = drag * v^2
    max_lateral_accel: float = 0.9 * GRAVITY  # [m/s^2] on a dry road; steering is limited so v^2 / R <= this


@dataclass(frozen=True)
class CavState:
    """State of ``n`` CAVs; every field has shape (n,)."""

    x: np.ndarray  # [m] bounding-box centre
    y: np.ndarray  # [m]
    yaw: np.ndarray  # [rad] counter-clockwise from +x
    speed: np.ndarray  # [m/s] >= 0
    steer_angle: np.ndarray  # [rad] current front wheel angle, + = left
    accel: np.ndarray  # [m/s^2] longitudinal acceleration in the last step


@dataclass(frozen=True)
class Controls:
    """CARLA-style controls for ``n`` CAVs, arrays of shape (n,)."""

    steer: np.ndarray  # [-1, 1], + = right
    throttle: np.ndarray  # [0, 1]
    brake: np.ndarray  # [0, 1]

    @staticmethod
    def zeros(n: int) -> Controls:
        return Controls(np.zeros(n), np.zeros(n), np.zeros(n))


@dataclass(frozen=True)
class ControlCheck:
    controls: Controls  # finite and in range
    clipped: np.ndarray  # (n,) bool, some value of that CAV was out of range and clipped


_CONTROL_NAMES = ("steer", "throttle", "brake")
_CONTROL_LOW = (-1.0, 0.0, 0.0)  # lower limits, in _CONTROL_NAMES order
_CONTROL_HIGH = (1.0, 1.0, 1.0)


_NUMERIC_KINDS = "biuf"  # numpy dtype kinds a control may be made of: bool, integers, floats


def _control_values(controls: Controls, cav_ids: list[str] | np.ndarray) -> list[np.ndarray]:
    """The three controls as float64 arrays, one value per CAV of ``cav_ids``; ControlError naming the
    control and the CAVs when one is not that many numbers (strings, objects, a ragged list, a shape)."""
    n = len(cav_ids)
    cavs = ", ".join(str(c) for c in cav_ids[:4]) + (", ..." if n > 4 else "")
    values = []
    for name in _CONTROL_NAMES:
        raw = getattr(controls, name)
        try:
            value = np.asarray(raw)
        except (ValueError, TypeError) as exc:  # ragged nested lists and the like
            raise ControlError(f"{name} is not an array of numbers ({exc}) (CAVs {cavs})") from exc
        if value.dtype.kind not in _NUMERIC_KINDS:
            shown = repr(raw) if len(repr(raw)) <= 60 else repr(raw)[:57] + "..."
            raise ControlError(
                f"{name} is {shown} of dtype {value.dtype}: controls must be numbers (CAVs {cavs})"
            )
        if value.shape != (n,):
            raise ControlError(
                f"{name} has shape {value.shape}, expected ({n},): one value per active CAV ({cavs})"
            )
        values.append(value.astype(np.float64, copy=False))
    return values


def check_controls(controls: Controls, cav_ids: list[str] | np.ndarray) -> Controls:
    """The controls as float64 arrays, one value per CAV of ``cav_ids``, or ControlError naming the
    control and the CAV: not numbers, the wrong shape, NaN or infinite. Out-of-range values pass (the
    world's step clips and reports them)."""
    values = _control_values(controls, cav_ids)
    for name, value in zip(_CONTROL_NAMES, values, strict=True):
        bad = np.flatnonzero(~np.isfinite(value))
        if len(bad):
            i = int(bad[0])
            raise ControlError(f"CAV {cav_ids[i]}: {name} is {value[i]} (controls must be finite)")
    return Controls(values[0], values[1], values[2])


def validate_controls(controls: Controls, cav_ids: list[str] | np.ndarray) -> ControlCheck:
    """Reject controls that are not finite numbers (naming the CAV) and clip out-of-range ones
    (reported)."""
    values = _control_values(controls, cav_ids)
    fixed, clipped, finite = _clip_controls(*values)  # one compiled loop: ~1 us instead of ~8 numpy calls
    if not finite:
        for name, value in zip(_CONTROL_NAMES, values, strict=True):
            bad = np.flatnonzero(~np.isfinite(value))
            if len(bad):
                i = int(bad[0])
                raise ControlError(f"CAV {cav_ids[i]}: {name} is {value[i]} (controls must be finite)")
    return ControlCheck(Controls(fixed[0], fixed[1], fixed[2]), clipped)


@numba.njit(cache=True)
def _clip_controls(
    steer: np.ndarray, throttle: np.ndarray, brake: np.ndarray
) -> tuple[np.ndarray, np.ndarray, bool]:
    """(3, n) controls clipped to their ranges, (n,) whether a CAV's were clipped, and whether all are
    finite (when not, the other two are meaningless)."""
    n = steer.shape[0]
    fixed, clipped = np.empty((3, n)), np.zeros(n, np.bool_)
    for k, value in enumerate((steer, throttle, brake)):
        low, high = _CONTROL_LOW[k], _CONTROL_HIGH[k]
        for i in range(n):
            v = value[i]
            if not np.isfinite(v):
                return fixed, clipped, False
            fixed[k, i] = min(max(v, low), high)
            clipped[i] |= fixed[k, i] != v
    return fixed, clipped, True


def step_bicycle(
    state: CavState, controls: Controls, params: VehicleParams, dt: float, friction: float = 1.0
) -> CavState:
    """Advance all CAVs by ``dt`` seconds. ``controls`` must already be validated.

    One compiled loop over the CAVs (numba): numpy's ~40 operations on 16-element arrays cost ~30 us
    per tick, the loop ~2 us."""
    out = _bicycle(
        state.x,
        state.y,
        state.yaw,
        state.speed,
        state.steer_angle,
        np.asarray(controls.steer, np.float64),
        np.asarray(controls.throttle, np.float64),
        np.asarray(controls.brake, np.float64),
        _param_array(params),
        dt,
        friction,
    )  # (6, n): x, y, yaw, speed, steer_angle, accel
    return CavState(*out)


@cache
def _param_array(p: VehicleParams) -> np.ndarray:
    """The parameters in the order ``_bicycle`` reads them (read-only, made once per VehicleParams)."""
    array = np.array(
        [
            p.wheelbase,
            p.rear_to_cg,
            p.max_steer,
            p.steer_rate,
            p.max_accel,
            p.max_speed,
            p.max_brake,
            p.rolling,
            p.drag,
            p.max_lateral_accel,
        ]
    )
    array.flags.writeable = False
    return array


@numba.njit(cache=True)
def _bicycle(
    x0: np.ndarray,
    y0: np.ndarray,
    yaw0: np.ndarray,
    v0: np.ndarray,
    steer_angle0: np.ndarray,
    steer: np.ndarray,
    throttle: np.ndarray,
    brake_input: np.ndarray,
    params: np.ndarray,
    dt: float,
    friction: float,
) -> np.ndarray:
    """(6, n) new x, y, yaw, speed, steer angle, accel of n CAVs; ``params`` in VehicleParams order."""
    wheelbase, rear_to_cg, max_steer, steer_rate = params[0], params[1], params[2], params[3]
    max_accel, max_speed, max_brake, rolling, drag, max_lat = params[4:10]
    out = np.empty((6, x0.shape[0]))
    for i in range(x0.shape[0]):
        v = v0[i]
        # longitudinal: throttle force fades with speed; brake scaled by road friction; resistances oppose
        # motion
        drive = throttle[i] * max_accel * min(max(1.0 - (v / max_speed) ** 2, 0.0), 1.0)
        resist = rolling + drag * v**2 if v > 0.0 else 0.0
        brake = brake_input[i] * max_brake * friction
        v_new = max(v + (drive - resist - brake) * dt, 0.0)  # brakes and drag stop the car, never reverse it
        # lateral: target wheel angle (CARLA: + steer = right = clockwise, i.e. negative in our frame),
        # limited by the actuator rate and by the grip available at this speed
        target = -steer[i] * max_steer
        v_mid = 0.5 * (v + v_new)
        grip_limit = np.arctan(wheelbase * max_lat * friction / max(v_mid, 1e-3) ** 2)
        target = min(max(target, -grip_limit), grip_limit)
        max_change = steer_rate * dt
        delta = steer_angle0[i] + min(max(target - steer_angle0[i], -max_change), max_change)
        beta = np.arctan(rear_to_cg / wheelbase * np.tan(delta))  # slip angle at the reference point
        yaw_rate = v_mid / rear_to_cg * np.sin(beta)
        yaw_mid = yaw0[i] + 0.5 * yaw_rate * dt
        out[0, i] = x0[i] + v_mid * np.cos(yaw_mid + beta) * dt
        out[1, i] = y0[i] + v_mid * np.sin(yaw_mid + beta) * dt
        out[2, i] = (yaw0[i] + yaw_rate * dt + np.pi) % (2.0 * np.pi) - np.pi
        out[3, i] = v_new
        out[4, i] = delta
        out[5, i] = (v_new - v) / dt
    return out
