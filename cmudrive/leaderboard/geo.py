"""GNSS coordinates of map points, as CARLA's GNSS sensor and the leaderboard's GPS route give them.

Convention (CARLA 0.9.10-0.9.15, the versions Leaderboard 2.0 and Bench2Drive run, and the leaderboard's
``route_manipulation``): a town has a geographic reference (lat_0, lon_0) read from its OpenDRIVE header
(``<geoReference>``, ``+lat_0=.. +lon_0=..``). The reference point is projected with a spherical Mercator
whose scale is cos(lat_0) (Earth radius 6,378,137 m, WGS84's equatorial radius); a CARLA world point
(x, y) is then (mx0 + x, my0 - y) in that projection, and the inverse Mercator gives its latitude and
longitude; the altitude is the point's z (the reference altitude is 0). Since our map frame is CARLA's
mirrored in y (``cmudrive.maps.coords``), a map point (x, y) is simply (mx0 + x, my0 + y): north is +y.

References: CARLA's Town01-Town07 all carry ``+lat_0=49 +lon_0=8`` in their OpenDRIVE headers (checked in
the .xodr files they are imported from), so those towns get (49, 8). Our procedural towns and other
networks have no OpenDRIVE header: they get the leaderboard's default for a map without one, (42, 2).

CARLA's newer development branch (0.10 / ue5) moved to a transverse Mercator; that is not followed here,
since the agents this serves were trained on 0.9.x data.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from cmudrive.maps.importer import CARLA_TOWNS

EARTH_RADIUS = 6378137.0  # [m] WGS84 equatorial radius, CARLA's and the leaderboard's Mercator radius


@dataclass(frozen=True)
class GeoReference:
    """A map's geographic reference: the latitude and longitude of its origin."""

    lat: float  # [deg]
    lon: float  # [deg]

    @property
    def scale(self) -> float:
        """Mercator scale factor cos(lat_0) [-]."""
        return float(np.cos(np.radians(self.lat)))

    @property
    def origin(self) -> tuple[float, float]:
        """(mx0, my0) [m]: the reference point in the scaled Mercator projection."""
        k = self.scale * EARTH_RADIUS
        return k * np.radians(self.lon), k * float(np.log(np.tan(np.radians(45.0 + 0.5 * self.lat))))


CARLA_TOWN_REFERENCE = GeoReference(49.0, 8.0)  # Town01-Town07's OpenDRIVE <geoReference>
DEFAULT_REFERENCE = GeoReference(42.0, 2.0)  # the leaderboard's reference for a map without one


def geo_reference(town: str) -> GeoReference:
    """The reference of a town by name or network path: CARLA's towns (49, 8), any other (42, 2)."""
    name = Path(town).name.removesuffix(".net.xml")
    return CARLA_TOWN_REFERENCE if name in CARLA_TOWNS else DEFAULT_REFERENCE


def map_to_gnss(xy: ArrayLike, z: ArrayLike, ref: GeoReference) -> np.ndarray:
    """(..., 3) latitude [deg], longitude [deg], altitude [m] of map points ``xy`` (..., 2) [m] at
    elevation ``z`` (...) [m]."""
    xy = np.asarray(xy, np.float64)
    mx0, my0 = ref.origin
    k = ref.scale * EARTH_RADIUS
    mx, my = mx0 + xy[..., 0], my0 + xy[..., 1]
    lon = np.degrees(mx / k)
    lat = 2.0 * np.degrees(np.arctan(np.exp(my / k))) - 90.0
    return np.stack([lat, lon, np.broadcast_to(np.asarray(z, np.float64), lat.shape)], axis=-1)


def gnss_to_map(gnss: ArrayLike, ref: GeoReference) -> np.ndarray:
    """(..., 3) map x, y, z [m] of GNSS readings (..., 3): latitude, longitude [deg], altitude [m]."""
    g = np.asarray(gnss, np.float64)
    mx0, my0 = ref.origin
    k = ref.scale * EARTH_RADIUS
    x = k * np.radians(g[..., 1]) - mx0
    y = k * np.log(np.tan(np.radians(45.0 + 0.5 * g[..., 0]))) - my0
    return np.stack([x, y, g[..., 2]], axis=-1)
