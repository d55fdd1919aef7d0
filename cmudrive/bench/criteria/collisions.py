"""Which contacts of a CAV count as collision infractions, and under which key.

Input is the tick's :class:`~cmudrive.sim.collisions.CollisionEvents` (every overlapping pair of 2D
boxes); a pair with a CAV on one side is a *contact* of that CAV, a pair of two CAVs a contact of each.
A contact counts unless the CAV is slower than ``collision_min_speed``, the same other actor was counted
for this CAV within ``collision_same_actor_time``, or the CAV is within ``collision_min_distance`` of where
it stood at its last counted collision. Boxes overlap on every tick of a contact, so these rules are what
turns a contact into one infraction.
"""

from __future__ import annotations

import numpy as np

from cmudrive.bench.criteria.config import CriteriaConfig
from cmudrive.sim.collisions import CollisionEvents
from cmudrive.sim.snapshot import ActorKind

PEDESTRIAN_KEY = "collisions_pedestrian"
VEHICLE_KEY = "collisions_vehicle"
LAYOUT_KEY = "collisions_layout"


def collision_key(kind: int) -> str:
    """Results key of a collision with an actor of ``kind``: walkers are pedestrians, props (cones,
    warning signs, barriers) are layout, everything else (cars, parked cars, bicycles, motorcycles,
    emergency vehicles, other CAVs) is a vehicle."""
    if kind == ActorKind.PEDESTRIAN:
        return PEDESTRIAN_KEY
    if kind == ActorKind.PROP:
        return LAYOUT_KEY
    return VEHICLE_KEY


def cav_contacts(
    events: CollisionEvents, cav_of_row: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Contacts of CAVs: (cav (m,), snapshot row of the CAV (m,), snapshot row of the other actor (m,)),
    in event order. ``cav_of_row`` (A,) holds the CAV index of each snapshot row, -1 for other actors."""
    side_a, side_b = cav_of_row[events.a], cav_of_row[events.b]
    cav = np.stack([side_a, side_b], axis=1).ravel()  # (2E,) event by event, a side first
    row = np.stack([events.a, events.b], axis=1).ravel()
    other = np.stack([events.b, events.a], axis=1).ravel()
    keep = cav >= 0
    return cav[keep], row[keep], other[keep]


class CollisionMemory:
    """Per-CAV memory of counted collisions: the last time each other actor was counted, and where the
    CAV stood at its last counted collision."""

    def __init__(self, num_cavs: int, config: CriteriaConfig) -> None:
        self.config = config
        self._last_time: list[dict[str, float]] = [{} for _ in range(num_cavs)]  # other id -> time [s]
        self._last_xy = np.full((num_cavs, 2), np.nan)  # [m] CAV centre at its last counted collision

    def forget_far(self, cav: np.ndarray, xy: np.ndarray) -> None:
        """Forget where CAVs ``cav`` (m,), now at ``xy`` (m, 2) [m], had their last counted collision once
        they are farther than ``collision_min_distance`` from it (upstream clears it the same way), so a
        CAV coming back to that spot later is charged again."""
        away = np.hypot(*(xy - self._last_xy[cav]).T) > self.config.collision_min_distance  # NaN: False
        self._last_xy[cav[away]] = np.nan

    def count(
        self, cav: np.ndarray, other_id: np.ndarray, cav_xy: np.ndarray, cav_speed: np.ndarray, time: float
    ) -> np.ndarray:
        """(m,) bool: which contacts (cav (m,), other actor id (m,), CAV centre (m, 2) [m], CAV speed (m,)
        [m/s]) count as collisions at ``time`` [s]; counted ones are remembered. Contacts are taken in
        order, so of two contacts of one CAV in one tick the second is usually within 5 m of the first."""
        cfg = self.config
        counted = np.zeros(len(cav), bool)
        # a loop over the contacts of this tick (almost always none), not over actors
        for r in np.flatnonzero(np.abs(cav_speed) >= cfg.collision_min_speed).tolist():
            i, other = int(cav[r]), str(other_id[r])
            last = self._last_time[i].get(other)
            if last is not None and time - last <= cfg.collision_same_actor_time:
                continue
            if np.hypot(*(cav_xy[r] - self._last_xy[i])) <= cfg.collision_min_distance:  # NaN: none yet
                continue
            counted[r] = True
            self._last_time[i][other] = time
            self._last_xy[i] = cav_xy[r]
        return counted
