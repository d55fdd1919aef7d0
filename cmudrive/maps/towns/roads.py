"""Road kinds of the procedural towns: the cross-section of one direction of travel.

A road kind says which lanes one carriageway direction has, from the kerb (right, SUMO lane index 0)
to the centre line, how wide they are, the speed limit and the rank used to pick junction controls.
Two-way roads use the same kind in both directions; one-way kinds get a single edge. Lanes:

* ``sidewalk``: pedestrians only (netconvert then guesses crossings and walking areas from it);
* ``parking``: SUMO lane ``type="parking"``, ``allow="custom1"``; never connected through junctions;
* ``bike``: bicycles only (``allow="bicycle"``);
* ``drive``: every vehicle class except pedestrians and ``custom1`` (and bicycles where ``bicycles`` is
  false). Scenario code puts parked cars into parking lanes directly (e.g. ``moveToXY``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

LaneKind = Literal["sidewalk", "parking", "bike", "drive"]

KMH = 1.0 / 3.6  # [m/s per km/h]


@dataclass(frozen=True)
class Lane:
    """One lane of an edge: its kind and width, and whether it is a motorway acceleration lane."""

    kind: LaneKind
    width: float  # [m]
    acceleration: bool = False


@dataclass(frozen=True)
class RoadKind:
    """Cross-section, speed limit and hierarchy of one direction of a road."""

    name: str
    lanes: int  # driving lanes per direction
    speed_kmh: float  # [km/h] speed limit
    rank: int  # hierarchy: 0 access, 1 local street, 2 collector, 3 arterial, 4 ramp, 5 motorway
    priority: int  # SUMO edge priority: the higher road has right of way at priority junctions
    oneway: bool = False
    lane_width: float = 3.3  # [m] driving lane
    sidewalk: float = 0.0  # [m] sidewalk width, 0 = none
    parking: float = 0.0  # [m] parking-lane width, 0 = none
    bike: float = 0.0  # [m] bike-lane width, 0 = none
    bicycles: bool = True  # bicycles may use the driving lanes
    left_pocket: float = 0.0  # [m] left-turn lane added before signalised junctions, 0 = none
    median: float = 0.0  # [m] painted median between the two directions; left-turn pockets take it

    def __post_init__(self) -> None:
        if self.left_pocket > 0 and self.median < self.lane_width - 1e-6:
            raise ValueError(f"road kind {self.name!r}: a left-turn pocket needs a median of one lane width")

    @property
    def speed(self) -> float:
        """Speed limit [m/s]."""
        return self.speed_kmh * KMH

    def cross_section(self, extra_right: int = 0, extra_left: int = 0) -> tuple[Lane, ...]:
        """Lanes from the kerb to the centre line; ``extra_*`` add driving lanes (ramps, turn pockets)."""
        lanes: list[Lane] = []
        if self.sidewalk > 0:
            lanes.append(Lane("sidewalk", self.sidewalk))
        if self.parking > 0:
            lanes.append(Lane("parking", self.parking))
        if self.bike > 0:
            lanes.append(Lane("bike", self.bike))
        lanes.extend(Lane("drive", self.lane_width) for _ in range(self.lanes + extra_right + extra_left))
        return tuple(lanes)

    @property
    def first_drive_lane(self) -> int:
        """SUMO index of the right-most driving lane."""
        return int(self.sidewalk > 0) + int(self.parking > 0) + int(self.bike > 0)


def _kinds(*kinds: RoadKind) -> dict[str, RoadKind]:
    return {k.name: k for k in kinds}


ROAD_KINDS: dict[str, RoadKind] = _kinds(
    # urban
    RoadKind(
        "arterial", lanes=2, speed_kmh=50, rank=3, priority=10, sidewalk=2.5, left_pocket=45.0, median=3.3
    ),
    RoadKind(
        "boulevard",
        lanes=3,
        speed_kmh=50,
        rank=3,
        priority=11,
        lane_width=3.25,
        sidewalk=2.5,
        bike=1.6,
        left_pocket=60.0,
        median=3.25,
    ),
    RoadKind(
        "avenue",
        lanes=3,
        speed_kmh=50,
        rank=3,
        priority=10,
        oneway=True,
        lane_width=3.2,
        sidewalk=3.0,
        parking=2.2,
    ),
    RoadKind("collector", lanes=1, speed_kmh=50, rank=2, priority=8, lane_width=3.4, sidewalk=2.0, bike=1.6),
    RoadKind("street", lanes=1, speed_kmh=40, rank=1, priority=5, lane_width=3.3, sidewalk=2.0, parking=2.2),
    RoadKind("bikestreet", lanes=1, speed_kmh=40, rank=1, priority=5, lane_width=3.3, sidewalk=2.0, bike=1.6),
    RoadKind(
        "residential", lanes=1, speed_kmh=30, rank=1, priority=3, lane_width=3.2, sidewalk=1.8, parking=2.1
    ),
    RoadKind("access", lanes=1, speed_kmh=30, rank=0, priority=2, lane_width=3.2, sidewalk=1.8),
    # rural and motorway
    RoadKind("interurban", lanes=2, speed_kmh=90, rank=3, priority=10, lane_width=3.5, bicycles=False),
    RoadKind("country", lanes=1, speed_kmh=80, rank=2, priority=7, lane_width=3.3),
    RoadKind("frontage", lanes=1, speed_kmh=70, rank=2, priority=7, lane_width=3.4),
    RoadKind(
        "motorway", lanes=3, speed_kmh=110, rank=5, priority=13, oneway=True, lane_width=3.5, bicycles=False
    ),
    RoadKind(
        "motorway_end",
        lanes=2,
        speed_kmh=70,
        rank=5,
        priority=12,
        oneway=True,
        lane_width=3.5,
        bicycles=False,
    ),
    RoadKind("ramp", lanes=1, speed_kmh=60, rank=4, priority=6, oneway=True, lane_width=3.5, bicycles=False),
)
