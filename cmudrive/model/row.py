"""The row contract: the one place that turns a CAV's observations and plan into V2V-VLA's input row.

Data collection (:class:`cmudrive.data.collector.RowCollector`) stores these rows and the closed-loop
agent (:class:`cmudrive.model.agent.V2VVLAAgent`) feeds them to the model, both through a
:class:`RowBuilder`, so that the model reads in closed loop what it was trained on; training reads the
stored columns :data:`TRAIN_COLUMNS`. A row of one CAV at one tick:

- ``camera``: the front camera image after the dataset's JPEG round trip (``data.schema.encode_image``,
  quality 90, decoded by PIL as ``datasets`` decodes it): training only ever saw JPEG images, and the
  committed checkpoints' speed waypoints move by up to metres between the raw and the JPEG image of the
  same frame (docs/model.md, "Row contract");
- ``merged_bev``: the merged occupancy (the own one with ``bev="own"``) as the occupancy image, one palette
  (:data:`cmudrive.sensors.occupancy.PALETTE`; stored as a palette PNG, lossless);
- ``speed`` [m/s] and ``target_points`` (2, 2) [m, ego frame], float32 as stored;
- ``standing`` [s]: how long the CAV has stood (below ``STANDING_SPEED``), -1.0 while it moves. Not a
  stored column: the closed loop counts it every tick (:class:`StandingClock`), training derives it from
  the stored rows' ``route_id``, ``cav``, ``time`` and ``speed`` (:func:`standing_seconds`), at the
  collection's 4 Hz: the derived value lags the counted one by less than a sample interval (0.25 s);
- ``other_cavs``: ``[cav, x, y, yaw]`` of every other active CAV in the ego frame (float32 values, as
  stored), CAV index order.

Target points (:class:`TargetPoints`) come from the sparse plan every agent gets (``CavPlan.target_points``,
no privileged data): the first two points more than ``TARGET_MIN_AHEAD`` metres of plan beyond the CAV's
progress, progress advanced once per tick.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from typing import Any

import numpy as np
from PIL import Image

from cmudrive.agents.base import CavPlan, Observations
from cmudrive.agents.control import STOPPED_SPEED
from cmudrive.data.schema import CAMERA_FORMAT, COLUMNS, encode_bev, encode_image
from cmudrive.maps.coords import to_ego
from cmudrive.sensors.occupancy import OccupancyConfig, pack_occupancy, packed_to_rgb

TARGET_MIN_AHEAD = 7.5  # [m] a target point closer than this along the plan counts as reached (SimLingo's)
TARGET_SEARCH = 3  # [segments] of the sparse plan searched ahead of the last one for the CAV's progress
STANDING_SPEED = STOPPED_SPEED  # [m/s] below this a CAV stands: the controller's, go/stop's and the clock's
MOVING = -1.0  # the ``standing`` value of a CAV that moves

INPUT_COLUMNS = ("camera", "merged_bev", "speed", "target_points", "other_cavs")  # what the model reads
# targets; desired_speed is the speed query's target, target_speed (with the speed) its stop label
LABEL_COLUMNS = (
    "path",
    "speed_waypoints",
    "target_speed",
    "desired_speed",
    "commentary",
    "communication",
    "partner_label",
)
# what training loads: route_id for the split, cav and time with the speed for the standing time, the grid
# the camera-rotation augmentation re-draws the merged BEV from (cmudrive.model.augment), and the expert's
# reason for bucketed sampling
TRAIN_COLUMNS = ("route_id", "cav", "time", *INPUT_COLUMNS, "merged_occupancy", *LABEL_COLUMNS, "reason")
assert set(TRAIN_COLUMNS) <= set(COLUMNS)


class TargetPoints:
    """The next two sparse target points of each CAV, from its progress along its sparse plan (the
    polyline through ``CavPlan.target_points``; what the leaderboard gives agents): the first two points
    more than ``TARGET_MIN_AHEAD`` metres of polyline beyond the CAV's projection on it, the last point
    repeated at the end. Progress only moves forward, over at most ``TARGET_SEARCH`` segments a call: call
    it once per tick (:class:`RowBuilder` does)."""

    def __init__(self, plans: tuple[CavPlan, ...]) -> None:
        k = max(len(p.target_points) for p in plans)
        self.points = np.zeros((len(plans), k, 2))  # (K, k, 2) map frame [m], padded with the last point
        self.distance = np.zeros((len(plans), k))  # (K, k) [m] along the polyline, padded with +inf
        self.count = np.array([len(p.target_points) for p in plans])
        for i, p in enumerate(plans):
            pts = np.asarray(p.target_points, np.float64)
            self.points[i, : len(pts)], self.points[i, len(pts) :] = pts, pts[-1]
            d = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
            self.distance[i, : len(pts)], self.distance[i, len(pts) :] = d, np.inf
        self.segment = np.zeros(len(plans), np.int64)  # the segment each CAV was last projected on

    def progress(self, rows: np.ndarray, pos: np.ndarray) -> np.ndarray:
        """(n,) [m] along the plan of CAVs ``rows`` at ``pos`` (n, 2); advances their segments."""
        last = np.maximum(self.count[rows] - 2, 0)  # last segment index per CAV
        seg = np.minimum(self.segment[rows][:, None] + np.arange(TARGET_SEARCH)[None, :], last[:, None])
        r = rows[:, None]
        a, b = self.points[r, seg], self.points[r, np.minimum(seg + 1, self.count[rows][:, None] - 1)]
        ab = b - a
        length2 = np.maximum((ab**2).sum(-1), 1e-9)
        t = np.clip(((pos[:, None] - a) * ab).sum(-1) / length2, 0.0, 1.0)  # (n, S)
        dist = np.linalg.norm(a + t[..., None] * ab - pos[:, None], axis=-1)
        best = np.argmin(dist, axis=1)
        n = np.arange(len(rows))
        self.segment[rows] = seg[n, best]
        return self.distance[rows, seg[n, best]] + t[n, best] * np.sqrt(length2[n, best])

    def next_two(self, rows: np.ndarray, pos: np.ndarray) -> np.ndarray:
        """(n, 2, 2) the next two target points (map frame) of CAVs ``rows`` at ``pos`` (n, 2)."""
        s = self.progress(rows, pos)
        ahead = self.distance[rows] > (s + TARGET_MIN_AHEAD)[:, None]  # (n, k), padding is +inf: True
        first = np.where(ahead.any(axis=1), np.argmax(ahead, axis=1), self.count[rows] - 1)
        first = np.minimum(first, self.count[rows] - 1)
        second = np.minimum(first + 1, self.count[rows] - 1)
        return np.stack([self.points[rows, first], self.points[rows, second]], axis=1)


class StandingClock:
    """How long each CAV of a route has stood: seconds since the first tick of its current standstill
    (speed below ``STANDING_SPEED``), ``MOVING`` while it moves. Call :meth:`update` once per tick."""

    def __init__(self, num_cavs: int) -> None:
        self.since = np.full(num_cavs, np.nan)  # [s] simulation time the standstill began; NaN: moving

    def update(self, cavs: np.ndarray, time: float, speed: np.ndarray) -> np.ndarray:
        """(n,) float32 [s] the standing time of CAVs ``cavs`` at ``time`` with speeds ``speed``."""
        stands = np.asarray(speed) < STANDING_SPEED
        began = np.where(np.isnan(self.since[cavs]), time, self.since[cavs])
        self.since[cavs] = np.where(stands, began, np.nan)
        return np.where(stands, time - began, MOVING).astype(np.float32)


def standing_seconds(route: np.ndarray, cav: np.ndarray, time: np.ndarray, speed: np.ndarray) -> np.ndarray:
    """(N,) float32 [s] the ``standing`` input of N stored rows (any order): time since the CAV's first row
    of its current standstill, ``MOVING`` where it moves (what :class:`StandingClock` counts every tick, at
    the rows' sampling rate)."""
    n = len(speed)
    _, route_code = np.unique(np.asarray(route), return_inverse=True)
    time = np.asarray(time, np.float64)
    order = np.lexsort((time, np.asarray(cav), route_code))
    stands = np.asarray(speed)[order] < STANDING_SPEED
    group = route_code[order] * (int(np.max(cav, initial=0)) + 1) + np.asarray(cav)[order]
    start = np.ones(n, bool)
    start[1:] = (group[1:] != group[:-1]) | ~stands[:-1]  # a new CAV, or the row after a moving one
    first = np.maximum.accumulate(np.where(start, np.arange(n), 0))
    out = np.empty(n, np.float32)
    out[order] = np.where(stands, time[order] - time[order][first], MOVING)
    return out


def other_cavs(relative: np.ndarray) -> list[list[list[float]]]:
    """(n, K, 3) poses of every CAV in each active CAV's frame (``Observations.other_cavs``, NaN for itself
    and CAVs not driving) -> per CAV the ``other_cavs`` column: ``[cav, x, y, yaw]`` lists, float32 values."""
    out = []
    for rel in np.asarray(relative, np.float64):
        seen = np.flatnonzero(~np.isnan(rel[:, 0]))
        values = np.column_stack([seen, rel[seen]]).astype(np.float32)
        out.append([[float(v) for v in row] for row in values])
    return out


def jpeg_round_trip(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 -> the same image stored as the dataset stores it and decoded as training decodes
    it (``encode_image`` with ``CAMERA_FORMAT``, then PIL, as ``datasets.Image`` does)."""
    stored = encode_image(image, CAMERA_FORMAT)["bytes"]
    assert stored is not None
    return np.asarray(Image.open(io.BytesIO(stored)).convert("RGB"))


@dataclass(frozen=True)
class RowInputs:
    """The input rows of the ``n`` active CAVs of one tick, images not yet encoded."""

    cav_index: np.ndarray  # (n,) which CAV of the route
    camera: np.ndarray  # (n, H, W, 3) uint8, the raw render
    bev: np.ndarray | None  # (n, H, W) uint8 packed occupancy the BEV image shows; None: no image
    speed: np.ndarray  # (n,) float32 [m/s]
    standing: np.ndarray  # (n,) float32 [s] since the CAV stopped, MOVING (-1) while it moves
    target_points: np.ndarray  # (n, 2, 2) float32 [m], ego frame
    other_cavs: list[list[list[float]]]  # per CAV: [cav, x, y, yaw] of the others (:func:`other_cavs`)

    def __len__(self) -> int:
        return len(self.cav_index)


class RowBuilder:
    """Per route: the model input rows of the active CAVs, each tick (module docstring)."""

    def __init__(self, plans: tuple[CavPlan, ...], occupancy: OccupancyConfig | None = None) -> None:
        self.targets = TargetPoints(plans)
        self.clock = StandingClock(len(plans))
        self.occupancy = occupancy or OccupancyConfig()
        self._tick: int | None = None
        self._cavs = np.zeros(0, np.int64)
        self._target_points = np.zeros((0, 2, 2), np.float32)
        self._standing = np.zeros(0, np.float32)

    def advance(self, obs: Observations) -> None:
        """Move the active CAVs' progress along their plans and their standing clocks to this tick: call it
        every tick (the closed loop builds rows every tick; the collector, which samples every fifth, calls
        it on the others too); a second call at the same tick changes nothing."""
        cavs = np.asarray(obs.cav_index, np.int64)
        if obs.tick != self._tick:
            points = self.targets.next_two(cavs, np.stack([obs.x, obs.y], axis=1))
            self._target_points = to_ego(points, obs.x[:, None], obs.y[:, None], obs.yaw[:, None]).astype(
                np.float32
            )
            self._standing = self.clock.update(cavs, obs.time, obs.speed)
            self._tick, self._cavs = obs.tick, cavs
        elif not np.array_equal(cavs, self._cavs):
            raise ValueError(f"tick {obs.tick}: rows asked twice, for other CAVs the second time")

    def target_points(self, obs: Observations) -> np.ndarray:
        """(n, 2, 2) float32 [m] the next two target points of the active CAVs in their frames
        (:meth:`advance` first)."""
        self.advance(obs)
        return self._target_points

    def standing(self, obs: Observations) -> np.ndarray:
        """(n,) float32 [s] how long each active CAV has stood, ``MOVING`` (-1) where it moves
        (:meth:`advance` first)."""
        self.advance(obs)
        return self._standing

    def inputs(self, obs: Observations, bev_grid: np.ndarray | None) -> RowInputs:
        """The rows of ``obs`` (camera and other CAVs' poses needed), the BEV image from ``bev_grid``
        ((n, C, H, W) bool: the merged occupancy, or the own one; None: no BEV)."""
        if obs.camera is None or obs.other_cavs is None:
            raise ValueError("model rows need the camera images and the other CAVs' poses")
        return RowInputs(
            cav_index=np.asarray(obs.cav_index, np.int64),
            camera=obs.camera,
            bev=None if bev_grid is None else pack_occupancy(bev_grid),
            speed=np.asarray(obs.speed, np.float32),
            standing=self.standing(obs),
            target_points=self.target_points(obs),
            other_cavs=other_cavs(obs.other_cavs),
        )

    def view(
        self,
        inputs: RowInputs,
        sel: np.ndarray,
        offset: np.ndarray,
        camera: np.ndarray,
        bev_grid: np.ndarray,
        relative: np.ndarray,
    ) -> RowInputs:
        """The rows of CAVs ``inputs[sel]`` as seen from view poses ``offset`` (k, 3): x, y [m], yaw [rad]
        in each CAV's own frame (a recovery view, ``cmudrive.data.recovery``). ``camera`` (k, H, W, 3) and
        ``bev_grid`` (k, C, H, W) are rendered from the view poses, ``relative`` (k, K, 3) holds every CAV's
        pose in each view's frame (``Observations.other_cavs``); the target points move into the view's
        frame; speed and standing time stay the CAV's."""
        sel = np.asarray(sel, np.int64)
        offset = np.asarray(offset, np.float64).reshape(len(sel), 3)
        tp = to_ego(
            inputs.target_points[sel].astype(np.float64),
            offset[:, None, 0],
            offset[:, None, 1],
            offset[:, None, 2],
        )
        return RowInputs(
            cav_index=inputs.cav_index[sel],
            camera=camera,
            bev=pack_occupancy(bev_grid),
            speed=inputs.speed[sel],
            standing=inputs.standing[sel],
            target_points=tp.astype(np.float32),
            other_cavs=other_cavs(relative),
        )

    def stored(self, inputs: RowInputs) -> dict[str, list[Any]]:
        """The dataset columns of the rows (:data:`INPUT_COLUMNS`, images encoded as stored)."""
        if inputs.bev is None:
            raise ValueError("the dataset stores the merged BEV: give the rows a BEV grid")
        n = len(inputs)
        return {
            "camera": [encode_image(inputs.camera[a], CAMERA_FORMAT) for a in range(n)],
            "merged_bev": [encode_bev(inputs.bev[a], self.occupancy) for a in range(n)],
            "speed": [float(v) for v in inputs.speed],
            "target_points": list(inputs.target_points),
            "other_cavs": inputs.other_cavs,
        }

    def model_rows(self, inputs: RowInputs, jpeg: bool = True) -> list[dict[str, Any]]:
        """The rows as training reads them back from the dataset (the columns of :meth:`stored`, decoded,
        and the derived ``standing``): the camera after the JPEG round trip (``jpeg=False``: the raw render,
        which training never saw), the BEV drawn with the stored image's palette (PNG is lossless: the
        same pixels)."""
        bev = None if inputs.bev is None else packed_to_rgb(inputs.bev, self.occupancy)
        out = []
        for a in range(len(inputs)):
            camera = inputs.camera[a]
            row: dict[str, Any] = {
                "camera": jpeg_round_trip(camera) if jpeg else camera,
                "speed": float(inputs.speed[a]),
                "standing": float(inputs.standing[a]),
                "target_points": inputs.target_points[a],
                "other_cavs": inputs.other_cavs[a],
            }
            if bev is not None:
                row["merged_bev"] = bev[a]
            out.append(row)
        return out
