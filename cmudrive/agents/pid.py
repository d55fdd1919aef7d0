"""A route-following PID agent that ignores every other actor: the smoke test of the evaluation loop.

Each CAV follows a smooth path through its sparse target points (a cubic spline over arc length,
sampled every 0.1 m) with the closed-loop controller SimLingo uses (``reference/MODEL_AND_EXPERT.md``):
steering is a windowed PID on the heading error to a look-ahead point 2.4-10.5 m ahead (growing with
speed), throttle a windowed PID on the speed error, brake when the wanted speed is ~0 or exceeded by
10 %. The wanted speed is 80 % of the speed limit at the next target point, 5 m/s into turns, and a
comfortable stop at the end of the route. All CAVs are handled at once (arrays over CAVs).

It does not look at lights, signs or other actors: on a busy route it will crash; on an empty route it
should complete with no infraction.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from scipy.interpolate import CubicSpline

from cmudrive.agents.base import Agent, Observation, Observations, RouteSetup, is_turn
from cmudrive.agents.control import (
    LOOKAHEAD_MAX,
    SPEED_GAINS,
    STEER_GAINS,
    WindowedPid,
    heading_error,
    lookahead_distance,
    nearest_ahead,
)
from cmudrive.sim.dynamics import Controls

PATH_STEP = 0.1  # [m] spacing of the followed path
SPEED_FACTOR = 0.8  # cruise at this share of the speed limit
TURN_SPEED = 5.0  # [m/s] in junction turns
TURN_PREVIEW = 25.0  # [m] slow down this far before a turn
STOP_DECEL = 2.0  # [m/s^2] comfortable stop at the route's end
BRAKE_SPEED = 0.4  # [m/s] wanted speed below this: brake
OVERSPEED = 1.1  # brake when speed / wanted speed exceeds this
SEARCH_WINDOW = 300  # [path points] progress search ahead of the last position


class PidAgent(Agent):
    """Follows each CAV's target points with PID control; sees nothing but its own state."""

    observations: ClassVar[frozenset[Observation]] = frozenset({Observation.EGO_STATE})

    def setup(self, route: RouteSetup) -> None:
        paths = [self._path(c.target_points) for c in route.cavs]
        n, longest = len(paths), max(len(p) for p in paths)
        self.length = np.array([len(p) for p in paths])
        self.path = np.zeros((n, longest + int(LOOKAHEAD_MAX / PATH_STEP) + 1, 2))
        for i, p in enumerate(paths):
            self.path[i, : len(p)], self.path[i, len(p) :] = p, p[-1]
        # the wanted speed along each path: speed limit, turns, final stop
        self.wanted = np.zeros((n, self.path.shape[1]))
        for i, (c, p) in enumerate(zip(route.cavs, paths, strict=True)):
            s = np.arange(len(p)) * PATH_STEP
            target_s = self._target_arclength(c.target_points, p)
            limit = (
                SPEED_FACTOR
                * c.target_speed_limits[np.clip(np.searchsorted(target_s, s), 0, len(target_s) - 1)]
            )
            for ts, turn in zip(target_s, is_turn(c.target_options), strict=True):
                if turn:
                    near = (s > ts - TURN_PREVIEW) & (s < ts + 5.0)
                    limit[near] = np.minimum(limit[near], TURN_SPEED)
            limit = np.minimum(limit, np.sqrt(2.0 * STOP_DECEL * np.maximum(s[-1] - s, 0.0)))
            self.wanted[i, : len(p)] = limit
        self.progress = np.zeros(n, np.int64)
        self.steer_pid = WindowedPid(n, *STEER_GAINS)
        self.speed_pid = WindowedPid(n, *SPEED_GAINS)

    @staticmethod
    def _path(points: np.ndarray) -> np.ndarray:
        """Smooth path through the target points, sampled every PATH_STEP metres."""
        d = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
        keep = np.concatenate([[True], np.diff(d) > 1e-3])
        d, points = d[keep], points[keep]
        if len(points) < 3:
            s = np.arange(0.0, d[-1] + PATH_STEP, PATH_STEP)
            return np.stack([np.interp(s, d, points[:, 0]), np.interp(s, d, points[:, 1])], axis=1)
        spline = CubicSpline(d, points, bc_type="natural")
        return spline(np.arange(0.0, d[-1], PATH_STEP))

    @staticmethod
    def _target_arclength(targets: np.ndarray, path: np.ndarray) -> np.ndarray:
        """Arc length [m] of the path point nearest to each target point (monotone)."""
        s = np.argmin(np.linalg.norm(path[None, :, :] - targets[:, None, :], axis=-1), axis=1) * PATH_STEP
        return np.maximum.accumulate(s)

    def run_step(self, obs: Observations) -> Controls:
        i = obs.cav_index
        pos = np.stack([obs.x, obs.y], axis=1)
        self.progress[i], _ = nearest_ahead(self.path, self.progress, i, pos, SEARCH_WINDOW)
        # lateral: heading error to the look-ahead point, in CARLA's sign (+ = right), scaled by 90 deg
        ahead = np.round(lookahead_distance(obs.speed) / PATH_STEP).astype(np.int64)
        target = self.path[i, np.minimum(self.progress[i] + ahead, self.path.shape[1] - 1)]
        steer = self.steer_pid(i, heading_error(pos, obs.yaw, target))
        # longitudinal
        wanted = self.wanted[i, self.progress[i]]
        speed_error = np.clip(wanted - obs.speed, 0.0, 1.0)
        throttle = np.clip(self.speed_pid(i, speed_error), 0.0, 1.0)
        stop = wanted < BRAKE_SPEED
        over = obs.speed > OVERSPEED * np.maximum(wanted, 1e-3)
        brake = np.where(stop, 1.0, np.where(over, 0.4, 0.0))
        throttle = np.where(stop | over, 0.0, throttle)
        return Controls(steer=np.clip(steer, -1.0, 1.0), throttle=throttle, brake=brake)
