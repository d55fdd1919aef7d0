"""Weather presets: documented ranges, the ordering of conditions, and matching CARLA weathers."""

from __future__ import annotations

import numpy as np
import pytest

from cmudrive.sim.weather import WEATHERS, Weather, get_weather, weather_from_carla

PRESETS = ["ClearNoon", "CloudySunset", "HardRainNoon", "ClearNight", "FogMorning"]

# a CARLA ClearNoon-like weather as a Bench2Drive <weather> element carries it
CARLA_CLEAR_NOON = {
    "route_percentage": 0.0,
    "cloudiness": 5.0,
    "precipitation": 0.0,
    "precipitation_deposits": 0.0,
    "wetness": 0.0,
    "wind_intensity": 10.0,
    "sun_azimuth_angle": -1.0,
    "sun_altitude_angle": 45.0,
    "fog_density": 2.0,
    "fog_distance": 0.75,
    "fog_falloff": 0.1,
}


def test_five_presets_with_documented_ranges() -> None:
    assert sorted(WEATHERS) == sorted(PRESETS)
    for name, w in WEATHERS.items():
        assert w.name == name and w.description
        assert 20.0 <= w.visibility <= 200.0  # [m]
        assert 0.0 <= w.light_level <= 1.0
        assert 0.5 <= w.friction <= 1.0
        assert -90.0 <= w.sun_altitude_deg <= 90.0
        for value in (w.cloudiness, w.precipitation, w.fog_density, w.wetness):
            assert 0.0 <= value <= 100.0


def test_night_and_fog_see_less_than_clear_noon() -> None:
    clear = get_weather("ClearNoon")
    for name in ("ClearNight", "FogMorning", "HardRainNoon", "CloudySunset"):
        assert get_weather(name).visibility < clear.visibility
    assert get_weather("FogMorning").visibility < get_weather("ClearNight").visibility
    assert get_weather("ClearNight").light_level < get_weather("CloudySunset").light_level < clear.light_level
    assert get_weather("ClearNight").is_night and not clear.is_night


def test_rain_has_lower_friction_and_scales_decelerations() -> None:
    rain, clear = get_weather("HardRainNoon"), get_weather("ClearNoon")
    assert rain.friction < get_weather("FogMorning").friction < clear.friction == 1.0
    assert clear.scale_decel(4.5) == pytest.approx(4.5)  # [m/s^2] SUMO's default passenger decel
    assert rain.scale_decel(4.5) == pytest.approx(4.5 * rain.friction)
    np.testing.assert_allclose(rain.scale_decel(np.array([4.5, 9.0])), np.array([4.5, 9.0]) * rain.friction)


def test_out_of_range_preset_is_rejected() -> None:
    with pytest.raises(ValueError, match="friction"):
        Weather("Ice", "ice", 100.0, 1.0, 1.5, 45.0, 0.0, 0.0, 0.0, 0.0)


def test_unknown_name_lists_the_valid_ones() -> None:
    with pytest.raises(ValueError, match="ClearNoon"):
        get_weather("SunnyDay")


def test_carla_clear_noon_maps_to_clear_noon() -> None:
    assert weather_from_carla(CARLA_CLEAR_NOON).name == "ClearNoon"


def test_sun_below_horizon_is_night_even_in_rain() -> None:
    assert weather_from_carla({**CARLA_CLEAR_NOON, "sun_altitude_angle": -90.0}).name == "ClearNight"
    rainy_night = {
        **CARLA_CLEAR_NOON,
        "sun_altitude_angle": -10.0,
        "precipitation": 100.0,
        "cloudiness": 100.0,
    }
    assert weather_from_carla(rainy_night).name == "ClearNight"


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        (
            {"cloudiness": 100.0, "precipitation": 100.0, "precipitation_deposits": 90.0, "wetness": 100.0},
            "HardRainNoon",
        ),
        ({"cloudiness": 60.0, "precipitation": 60.0, "precipitation_deposits": 60.0}, "HardRainNoon"),
        ({"sun_altitude_angle": 15.0, "cloudiness": 50.0}, "CloudySunset"),
        ({"sun_altitude_angle": 20.0, "fog_density": 60.0, "fog_distance": 10.0}, "FogMorning"),
    ],
)
def test_carla_weathers_map_to_the_nearest_preset(change: dict[str, float], expected: str) -> None:
    assert weather_from_carla({**CARLA_CLEAR_NOON, **change}).name == expected


def test_each_preset_maps_to_itself() -> None:
    for w in WEATHERS.values():
        carla = {
            "cloudiness": w.cloudiness,
            "precipitation": w.precipitation,
            "fog_density": w.fog_density,
            "wetness": w.wetness,
            "sun_altitude_angle": w.sun_altitude_deg,
        }
        assert weather_from_carla(carla) is w


def test_carla_bad_input_raises() -> None:
    with pytest.raises(ValueError, match="cloudyness"):
        weather_from_carla({"cloudyness": 10.0})
    with pytest.raises(ValueError, match="non-finite"):
        weather_from_carla({"fog_density": float("nan")})
