"""The per-tick snapshot of every actor in the world: a struct of numpy arrays over actors.

This is what criteria, collisions, sensors and renderers read. One snapshot is taken per tick after the
SUMO step; actors are ordered CAVs first (in CAV order), then scenario actors, then background actors and
props, each group in a deterministic order (the order SUMO inserted them). ``A`` is the number of actors.

Poses are of the *centre* of the actor's bounding box in the map frame (x east, y north [m]; yaw
counter-clockwise from +x [rad]); SUMO's own position (front bumper, angle clockwise from north) is
converted when reading.

A snapshot is a record: never write into its arrays. The world shares the columns that change only when
actors come or go (``ids``, ``kind``, ``role``, ``length``, ``width``, ``valid``) and ``tls_state``
between consecutive snapshots, as read-only arrays; copy before modifying (``select`` returns copies).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from enum import IntEnum

import numpy as np

from cmudrive.maps.elevation import other_level


class ActorKind(IntEnum):
    CAR = 0
    VAN = 1
    TRUCK = 2
    BUS = 3
    MOTORCYCLE = 4
    BICYCLE = 5
    PEDESTRIAN = 6
    EMERGENCY = 7  # police car / ambulance / fire truck with siren capability
    PROP = 8  # static obstacle: parked car, cone, warning sign, barrier


class Role(IntEnum):
    CAV = 0  # connected autonomous vehicle driven by the agent under test
    BACKGROUND = 1  # SUMO traffic managed by the background activity
    SCENARIO = 2  # actors scripted by a scenario (adversaries, flows, obstacles)
    PROP = 3  # static props


# SUMO vehicle signal bits (libsumo vehicle.getSignals)
SIGNAL_BLINKER_RIGHT = 1 << 0
SIGNAL_BLINKER_LEFT = 1 << 1
SIGNAL_BLINKER_EMERGENCY = 1 << 2
SIGNAL_BRAKELIGHT = 1 << 3
SIGNAL_FRONTLIGHT = 1 << 4
SIGNAL_EMERGENCY_BLUE = 1 << 11  # the siren / blue light of an emergency vehicle


@dataclass(frozen=True, eq=False)
class Snapshot:
    """Every actor at one tick. All per-actor arrays have shape (A,)."""

    step: int  # tick number since the route started
    time: float  # simulation time [s]
    ids: np.ndarray  # (A,) str, actor ids (SUMO ids; CAVs are "cav0", "cav1", ...)
    kind: np.ndarray  # (A,) int8 ActorKind
    role: np.ndarray  # (A,) int8 Role
    x: np.ndarray  # (A,) float64 bounding-box centre [m]
    y: np.ndarray  # (A,) float64 [m]
    yaw: np.ndarray  # (A,) float64 heading [rad], counter-clockwise from +x
    speed: np.ndarray  # (A,) float64 [m/s], signed along the heading
    accel: np.ndarray  # (A,) float64 longitudinal acceleration [m/s^2]
    length: np.ndarray  # (A,) float64 bounding-box length [m]
    width: np.ndarray  # (A,) float64 bounding-box width [m]
    lane: np.ndarray  # (A,) int32 map lane index the actor is on, -1 when off the road network
    z: np.ndarray  # (A,) float64 elevation of the actor's lane where it is [m], NaN off the network
    signals: np.ndarray  # (A,) int32 SUMO signal bit mask (blinkers, brake light, blue light)
    valid: np.ndarray  # (A,) bool, False for padding rows
    tls_state: np.ndarray  # (T,) str, current signal string of each traffic light of the map

    @property
    def num_actors(self) -> int:
        return int(self.ids.shape[0])

    @property
    def xy(self) -> np.ndarray:
        """(A, 2) centre positions [m]."""
        return np.stack([self.x, self.y], axis=1)

    @property
    def siren(self) -> np.ndarray:
        """(A,) bool: the blue light / siren is on."""
        return (self.signals & SIGNAL_EMERGENCY_BLUE) != 0

    def other_level(self, rows: np.ndarray) -> np.ndarray:
        """(len(rows), A) bool: actor j is on another level than actor ``rows[i]`` (a bridge over its road:
        more than ``LEVEL_CLEARANCE`` above or below); never for an unknown (NaN) elevation."""
        return other_level(self.z[np.asarray(rows)][:, None], self.z[None, :])

    @property
    def brake_light(self) -> np.ndarray:
        return (self.signals & SIGNAL_BRAKELIGHT) != 0

    def corners(self) -> np.ndarray:
        """(A, 4, 2) bounding-box corners [m]: front-left, front-right, rear-right, rear-left."""
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        hl, hw = 0.5 * self.length, 0.5 * self.width
        local = np.array([[1.0, 1.0], [1.0, -1.0], [-1.0, -1.0], [-1.0, 1.0]])  # (4, 2) in (long, lat) units
        lon = local[None, :, 0] * hl[:, None]
        lat = local[None, :, 1] * hw[:, None]
        x = self.x[:, None] + lon * c[:, None] - lat * s[:, None]
        y = self.y[:, None] + lon * s[:, None] + lat * c[:, None]
        return np.stack([x, y], axis=-1)

    def select(self, rows: np.ndarray) -> Snapshot:
        """A snapshot of the actors at ``rows`` (a bool mask or indices, in that order); lights kept."""
        kwargs = {}
        for f in fields(self):
            value = getattr(self, f.name)
            per_actor = isinstance(value, np.ndarray) and f.name != "tls_state"
            kwargs[f.name] = value[rows] if per_actor else value
        return Snapshot(**kwargs)

    def cav_rows(self) -> tuple[np.ndarray, np.ndarray]:
        """Rows of the CAVs in this snapshot and their CAV indices ("cav3" -> 3), in snapshot order."""
        rows = np.flatnonzero(self.role == Role.CAV)
        return rows, np.array([int(str(c)[3:]) for c in self.ids[rows]], np.int64)  # <= 16 CAVs

    def index_of(self, actor_id: str) -> int:
        hits = np.flatnonzero(self.ids == actor_id)
        if len(hits) == 0:
            raise KeyError(f"actor {actor_id!r} is not in the snapshot of step {self.step}")
        return int(hits[0])

    @staticmethod
    def from_rows(step: int, time: float, tls_state: np.ndarray, **columns: np.ndarray) -> Snapshot:
        """Build a snapshot from per-actor columns (tests and synthetic scenes); ``valid`` defaults True."""
        n = len(columns["x"])
        defaults: dict[str, np.ndarray] = {
            "ids": np.array([f"a{i}" for i in range(n)]),
            "kind": np.zeros(n, np.int8),
            "role": np.full(n, Role.BACKGROUND, np.int8),
            "yaw": np.zeros(n),
            "speed": np.zeros(n),
            "accel": np.zeros(n),
            "length": np.full(n, 4.5),
            "width": np.full(n, 1.9),
            "lane": np.full(n, -1, np.int32),
            "z": np.zeros(n),
            "signals": np.zeros(n, np.int32),
            "valid": np.ones(n, bool),
        }
        defaults.update({k: np.asarray(v) for k, v in columns.items()})
        return Snapshot(step=step, time=time, tls_state=np.asarray(tls_state, dtype=str), **defaults)
