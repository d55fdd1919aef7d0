"""Errors raised by the map layer. Every message names the file or the points involved."""

from __future__ import annotations


class MapError(Exception):
    """A map could not be built, loaded or queried."""


class NetconvertError(MapError):
    """SUMO's netconvert is missing or failed on an input file."""


class RouteError(MapError):
    """No route exists between the requested points."""
