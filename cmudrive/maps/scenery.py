"""Static scenery beside the roads: buildings, walls, poles, guardrails, trees, as oriented boxes.

SUMO networks carry no scenery, so a town's scenery is derived from its map (``build_scenery``, in
:mod:`cmudrive.maps.scenery_build`) and cached beside the map arrays. Every object is an oriented box on
the ground: a centre, a heading, a footprint and a height. Boxes are enough for everything that reads
scenery: the front camera draws them as 3D boxes, the visibility model uses their footprints as 2D
occluders, the occupancy map marks them as the ``static`` class, and a CAV that touches one has a layout
collision (CARLA's ``collisions_layout``, factor 0.65).

Frame: the map's (x east, y north, metres; yaw counter-clockwise from +x, radians).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from enum import IntEnum

import numpy as np


class SceneryKind(IntEnum):
    BUILDING = 0  # a block of houses or offices, set back from the sidewalk
    WALL = 1  # a boundary wall, fence or noise barrier
    POLE = 2  # a street-light, sign or utility pole
    GUARDRAIL = 3  # a highway guardrail segment (long, thin, low)
    TREE = 4  # a tree trunk (the footprint of the trunk; the canopy is not an obstacle)
    OBJECT = 5  # an object read from the map file (OpenDRIVE <object>)


@dataclass(frozen=True, eq=False)
class StaticScenery:
    """``S`` static objects as oriented boxes; every array has shape (S,)."""

    kind: np.ndarray  # (S,) int8 SceneryKind
    x: np.ndarray  # (S,) float64 footprint centre [m]
    y: np.ndarray  # (S,) float64 [m]
    yaw: np.ndarray  # (S,) float64 heading of the box's length axis [rad]
    length: np.ndarray  # (S,) float64 footprint along the heading [m]
    width: np.ndarray  # (S,) float64 footprint across the heading [m]
    height: np.ndarray  # (S,) float64 [m], from the ground

    def __post_init__(self) -> None:
        n = len(self.kind)
        for f in fields(self):
            value = getattr(self, f.name)
            if value.shape != (n,):
                raise ValueError(f"StaticScenery.{f.name} has shape {value.shape}, expected ({n},)")

    def __len__(self) -> int:
        return int(self.kind.shape[0])

    @classmethod
    def empty(cls) -> StaticScenery:
        return cls(np.zeros(0, np.int8), *(np.zeros(0) for _ in range(6)))

    @classmethod
    def concatenate(cls, parts: list[StaticScenery]) -> StaticScenery:
        if not parts:
            return cls.empty()
        return cls(**{f.name: np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(cls)})

    def select(self, rows: np.ndarray) -> StaticScenery:
        return StaticScenery(**{f.name: getattr(self, f.name)[rows] for f in fields(self)})

    def corners(self) -> np.ndarray:
        """(S, 4, 2) footprint corners [m]: front-left, front-right, rear-right, rear-left (the order of
        :meth:`cmudrive.sim.Snapshot.corners`)."""
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        hl, hw = 0.5 * self.length, 0.5 * self.width
        sign_lon = np.array([1.0, 1.0, -1.0, -1.0])
        sign_lat = np.array([1.0, -1.0, -1.0, 1.0])
        lon = sign_lon[None, :] * hl[:, None]
        lat = sign_lat[None, :] * hw[:, None]
        x = self.x[:, None] + lon * c[:, None] - lat * s[:, None]
        y = self.y[:, None] + lon * s[:, None] + lat * c[:, None]
        return np.stack([x, y], axis=-1)

    def arrays(self) -> dict[str, np.ndarray]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> StaticScenery:
        return cls(**{f.name: np.asarray(arrays[f.name]) for f in fields(cls)})
