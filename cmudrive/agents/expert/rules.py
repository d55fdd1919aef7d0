"""The expert's speed rules: IDM toward each relevant object, and the kind of object found in the route
corridor ahead (``cmudrive.agents.corridor``).

IDM (Treiber's intelligent driver model) gives, for the object ahead at gap ``s`` moving at ``v_lead``::

    a = a_max * (1 - (v / v0)^4 - (s* / s)^2),  s* = s0 + v T + v (v - v_lead) / (2 sqrt(a_max b))

with the per-kind minimum gap ``s0`` and headway ``T`` of PDM-Lite (``reference/MODEL_AND_EXPERT.md``).
PDM-Lite's a_max = 24 m/s^2 and b = 3.72-8.7 m/s^2 are tuned to saturate CARLA's own controller; our
expert commands the acceleration through a speed controller that tracks it, so it uses physical values
(``IdmConfig``): it starts braking early enough to stop on a wet road (friction 0.7, 5.6 m/s^2 at most).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from cmudrive.sim.snapshot import ActorKind


class Reason(IntEnum):
    """Why the expert drives slower than the road allows (the rule that set its acceleration)."""

    NONE = 0  # cruising at the speed the road allows
    ROAD = 1  # speed limit, curve or junction cap ahead
    LEADING_VEHICLE = 2
    BICYCLE = 3
    PEDESTRIAN = 4
    OBSTACLE = 5  # a static prop or standing scenario obstacle in the corridor
    RED_LIGHT = 6
    YELLOW_LIGHT = 7
    STOP_SIGN = 8
    YIELD = 9  # giving way at a junction to a vehicle with priority
    FORECAST = 10  # a predicted collision within the forecast horizon
    DETOUR_WAIT = 11  # waiting for a gap before going around an obstacle


@dataclass(frozen=True)
class IdmGap:
    s0: float  # [m] minimum gap, bumper to object
    headway: float  # [s]


# the per-kind gaps of PDM-Lite's table
GAPS: dict[Reason, IdmGap] = {
    Reason.LEADING_VEHICLE: IdmGap(4.0, 0.25),
    Reason.BICYCLE: IdmGap(4.0, 0.25),
    Reason.PEDESTRIAN: IdmGap(4.0, 0.1),
    Reason.OBSTACLE: IdmGap(4.0, 0.25),
    Reason.RED_LIGHT: IdmGap(6.0, 0.1),
    Reason.YELLOW_LIGHT: IdmGap(6.0, 0.1),
    Reason.STOP_SIGN: IdmGap(2.0, 0.1),
    Reason.YIELD: IdmGap(2.0, 0.1),
    Reason.FORECAST: IdmGap(2.0, 0.1),
    Reason.DETOUR_WAIT: IdmGap(1.0, 0.1),  # to the detour's stop point (CAV centre), not to an object
}


@dataclass(frozen=True)
class IdmConfig:
    max_accel: float = 2.5  # [m/s^2] a_max
    comfort_decel: float = 3.0  # [m/s^2] b
    exponent: float = 4.0  # delta


def idm(
    v: np.ndarray,
    v0: np.ndarray,
    gap: np.ndarray,
    v_lead: np.ndarray,
    s0: float,
    headway: float,
    c: IdmConfig,
) -> np.ndarray:
    """(n,) IDM acceleration [m/s^2] toward an object ``gap`` metres ahead (bumper to object)."""
    s_star = s0 + np.maximum(
        v * headway + v * (v - v_lead) / (2.0 * np.sqrt(c.max_accel * c.comfort_decel)), 0.0
    )
    free = 1.0 - (v / np.maximum(v0, 0.1)) ** c.exponent
    return c.max_accel * (free - (s_star / np.maximum(gap, 0.1)) ** 2)


def allowed_speed(
    gap: np.ndarray, v_object: np.ndarray, s0: float, headway: float, decel: float
) -> np.ndarray:
    """(n,) [m/s] the speed a rule allows now, whatever the CAV's own speed: the highest speed from which
    braking at ``decel`` [m/s^2] brings the CAV down to the object's speed ``v_object`` [m/s] (0 for
    stop lines) by the time the ``gap`` [m] has shrunk to ``s0 + v_object * headway``. It is the
    target of a learned model's speed query (``ExpertDecision.desired_speed``): unlike the expert's
    acceleration-limited ``target_speed``, it does not follow the CAV's speed, so a model that reads its
    speed cannot learn it by copying the speed (docs/model.md, "Go/stop")."""
    room = np.maximum(gap - s0 - v_object * headway, 0.0)
    return np.sqrt(v_object**2 + 2.0 * decel * room)


def reason_of_kind(kind: np.ndarray, is_prop: np.ndarray) -> np.ndarray:
    """(m,) Reason for corridor objects of ``kind`` (ActorKind); ``is_prop`` (m,) bool: static props."""
    out = np.full(len(kind), Reason.LEADING_VEHICLE, np.int8)
    out[kind == ActorKind.BICYCLE] = Reason.BICYCLE
    out[kind == ActorKind.PEDESTRIAN] = Reason.PEDESTRIAN
    out[(kind == ActorKind.PROP) | is_prop] = Reason.OBSTACLE
    return out
