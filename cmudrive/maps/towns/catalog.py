"""The procedural towns, as data: one spec per town, built by the generic layout builders.

Together the towns hold every road layout the 44 scenario types need (signalised 4-way junctions with
multi-lane approaches and permissive left turns, priority / all-way-stop / stop-controlled and
T-junctions, 1+1 two-way roads, 3-lane one-way avenues, parking and bike lanes, sidewalks and crossings,
a motorway with on-ramps, auxiliary lane and exits, an interurban road network with oblique junctions).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from cmudrive.maps.towns.graph import RoadGraph
from cmudrive.maps.towns.grid import ControlRule, GridSpec, Street
from cmudrive.maps.towns.highway import HighwaySpec, Interchange
from cmudrive.maps.towns.ring import Chord, RingSpec


class Layout(Protocol):
    """A layout spec: frozen data that builds a road graph from a seeded generator."""

    def build(self, rng: np.random.Generator) -> RoadGraph: ...


@dataclass(frozen=True)
class TownSpec:
    """A named town: its layout and the seed of the committed network."""

    name: str
    description: str
    layout: Layout
    seed: int = 0


# Junction control by road rank (0 access, 1 local street, 2 collector, 3 arterial).
_SIGNALISED_CENTRE = (
    ControlRule(3, 3, "traffic_light"),
    ControlRule(3, 2, "traffic_light"),
    ControlRule(3, 1, "traffic_light"),
    ControlRule(2, 1, "priority_stop"),
    ControlRule(1, 1, "allway_stop"),
)
_SUBURBAN = (
    ControlRule(2, 2, "allway_stop"),
    ControlRule(2, 1, "priority"),
    ControlRule(2, 0, "priority"),
    ControlRule(1, 1, "allway_stop"),
    ControlRule(1, 0, "priority_stop"),
    ControlRule(0, 0, "right_before_left"),
)
_CORRIDOR = (
    ControlRule(3, 2, "traffic_light"),
    ControlRule(3, 1, "priority_stop"),
    ControlRule(2, 1, "priority"),
    ControlRule(2, 2, "allway_stop"),
)

_TOWN_LIST = (
    TownSpec(
        "downtown",
        "signalised city grid: 2+2 arterials with left-turn pockets, a pair of 3-lane one-way avenues with "
        "parking, 1+1 streets with parking or bike lanes, sidewalks and crosswalks everywhere",
        GridSpec(
            columns=(
                Street("street"),
                Street("arterial", name="Market Avenue"),
                Street("avenue", name="North Avenue"),
                Street("bikestreet"),
                Street("avenue", reverse=True, name="South Avenue"),
                Street("street"),
            ),
            rows=(
                Street("street"),
                Street("arterial", name="Main Street"),
                Street("bikestreet"),
                Street("arterial", name="Union Street"),
                Street("street"),
            ),
            block_x=(130.0, 170.0),
            block_y=(120.0, 160.0),
            controls=_SIGNALISED_CENTRE,
            default_control="priority_stop",
            jitter=2.0,
        ),
        seed=11,
    ),
    TownSpec(
        "suburb",
        "unsignalised residential grid at 30-50 km/h: priority collectors with bike lanes, all-way stops, "
        "stop-controlled and right-before-left junctions, T-junctions, streets with parking",
        GridSpec(
            columns=(
                Street("residential"),
                Street("access"),
                Street("collector", name="Elm Road"),
                Street("residential"),
                Street("access"),
                Street("residential"),
            ),
            rows=(
                Street("residential"),
                Street("access"),
                Street("collector", name="Oak Road"),
                Street("residential"),
                Street("residential"),
            ),
            block_x=(100.0, 140.0),
            block_y=(90.0, 130.0),
            controls=_SUBURBAN,
            jitter=3.0,
            missing=4,
        ),
        seed=23,
    ),
    TownSpec(
        "corridor",
        "arterial corridor: a 3+3 boulevard with bike lanes and left-turn pockets, signals at collector "
        "crossings, stop-controlled side streets (many T-junctions), parallel collectors behind",
        GridSpec(
            columns=tuple(
                Street(k)
                for k in (
                    "street",
                    "residential",
                    "collector",
                    "street",
                    "residential",
                    "collector",
                    "street",
                    "residential",
                    "collector",
                    "street",
                    "residential",
                )
            ),
            rows=(
                Street("collector", name="South Lane"),
                Street("boulevard", name="Grand Boulevard"),
                Street("collector", name="North Lane"),
            ),
            block_x=(130.0, 230.0),
            block_y=(140.0, 180.0),
            controls=_CORRIDOR,
            jitter=2.0,
            missing=4,
        ),
        seed=5,
    ),
    TownSpec(
        "highway",
        "3-lane motorway (100-120 km/h) between two signalised end junctions, two interchanges with exit "
        "lanes, entry ramps merging from the right (acceleration and auxiliary lanes), frontage roads",
        HighwaySpec(
            length=(3500.0, 3800.0),
            interchanges=(Interchange(0.32, "priority_stop"), Interchange(0.68, "traffic_light")),
        ),
        seed=3,
    ),
    TownSpec(
        "interurban",
        "rural network: a 2+2 ring road at 90 km/h with 1+1 country roads across it at 80 km/h, oblique "
        "priority, stop-controlled and signalised junctions, all-way stops where country roads cross",
        RingSpec(
            radius=(800.0, 600.0),
            crossing_control="allway_stop",
            chords=(
                Chord(160.0, 20.0, "Mill Road", turn_start=30.0, turn_end=-30.0, control="priority_stop"),
                Chord(200.0, 340.0, "Church Road", turn_start=-30.0, turn_end=30.0, control="priority"),
                Chord(110.0, 250.0, "Forest Road", turn_start=10.0, turn_end=-10.0, control="traffic_light"),
                Chord(70.0, 290.0, "River Road", turn_start=15.0, turn_end=15.0, control="priority"),
            ),
        ),
        seed=8,
    ),
)

TOWNS: dict[str, TownSpec] = {t.name: t for t in _TOWN_LIST}
