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

Rows of states the expert did not drive into (closed-loop data: another agent drove, the expert labels
beside it) have no future of the expert's to read; :func:`plan_labels` labels them from the expert's plan
at the sample tick instead (its docstring says how).
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


def plan_labels(
    plan: np.ndarray,
    x: float,
    y: float,
    yaw: float,
    speed: float,
    accel: float,
    desired: float,
) -> tuple[np.ndarray, np.ndarray]:
    """``path`` (PATH_POINTS, 2) and ``speed_waypoints`` (SPEED_POINTS, 2), float32, in the frame of a CAV
    at ``x``, ``y`` [m], heading ``yaw`` [rad], from the expert's plan for it at this tick.

    ``plan`` (P, 2), map frame: the expert's planned path ahead (its route ahead, shifted around
    obstacles; ``ExpertDecision.path``, which starts at the route point ahead of the CAV: it is reached
    back 2 m along its first heading). The path label is that plan from its point nearest the CAV on,
    resampled ``PATH_SPACING`` apart: a CAV beside its lane gets a path that starts on the lane, as the
    recovery views' labels do (``cmudrive.data.recovery``). The speed waypoints advance along the same
    polyline from there, the speed starting at ``speed`` [m/s] and changing at the expert's commanded
    ``accel`` [m/s^2] until it reaches ``desired`` [m/s] (the speed its rules allow now), never below 0;
    a plan shorter than needed is continued straight along its last heading (a plan of one point, at the
    end of its route, along the CAV's heading)."""
    plan = _dedup(np.asarray(plan, np.float64).reshape(-1, 2))
    if len(plan) == 0:
        plan = np.array([[x, y]], np.float64)
    if len(plan) > 1:  # the plan starts at the route point ahead of the CAV: reach back to beside it
        d = plan[0] - plan[1]
        plan = np.concatenate([plan[:1] + 2.0 * PATH_SPACING * d / np.hypot(*d), plan])
    s0, arc = _projection(plan, np.array([x, y]))
    ticks = np.arange(1, SPEED_POINTS * SPEED_STEP_TICKS + 1) * 0.05  # [s] every tick of the horizon
    v0, limit = max(speed, 0.0), max(desired, 0.0)
    v = v0 + accel * ticks
    v = np.minimum(v, max(v0, limit)) if accel >= 0.0 else np.maximum(v, min(v0, limit))
    v = np.concatenate([[v0], np.maximum(v, 0.0)])
    travelled = np.cumsum(v[:-1] + v[1:]) * 0.025  # trapezoids of 0.05 s
    reach = max((PATH_POINTS - 1) * PATH_SPACING, float(travelled[-1]))
    pts, arc = _extend(plan, arc, s0 + reach, np.array([np.cos(yaw), np.sin(yaw)]))
    path = along(pts, arc, s0 + np.arange(PATH_POINTS) * PATH_SPACING)
    speed_wp = along(pts, arc, s0 + travelled[SPEED_STEP_TICKS - 1 :: SPEED_STEP_TICKS])
    return to_ego(path, x, y, yaw).astype(np.float32), to_ego(speed_wp, x, y, yaw).astype(np.float32)


def _projection(points: np.ndarray, p: np.ndarray) -> tuple[float, np.ndarray]:
    """(arc length of the point of the polyline ``points`` nearest ``p``, the polyline's arc lengths)."""
    if len(points) == 1:
        return 0.0, np.zeros(1)
    seg = np.diff(points, axis=0)
    length = np.hypot(*seg.T)
    arc = np.concatenate([[0.0], np.cumsum(length)])
    u = np.clip(((p - points[:-1]) * seg).sum(axis=1) / length**2, 0.0, 1.0)
    nearest = points[:-1] + u[:, None] * seg
    k = int(np.argmin(np.hypot(*(nearest - p).T)))
    return float(arc[k] + u[k] * length[k]), arc


def _extend(
    points: np.ndarray, arc: np.ndarray, reach: float, heading: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The polyline continued straight along its last heading (``heading``, a unit vector, for a lone
    point: a plan at the end of its route, its points all the same) to arc ``reach``."""
    if arc[-1] >= reach:
        return points, arc
    d = points[-1] - points[-2] if len(points) > 1 else heading
    extra = reach - arc[-1] + PATH_SPACING
    end = points[-1] + extra * d / np.hypot(*d)
    return np.concatenate([points, end[None]]), np.concatenate([arc, [arc[-1] + extra]])
