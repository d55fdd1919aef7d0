"""Recovery views: extra rows of a CAV rendered from a pose beside it, labelled back toward the expert's path.

A model trained only on the expert's own states has never seen itself off its lane and cannot steer back
(imitation's compounding error). SimLingo renders half of its samples from a camera shifted sideways and
turned, and moves the labels into the shifted frame. We render such views exactly, because we own the
sensors: the collector (:class:`cmudrive.data.collector.RowCollector`) picks a share ``prob`` of the
sampled CAV rows, draws a lateral offset (uniform in +-``max_shift``) and a heading offset (uniform in
+-``max_yaw_deg``), and stores a *second* row of that CAV at that tick (the CAV's own row stays as it
was), computed in a counterfactual copy of the tick's snapshot where the chosen CAVs stand at their view
poses:

- the camera, the CAV's own occupancy and its partner's (which now sees the CAV where the view puts it)
  are sensed in that copy; the merged occupancy is the partner's grid warped into the view's frame, as the
  V2V link does (ideal link, the tick's partner);
- target points and the other CAVs' poses are expressed in the view's frame; speed, standing time and
  the language labels stay the CAV's (the same situation, a worse position);
- ``path`` and ``speed_waypoints`` are the CAV's own labels (the positions the expert drove) moved into
  the view's frame: from a view 1 m left of the CAV the path starts 1 m to the right and runs along the
  lane, so the model learns to steer back onto it; the expert's controls of the CAV's real pose are kept.

The row's ``view`` column says where the view was (x, y [m], yaw [rad] in the CAV's frame; zeros for
the CAV's own rows), so training and evaluation can tell the two apart. Each view costs one more camera
render and two occupancy grids; its random draws come from their own generator (``seed``, 3), so the
CAV's own rows are the same with views on or off.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from cmudrive.maps.coords import to_ego
from cmudrive.sim.snapshot import Snapshot


@dataclass(frozen=True)
class RecoveryViews:
    """Which sampled rows get a recovery view, and how far off it is."""

    prob: float = 0.0  # [-] share of sampled CAV rows that get a second row from a shifted view
    max_shift: float = 1.5  # [m] lateral offset, uniform in +-max_shift (SimLingo's range)
    max_yaw_deg: float = 10.0  # [deg] heading offset, uniform in +-max_yaw_deg

    def __post_init__(self) -> None:
        if not 0.0 <= self.prob <= 1.0:
            raise ValueError(f"recovery view share must be in [0, 1], got {self.prob}")
        if not 0.0 <= self.max_shift <= 3.0:
            raise ValueError(f"recovery view shift must be in [0, 3] m, got {self.max_shift}")
        if not 0.0 <= self.max_yaw_deg < 45.0:
            raise ValueError(f"recovery view yaw must be in [0, 45) deg, got {self.max_yaw_deg}")

    def draw(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Of ``n`` rows: the indices (k,) that get a view and their offsets (k, 3): x (0), y [m], yaw
        [rad] in the CAV's frame. Draws a fixed count of numbers per call, so one tick's draws do not
        depend on the last's outcome."""
        u = rng.random((n, 3))
        sel = np.flatnonzero(u[:, 0] < self.prob)
        offset = np.zeros((len(sel), 3))
        offset[:, 1] = (2.0 * u[sel, 1] - 1.0) * self.max_shift
        offset[:, 2] = (2.0 * u[sel, 2] - 1.0) * math.radians(self.max_yaw_deg)
        return sel, offset


def view_poses(x: np.ndarray, y: np.ndarray, yaw: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """(k, 3) map-frame poses (x, y, yaw) of views at ``offset`` (k, 3) in the frames of vehicles at
    (x, y, yaw) (k,)."""
    offset = np.asarray(offset, np.float64).reshape(-1, 3)
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack(
        [
            x + c * offset[:, 0] - s * offset[:, 1],
            y + s * offset[:, 0] + c * offset[:, 1],
            (np.asarray(yaw) + offset[:, 2] + np.pi) % (2 * np.pi) - np.pi,
        ],
        axis=1,
    )


def moved(snap: Snapshot, rows: np.ndarray, poses: np.ndarray) -> Snapshot:
    """A copy of ``snap`` where the actors at ``rows`` stand at ``poses`` (k, 3) (x, y, yaw); everything
    else (their lanes and elevations included) as it was."""
    rows = np.asarray(rows, np.int64)
    kwargs = {f.name: getattr(snap, f.name) for f in fields(snap)}
    for k, name in enumerate(("x", "y", "yaw")):
        column = np.array(kwargs[name], np.float64, copy=True)
        column[rows] = poses[:, k]
        kwargs[name] = column
    return Snapshot(**kwargs)


def to_view(points: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """(..., 2) float32 points of a CAV's frame in the frame of its view at ``offset`` (3,)."""
    return to_ego(np.asarray(points, np.float64), offset[0], offset[1], offset[2]).astype(np.float32)


__all__ = ["RecoveryViews", "moved", "to_view", "view_poses"]
