"""Waypoint labels from a CAV's actual future trajectory (ego frame: :func:`cmudrive.maps.coords.to_ego`).

A sample taken at tick ``t`` gets two SimLingo-style action labels, both in the ego frame at ``t`` (x forward,
y left, metres):

- ``path`` (``PATH_POINTS``, 2): points ``PATH_SPACING`` = 1 m apart in arc length, 0 .. 19 m, along the
  path the CAV actually drove after ``t`` (its positions at every later tick until it left the world);
- ``speed_waypoints`` (``SPEED_POINTS``, 2): its positions 0.25 s, 0.5 s, ... 2.5 s after ``t``.

When the recorded future is too short (the CAV finished its route or the route hit its tick cap before it had
driven 19 m or before 2.5 s passed), the polyline is continued by the expert's planned path at the CAV's last
recorded tick (its route ahead, shifted around obstacles), then straight along the last heading; speed
waypoints past the last tick advance along that continuation at the last recorded speed. A CAV that stands
still keeps its future: a CAV that waited 40 s at a red light and then drove on gets a path along the road
it took and speed waypoints that stay at its position.
"""

from __future__ import annotations

import numpy as np

from cmudrive.maps.coords import to_ego

PATH_POINTS = 20  # [-] path label points
PATH_SPACING = 1.0  # [m] between path points
SPEED_POINTS = 10  # [-] speed waypoints
SPEED_STEP_TICKS = 5  # [ticks of 0.05 s] = 0.25 s between speed waypoints
MIN_STEP = 1e-6  # [m] a polyline point this close to the one before is dropped (standing still)


def _dedup(points: np.ndarray) -> np.ndarray:
    """Drop points within MIN_STEP of the point before them (arc length must grow strictly)."""
    if len(points) < 2:
        return points
    step = np.hypot(*np.diff(points, axis=0).T)
    return points[np.concatenate([[True], step > MIN_STEP])]


def _continuation(last: np.ndarray, plan: np.ndarray) -> np.ndarray:
    """The planned path's points beyond its point nearest to ``last`` (the trajectory's end)."""
    if len(plan) == 0:
        return plan
    k = int(np.argmin(np.hypot(plan[:, 0] - last[0], plan[:, 1] - last[1])))
    return plan[k + 1 :]


def future_polyline(trajectory: np.ndarray, plan: np.ndarray, reach: float) -> tuple[np.ndarray, np.ndarray]:
    """A polyline that starts at ``trajectory[0]`` and reaches at least ``reach`` metres of arc length.

    ``trajectory`` (T, 2): the CAV's positions from the sample tick on (T >= 1), map frame; ``plan`` (P, 2):
    the expert's planned path at the last of those ticks. Returns the points (M, 2) and their arc lengths
    (M,), strictly increasing (see the module docstring for the continuation rule)."""
    traj = _dedup(np.asarray(trajectory, np.float64))
    pts = traj
    if len(plan):
        pts = _dedup(np.concatenate([traj, _continuation(traj[-1], np.asarray(plan, np.float64))]))
    seg = np.hypot(*np.diff(pts, axis=0).T) if len(pts) > 1 else np.zeros(0)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    if arc[-1] < reach:  # straight on along the last heading (or the first one's, a lone point: +x)
        if len(pts) > 1:
            d = pts[-1] - pts[-2]
            heading = d / np.hypot(*d)
        else:
            heading = np.array([1.0, 0.0])
        extra = reach - arc[-1] + PATH_SPACING
        pts = np.concatenate([pts, pts[-1:] + extra * heading[None, :]])
        arc = np.concatenate([arc, [arc[-1] + extra]])
    return pts, arc


def along(points: np.ndarray, arc: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Points at arc lengths ``s`` on the polyline (linear interpolation; s beyond the end: the end)."""
    return np.stack([np.interp(s, arc, points[:, 0]), np.interp(s, arc, points[:, 1])], axis=-1)


def waypoint_labels(
    trajectory: np.ndarray,
    yaw: float,
    plan: np.ndarray,
    last_speed: float,
) -> tuple[np.ndarray, np.ndarray]:
    """``path`` (PATH_POINTS, 2) and ``speed_waypoints`` (SPEED_POINTS, 2), float32, ego frame.

    ``trajectory`` (T, 2) holds the CAV's position at the sample tick and every later tick it was in the
    world (20 Hz); ``yaw`` its heading at the sample tick; ``plan`` (P, 2) the expert's planned path at the
    trajectory's last tick and ``last_speed`` [m/s] its speed then (both for the continuation)."""
    trajectory = np.asarray(trajectory, np.float64)
    reach = (PATH_POINTS - 1) * PATH_SPACING
    n_ticks = len(trajectory)
    horizon = SPEED_POINTS * SPEED_STEP_TICKS
    missing = max(horizon - (n_ticks - 1), 0)  # ticks of the 2.5 s not recorded
    reach = max(reach, 0.0) + max(last_speed, 0.0) * missing * 0.05
    pts, arc = future_polyline(trajectory, plan, reach)
    x0, y0 = trajectory[0]
    path = along(pts, arc, np.arange(PATH_POINTS) * PATH_SPACING)
    speed_wp = np.empty((SPEED_POINTS, 2))
    ticks = np.arange(1, SPEED_POINTS + 1) * SPEED_STEP_TICKS
    recorded = ticks < n_ticks
    speed_wp[recorded] = trajectory[ticks[recorded]]
    if not recorded.all():  # past the last recorded tick: on along the polyline at the last speed
        s_end = _arc_of_trajectory_end(trajectory)
        extra = (ticks[~recorded] - (n_ticks - 1)) * 0.05 * max(last_speed, 0.0)
        speed_wp[~recorded] = along(pts, arc, s_end + extra)
    return (
        to_ego(path, x0, y0, yaw).astype(np.float32),
        to_ego(speed_wp, x0, y0, yaw).astype(np.float32),
    )


def _arc_of_trajectory_end(trajectory: np.ndarray) -> float:
    """Arc length of the trajectory's last point on the polyline (the polyline starts with the trajectory)."""
    seg = np.hypot(*np.diff(_dedup(trajectory), axis=0).T) if len(trajectory) > 1 else np.zeros(0)
    return float(seg.sum())
