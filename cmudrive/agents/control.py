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
