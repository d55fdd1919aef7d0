"""Weather and light presets: the five conditions every benchmark scenario is run under, as data.

SUMO has no weather, so a preset carries what our own layer needs from it:
- ``visibility`` [m]: the range at which the camera / perception model can still pick out an actor; the
  visibility sensor clips to it;
- ``light_level`` [0..1]: ambient illumination after the camera's auto-exposure, for the renderer;
- ``friction`` [0..1]: factor on tyre grip relative to dry asphalt; it scales vehicle decelerations
  (``Weather.scale_decel``);
- CARLA's own parameters (``sun_altitude_deg`` in degrees, the rest on CARLA's 0-100 scale), so that a
  preset can be matched to a CARLA / Bench2Drive weather (``weather_from_carla``) and rendered alike.

Names follow CARLA's preset style (``ClearNoon``, ``HardRainNoon``, ...).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Weather:
    """One weather and light condition."""

    name: str
    description: str  # one line
    visibility: float  # [m] perception range for actors
    light_level: float  # [0..1] ambient illumination seen by the camera, 1 = clear noon
    friction: float  # [0..1] tyre grip relative to dry asphalt
    sun_altitude_deg: float  # [deg] -90..90, below 0 is night
    cloudiness: float  # [0..100] CARLA scale
    precipitation: float  # [0..100] CARLA scale, rain intensity
    fog_density: float  # [0..100] CARLA scale
    wetness: float  # [0..100] CARLA scale, water on the road

    def __post_init__(self) -> None:
        checks = {
            "visibility": self.visibility > 0.0,
            "light_level": 0.0 <= self.light_level <= 1.0,
            "friction": 0.0 < self.friction <= 1.0,
            "sun_altitude_deg": -90.0 <= self.sun_altitude_deg <= 90.0,
            **{
                k: 0.0 <= getattr(self, k) <= 100.0
                for k in ("cloudiness", "precipitation", "fog_density", "wetness")
            },
        }
        bad = [k for k, ok in checks.items() if not ok]
        if bad:
            raise ValueError(f"weather {self.name!r}: out-of-range {bad}")

    @property
    def is_night(self) -> bool:
        return self.sun_altitude_deg < 0.0

    def scale_decel(self, decel: float | np.ndarray) -> float | np.ndarray:
        """Deceleration [m/s^2] (e.g. SUMO vType ``decel`` / ``emergencyDecel``) reachable on this road.

        Braking is grip limited, so it scales with friction. Acceleration is not scaled: a car's ~2-3 m/s^2
        is engine limited, well below even wet grip (~0.5 g)."""
        return decel * self.friction


WEATHERS: dict[str, Weather] = {
    w.name: w
    for w in (
        Weather(
            name="ClearNoon",
            description="Clear sky, sun high, dry road: the reference condition.",
            # camera range, not meteorological visibility (> 10 km): a 1.8 m wide car at 120 m spans
            # ~0.9 deg, about 15-20 px for a ~70 deg, 1600 px wide front camera, near detection limits
            visibility=120.0,  # [m]
            light_level=1.0,  # [-] ~100 klx direct sun is the reference
            friction=1.0,  # [-] dry asphalt, mu ~0.8-0.9
            sun_altitude_deg=60.0,  # [deg] around noon at mid latitudes
            cloudiness=10.0,  # [0..100] a few clouds
            precipitation=0.0,  # [0..100]
            fog_density=2.0,  # [0..100] light haze only
            wetness=0.0,  # [0..100]
        ),
        Weather(
            name="CloudySunset",
            description="Partly cloudy, low sun near the horizon: glare and long shadows, dry road.",
            visibility=90.0,  # [m] low contrast and sun glare into the camera cut detection range by ~1/4
            light_level=0.5,  # [-] ~5-10 klx at 10 deg sun altitude, lifted by auto-exposure
            friction=1.0,  # [-] dry
            sun_altitude_deg=10.0,  # [deg] low sun
            cloudiness=60.0,  # [0..100] broken cloud
            precipitation=0.0,  # [0..100]
            fog_density=5.0,  # [0..100] evening haze
            wetness=0.0,  # [0..100]
        ),
        Weather(
            name="HardRainNoon",
            description="Heavy rain under full overcast at noon: spray, drops on the lens, wet road.",
            # heavy rain (> 8 mm/h) leaves km of meteorological visibility, but spray, lens drops and
            # wipers blur distant actors: camera detection range roughly halves
            visibility=60.0,  # [m]
            light_level=0.4,  # [-] thick overcast passes ~10-20 % of clear-sky light, lifted by exposure
            friction=0.7,  # [-] wet asphalt mu ~0.5-0.65 against ~0.8-0.9 dry
            sun_altitude_deg=60.0,  # [deg] noon, behind clouds
            cloudiness=100.0,  # [0..100] full overcast
            precipitation=100.0,  # [0..100] hard rain
            fog_density=10.0,  # [0..100] rain mist
            wetness=100.0,  # [0..100] standing water
        ),
        Weather(
            name="ClearNight",
            description="Clear night, street lights and headlights only, dry road.",
            visibility=50.0,  # [m] low-beam headlights light the road ~40-60 m ahead
            light_level=0.1,  # [-] street lighting ~10-30 lx, bright only where lamps and headlights are
            friction=1.0,  # [-] dry
            sun_altitude_deg=-30.0,  # [deg] sun well below the horizon (astronomical night < -18 deg)
            cloudiness=10.0,  # [0..100]
            precipitation=0.0,  # [0..100]
            fog_density=0.0,  # [0..100]
            wetness=0.0,  # [0..100]
        ),
        Weather(
            name="FogMorning",
            description="Dense morning fog, low sun, damp road.",
            visibility=35.0,  # [m] dense fog: meteorological visibility below ~50 m
            light_level=0.6,  # [-] morning sun diffused by fog: bright but flat light
            friction=0.9,  # [-] dew and fog condensation dampen the road surface slightly
            sun_altitude_deg=15.0,  # [deg] early morning
            cloudiness=30.0,  # [0..100]
            precipitation=0.0,  # [0..100]
            fog_density=70.0,  # [0..100] dense fog
            wetness=20.0,  # [0..100] damp
        ),
    )
}

NIGHT_PRESET = "ClearNight"  # every CARLA weather with the sun below the horizon maps here

# weather_from_carla: feature -> (scale [unit of the feature], weight [-]); the distance to a preset is
# sqrt(sum(weight * ((carla - preset) / scale) ** 2)). Rain and fog weigh double: they cut visibility.
_MATCH_FEATURES: dict[str, tuple[float, float]] = {
    "cloudiness": (100.0, 1.0),
    "precipitation": (100.0, 2.0),
    "fog_density": (100.0, 2.0),
    "wetness": (100.0, 1.0),
    "sun_altitude_deg": (90.0, 1.0),
}

# CARLA WeatherParameters (and Bench2Drive <weather> attributes) we accept; the ones not used for matching
# only steer CARLA's rendering (sun direction, wind, fog falloff and scattering, position along the route).
_CARLA_KEYS = frozenset(
    {
        "cloudiness",
        "precipitation",
        "precipitation_deposits",
        "wind_intensity",
        "sun_azimuth_angle",
        "sun_altitude_angle",
        "fog_density",
        "fog_distance",
        "fog_falloff",
        "wetness",
        "scattering_intensity",
        "mie_scattering_scale",
        "rayleigh_scattering_scale",
        "dust_storm",
        "route_percentage",
    }
)


def get_weather(name: str) -> Weather:
    """The preset called ``name``; ValueError naming the valid presets otherwise."""
    try:
        return WEATHERS[name]
    except KeyError:
        raise ValueError(f"unknown weather {name!r}; valid: {sorted(WEATHERS)}") from None


def weather_from_carla(params: dict[str, float]) -> Weather:
    """The preset nearest to a CARLA / Bench2Drive weather.

    A sun below the horizon (``sun_altitude_angle`` < 0) is night whatever else it says (darkness is what
    limits perception most). Otherwise the nearest daytime preset by the weighted distance of
    ``_MATCH_FEATURES``, with road water = max(``wetness``, ``precipitation_deposits``); ties go to the
    preset listed first. Missing keys are 0, as in CARLA's ``WeatherParameters()``; unknown keys (typos)
    and non-finite values raise ValueError."""
    unknown = sorted(set(params) - _CARLA_KEYS)
    if unknown:
        raise ValueError(f"unknown CARLA weather keys {unknown}; accepted: {sorted(_CARLA_KEYS)}")
    values = {k: float(v) for k, v in params.items()}
    bad = sorted(k for k, v in values.items() if not math.isfinite(v))
    if bad:
        raise ValueError(f"non-finite CARLA weather values for {bad}")
    sun = min(max(values.get("sun_altitude_angle", 0.0), -90.0), 90.0)
    if sun < 0.0:
        return WEATHERS[NIGHT_PRESET]
    features = {
        "cloudiness": values.get("cloudiness", 0.0),
        "precipitation": values.get("precipitation", 0.0),
        "fog_density": values.get("fog_density", 0.0),
        "wetness": max(values.get("wetness", 0.0), values.get("precipitation_deposits", 0.0)),
        "sun_altitude_deg": sun,
    }

    def distance(w: Weather) -> float:
        return math.sqrt(
            sum(
                weight * ((features[k] - getattr(w, k)) / scale) ** 2
                for k, (scale, weight) in _MATCH_FEATURES.items()
            )
        )

    return min((w for w in WEATHERS.values() if not w.is_night), key=distance)
