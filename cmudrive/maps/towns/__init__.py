"""Procedural towns: road networks generated from small typed specs and built by SUMO's netconvert.

Each town in ``TOWNS`` is a frozen spec (a grid of blocks, a motorway with interchanges, or an
interurban ring) that a generic builder turns into a road graph with a seeded
``numpy.random.Generator``; the graph is written as SUMO plain XML and netconvert makes the full
network (junction-internal lanes, traffic lights, sidewalks, crossings). The committed networks live in
``assets_dir()``; ``python -m cmudrive.maps.towns`` rebuilds them.
"""

from __future__ import annotations

from cmudrive.maps.towns.build import assets_dir, build_town, town_spec
from cmudrive.maps.towns.catalog import TOWNS, TownSpec

__all__ = ["TOWNS", "TownSpec", "assets_dir", "build_town", "town_spec"]
