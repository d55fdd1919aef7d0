"""Minimum speed (recorded only, as in Bench2Drive): the CAV's speed relative to surrounding traffic.

The route is cut into ``min_speed_checkpoints`` parts of equal length; a CAV is in the part that holds its
route progress. Each tick in which background vehicles (SUMO traffic, not pedestrians, props or scenario
actors) are within ``min_speed_radius`` of the CAV adds the CAV's speed to one sum and the mean speed of
those vehicles to another; a part's value is ``100 * CAV sum / traffic sum`` [%], or 100 when it had no
such tick (or the traffic stood still throughout). Parts the CAV never reached have no value, and
neither has the part it is still in (the open one) unless it has done more than
``OPEN_CHECKPOINT_COMPLETION`` of its route, as upstream, so standing at the end of a stunted run does not
count as driving slowly.
"""

from __future__ import annotations

import numpy as np

from cmudrive.bench.criteria.config import CriteriaConfig
from cmudrive.sim.snapshot import ActorKind, Role, Snapshot

OPEN_CHECKPOINT_COMPLETION = 95.0  # [%] route completion above which the open part counts too
_IS_VEHICLE = np.array([k not in (ActorKind.PEDESTRIAN, ActorKind.PROP) for k in ActorKind])  # by kind


def background_vehicles(snap: Snapshot) -> np.ndarray:
    """(A,) bool: valid background vehicles of the snapshot."""
    return snap.valid & (snap.role == Role.BACKGROUND) & _IS_VEHICLE[snap.kind]


class MinSpeedMonitor:
    def __init__(self, route_length: np.ndarray, config: CriteriaConfig) -> None:
        n, c = len(route_length), config.min_speed_checkpoints
        self.config = config
        self._part = np.maximum(route_length, 1e-9) / c  # (n,) [m] length of one part
        self.cav_sum = np.zeros((n, c))  # [m/s] summed CAV speed over ticks with traffic near
        self.traffic_sum = np.zeros((n, c))  # [m/s] summed mean traffic speed over those ticks
        self.ticks = np.zeros((n, c), np.int64)  # ticks spent in each part
        self.where = np.zeros((n, c, 3))  # tick, x [m], y [m] of the last tick spent in each part

    def update(
        self,
        tick: int,
        cav: np.ndarray,
        xy: np.ndarray,
        speed: np.ndarray,
        progress: np.ndarray,
        traffic_xy: np.ndarray,
        traffic_speed: np.ndarray,
    ) -> None:
        """One tick for CAVs ``cav`` (m,) at ``xy`` (m, 2) [m] with ``speed`` (m,) [m/s] and route
        ``progress`` (m,) [m]; ``traffic_xy`` (B, 2) [m] and ``traffic_speed`` (B,) [m/s] of the
        background vehicles."""
        part = np.minimum(
            (progress / self._part[cav]).astype(np.int64), self.config.min_speed_checkpoints - 1
        )
        self.ticks[cav, part] += 1
        self.where[cav, part] = np.column_stack([np.full(len(cav), float(tick)), xy])
        if len(traffic_xy) == 0:
            return
        d2 = np.sum((xy[:, None, :] - traffic_xy[None, :, :]) ** 2, axis=-1)  # (m, B)
        near = d2 <= self.config.min_speed_radius**2
        count = near.sum(axis=1)
        has = count > 0
        mean = (near @ np.abs(traffic_speed))[has] / count[has]
        self.cav_sum[cav[has], part[has]] += np.abs(speed[has])
        self.traffic_sum[cav[has], part[has]] += mean

    def checkpoints(self, cav: int, completion: float) -> list[tuple[int, float]]:
        """(part, value [%]) of every part the CAV reached, in route order; the part it is in last (still
        open) only when its route ``completion`` [%] is above ``OPEN_CHECKPOINT_COMPLETION``."""
        out = []
        reached = np.flatnonzero(self.ticks[cav] > 0).tolist()
        if reached and completion <= OPEN_CHECKPOINT_COMPLETION:
            reached = reached[:-1]
        for c in reached:
            traffic = float(self.traffic_sum[cav, c])
            out.append((c, 100.0 * float(self.cav_sum[cav, c]) / traffic if traffic > 0.0 else 100.0))
        return out
