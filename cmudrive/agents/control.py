"""The closed-loop controllers shared by the bundled agents, vectorised over CAVs.

SimLingo's controller (``reference/MODEL_AND_EXPERT.md``): steering is a windowed PID on the heading error
to a look-ahead point on the path, 2.4-10.5 m ahead and growing with speed; throttle a windowed PID on the
speed error. :class:`WindowedPid` keeps one error window per CAV of the route, so a CAV that leaves the
route keeps its rows and the others are unaffected.
"""

from __future__ import annotations

import numpy as np

LOOKAHEAD_A, LOOKAHEAD_B = 0.9755, 1.9153  # look-ahead [0.1 m] = A * v[km/h] + B
LOOKAHEAD_MIN, LOOKAHEAD_MAX = 2.4, 10.5  # [m]
STEER_GAINS = (3.118, 0.641, 1.378, 6)  # kp, ki, kd, window [ticks]
SPEED_GAINS = (1.75, 1.0, 2.0, 20)


class WindowedPid:
    """PID with the integral as the mean of the last ``window`` errors and the derivative as the change
    since the last call, one history row per CAV of the route."""

    def __init__(self, num_cavs: int, kp: float, ki: float, kd: float, window: int) -> None:
        self.kp, self.ki, self.kd = kp, ki, kd
        self.history = np.zeros((num_cavs, window))

    def __call__(self, rows: np.ndarray, error: np.ndarray) -> np.ndarray:
        previous = self.history[rows, -1]
        self.history[rows] = np.roll(self.history[rows], -1, axis=1)
        self.history[rows, -1] = error
        return self.kp * error + self.ki * self.history[rows].mean(axis=1) + self.kd * (error - previous)


def nearest_ahead(
    path: np.ndarray, progress: np.ndarray, rows: np.ndarray, pos: np.ndarray, window: int
) -> tuple[np.ndarray, np.ndarray]:
    """Route following's progress step: for CAVs ``rows`` at ``pos`` (n, 2), the index of the nearest point
    of their padded paths ``path`` (K, P, 2) among the ``window`` points from ``progress[rows]`` on, and the
    distance to it (n,) [m]. A short window keeps a route that passes close to itself from pulling the
    progress onto its later part."""
    idx = np.minimum(progress[rows][:, None] + np.arange(window)[None, :], path.shape[1] - 1)
    d = np.linalg.norm(path[rows[:, None], idx] - pos[:, None, :], axis=-1)
    best = np.argmin(d, axis=1)
    n = np.arange(len(rows))
    return idx[n, best], d[n, best]


def lookahead_distance(speed: np.ndarray) -> np.ndarray:
    """[m] how far ahead on the path the steering aims: 0.1 m x (0.9755 v[km/h] + 1.9153), in 2.4-10.5 m."""
    return np.clip(0.1 * (LOOKAHEAD_A * speed * 3.6 + LOOKAHEAD_B), LOOKAHEAD_MIN, LOOKAHEAD_MAX)


def heading_error(pos: np.ndarray, yaw: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Angle to ``target`` (n, 2) seen from ``pos`` (n, 2) with heading ``yaw``, in CARLA's sign (+ = to the
    right) divided by 90 deg: the input of SimLingo's steering PID."""
    rel = target - pos
    fwd = rel[:, 0] * np.cos(yaw) + rel[:, 1] * np.sin(yaw)
    left = -rel[:, 0] * np.sin(yaw) + rel[:, 1] * np.cos(yaw)
    return np.degrees(np.arctan2(-left, fwd)) / 90.0


# ---- SimLingo's waypoint controller: predicted path + speed waypoints (ego frame) -> controls ---------
SPEED_WAYPOINT_DT = 0.25  # [s] between speed waypoints (the model's 10 waypoints cover 2.5 s)
BRAKE_SPEED = 0.4  # [m/s] desired speed below this: brake
OVERSPEED = 1.1  # brake when speed / desired speed exceeds this
MAX_SPEED_ERROR = 1.0  # [m/s] the throttle PID sees clip(desired - speed, 0, this)
STOPPED_SPEED = 0.1  # [m/s] below this a CAV counts as standing (for creeping)
CREEP_AFTER = 800  # [ticks] standing this long (40 s) starts a creep
CREEP_TICKS = 15  # [ticks] a creep lasts this long
CREEP_THROTTLE = 0.4  # [-] throttle at least this during a creep, no brake


def desired_speed(speed_waypoints: np.ndarray) -> np.ndarray:
    """(n,) [m/s]: distance between the 0.25 s and 0.75 s waypoints (n, >= 3, 2) over the 0.5 s between."""
    return np.linalg.norm(speed_waypoints[:, 2] - speed_waypoints[:, 0], axis=-1) / (2 * SPEED_WAYPOINT_DT)


def brakes(speed: np.ndarray, desired: np.ndarray) -> np.ndarray:
    """(n,) bool: SimLingo's brake rule at ``speed`` [m/s] for ``desired`` speeds (n,) [m/s]: a desired
    speed below 0.4 m/s, or one that the CAV exceeds by more than 10 %."""
    return (desired < BRAKE_SPEED) | (speed > OVERSPEED * desired)


def expert_stops(speed: np.ndarray, target_speed: np.ndarray) -> np.ndarray:
    """(n,) bool: the expert's go/stop decision, the label of a model's stop head and the reference of
    ``benchmarks/go_stop.py``: SimLingo's brake rule (:func:`brakes`) for the expert's target speed [m/s]
    (where its speed controller means to be 0.5 s later) at ``speed`` [m/s]."""
    return brakes(np.asarray(speed, np.float64), np.asarray(target_speed, np.float64))


def point_along(path: np.ndarray, distance: np.ndarray) -> np.ndarray:
    """(n, 2) the point ``distance`` (n,) [m] along each polyline that starts at the origin and runs through
    ``path`` (n, P, 2): the look-ahead point of SimLingo's path resampled every 0.1 m (its last point when the
    path is shorter)."""
    n = len(path)
    poly = np.concatenate([np.zeros((n, 1, 2)), path], axis=1)  # (n, P+1, 2) from the ego's centre
    seg = np.linalg.norm(np.diff(poly, axis=1), axis=-1)  # (n, P)
    cum = np.concatenate([np.zeros((n, 1)), np.cumsum(seg, axis=1)], axis=1)  # (n, P+1)
    d = np.minimum(distance, cum[:, -1])
    j = np.clip((cum[:, 1:] < d[:, None]).sum(axis=1), 0, seg.shape[1] - 1)  # (n,) segment holding d
    rows = np.arange(n)
    t = np.where(seg[rows, j] > 0, (d - cum[rows, j]) / np.maximum(seg[rows, j], 1e-9), 0.0)
    return poly[rows, j] + t[:, None] * (poly[rows, j + 1] - poly[rows, j])


class WaypointController:
    """Controls from a predicted path and speed waypoints (ego frame, x forward, y left), SimLingo's rules
    (``reference/MODEL_AND_EXPERT.md``): desired speed from the 0.25 s and 0.75 s speed waypoints; brake
    when it is below 0.4 m/s or exceeded by 10 %; throttle a windowed PID (kp 1.75, ki 1.0, kd 2.0, 20
    ticks) on the clipped speed error; steering a windowed PID (kp 3.118, ki 0.641, kd 1.378, 6 ticks) on
    the heading error to the look-ahead point on the path; a creep after 40 s standing. One history row
    per CAV of the route."""

    def __init__(self, num_cavs: int) -> None:
        self.steer_pid = WindowedPid(num_cavs, *STEER_GAINS)
        self.speed_pid = WindowedPid(num_cavs, *SPEED_GAINS)
        self.stopped = np.zeros(num_cavs, np.int64)  # [ticks] standing
        self.creep = np.zeros(num_cavs, np.int64)  # [ticks] of creep left

    def __call__(
        self,
        rows: np.ndarray,
        speed: np.ndarray,
        path: np.ndarray,
        speed_waypoints: np.ndarray,
        target_speed: np.ndarray | None = None,
        stop: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(steer, throttle, brake), each (n,), for CAVs ``rows`` at ``speed`` (n,) [m/s] with predicted
        ``path`` (n, P, 2) and ``speed_waypoints`` (n, 10, 2) [m]. A model that predicts its go/stop
        passes ``stop`` (n,) bool: it replaces the brake rule; one that predicts the speed to drive at
        passes ``target_speed`` (n,) [m/s] too: it replaces the desired speed read from the speed
        waypoints, and the CAV also brakes where the brake rule says so for it (above it by 10 %, or it
        below 0.4 m/s)."""
        target = point_along(path, lookahead_distance(speed))
        zeros = np.zeros(len(rows))
        steer = np.clip(
            self.steer_pid(rows, heading_error(np.zeros((len(rows), 2)), zeros, target)), -1.0, 1.0
        )
        if target_speed is not None and stop is None:
            raise ValueError("a target speed comes with the model's stop decision")
        desired = (
            desired_speed(speed_waypoints) if target_speed is None else np.asarray(target_speed, np.float64)
        )
        brake = brakes(speed, desired)
        if stop is not None:
            brake = np.asarray(stop, bool) if target_speed is None else brake | np.asarray(stop, bool)
        error = np.clip(desired - speed, 0.0, MAX_SPEED_ERROR)
        throttle = np.where(brake, 0.0, np.clip(self.speed_pid(rows, error), 0.0, 1.0))
        # creep: a CAV that has stood for CREEP_AFTER ticks rolls for CREEP_TICKS
        self.stopped[rows] = np.where(speed < STOPPED_SPEED, self.stopped[rows] + 1, 0)
        start = self.stopped[rows] > CREEP_AFTER
        self.creep[rows] = np.where(start, CREEP_TICKS, self.creep[rows])
        self.stopped[rows] = np.where(start, 0, self.stopped[rows])
        creeping = self.creep[rows] > 0
        self.creep[rows] = np.maximum(self.creep[rows] - 1, 0)
        throttle = np.where(creeping, np.maximum(throttle, CREEP_THROTTLE), throttle)
        brake = brake & ~creeping
        return steer, throttle, brake.astype(np.float64)
