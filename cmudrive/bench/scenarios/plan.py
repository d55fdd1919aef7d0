"""What a scenario will spawn and where, as computed at setup (``Scenario.plan()``), for drawing routes.

Two item types, both in the map frame:

* :class:`PlanPoint`: an actor that stands (or starts) somewhere: ``kind`` is its actor type (``car``,
  ``police``, ``cone``, ``warning_sign``, ``pedestrian``, ``bicycle``, ``ambulance``, ...) or a marker
  (``patch`` for ControlLoss, ``light`` for a forced traffic light, ``slot`` for ParkingExit's start);
* :class:`PlanPath`: how an actor or a flow will move, start to end: ``kind`` is ``flow`` (a vehicle flow,
  source to sink), ``crossing``, ``cut_in``, ``ride`` (cyclists), ``approach`` (an emergency vehicle),
  ``invading`` or ``drive_off``.

Plans are read from the placements the scenario computed in ``place()``: building a scenario for its plan
needs the map and the CAV routes, not a running world (``plan_scenarios``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PlanPoint:
    kind: str
    xy: np.ndarray  # (2,) [m] map frame
    yaw: float = 0.0  # [rad]


@dataclass(frozen=True)
class PlanPath:
    kind: str
    xy: np.ndarray  # (n, 2) [m] map frame, n >= 2, from start to end


PlanItem = PlanPoint | PlanPath


def point(kind: str, xy: np.ndarray, yaw: float = 0.0) -> PlanPoint:
    return PlanPoint(kind, np.asarray(xy, np.float64).reshape(2), float(yaw))


def path(kind: str, xy: np.ndarray) -> PlanPath:
    return PlanPath(kind, np.asarray(xy, np.float64).reshape(-1, 2))
