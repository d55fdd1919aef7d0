"""The few CARLA client types a leaderboard agent touches, so that it runs here without CARLA installed.

A leaderboard agent writes ``import carla`` for ``carla.VehicleControl`` (its return value) and reads
``carla.Transform`` / ``carla.Location`` / ``carla.Rotation`` from its global plan in world coordinates.
It changes that line to ``from cmudrive.leaderboard import carla`` and keeps every ``carla.X`` as it is.
Only these value types exist here (no client, world or actors: there is no CARLA server).

Frames and units are CARLA's: x forward / east, y right / south, z up [m] (left-handed); rotations in
degrees, yaw clockwise seen from above.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field


@dataclass
class Vector3D:
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0

    def length(self) -> float:
        return math.sqrt(self.x * self.x + self.y * self.y + self.z * self.z)

    def __add__(self, other: Vector3D) -> Vector3D:
        return type(self)(self.x + other.x, self.y + other.y, self.z + other.z)

    def __sub__(self, other: Vector3D) -> Vector3D:
        return type(self)(self.x - other.x, self.y - other.y, self.z - other.z)


@dataclass
class Location(Vector3D):
    """A point in CARLA's world frame [m]."""

    def distance(self, other: Location) -> float:
        """Euclidean distance [m] to ``other``."""
        return (self - other).length()


@dataclass
class Rotation:
    """CARLA's rotation [deg]: pitch (nose up +), yaw (clockwise seen from above), roll. CARLA's argument
    order (pitch, yaw, roll)."""

    pitch: float = 0.0
    yaw: float = 0.0
    roll: float = 0.0

    def get_forward_vector(self) -> Vector3D:
        p, y = math.radians(self.pitch), math.radians(self.yaw)
        return Vector3D(math.cos(p) * math.cos(y), math.cos(p) * math.sin(y), math.sin(p))


@dataclass
class Transform:
    location: Location = field(default_factory=Location)
    rotation: Rotation = field(default_factory=Rotation)

    def get_forward_vector(self) -> Vector3D:
        return self.rotation.get_forward_vector()


@dataclass
class VehicleControl:
    """What ``run_step`` returns. throttle and brake in [0, 1], steer in [-1, 1] (+ = right). A pulled
    ``hand_brake`` brakes fully; ``reverse`` is refused (our CAVs have no reverse gear); ``gear`` and
    ``manual_gear_shift`` are ignored (automatic gearbox)."""

    throttle: float = 0.0
    steer: float = 0.0
    brake: float = 0.0
    hand_brake: bool = False
    reverse: bool = False
    manual_gear_shift: bool = False
    gear: int = 0


__all__ = ["Location", "Rotation", "Transform", "Vector3D", "VehicleControl"]
