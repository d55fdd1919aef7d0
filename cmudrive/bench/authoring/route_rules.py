"""The benchmark route sets' rules, as data: for each of the 44 scenario types, the towns whose layout it
needs, the junction turn and control it is built at, and its Bench2Drive-220 parameter ranges
(``reference/SCENARIOS.md``). ``benchmark_gen`` draws routes by them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

TRIGGER_AFTER_START = (3.0, 15.0)  # [m] trigger point along CAV 0's route from its start


@dataclass(frozen=True)
class TypeRule:
    """Where a type can be built and its Bench2Drive-220 parameter ranges."""

    towns: tuple[str, ...]  # tried in turn, route k starting at towns[k % len]
    junction: str = ""  # "" road type; else the turn at the junction: left, right, straight, turn, any
    control: str = "any"  # signal, nosignal, stop, any
    # name -> fixed str, tuple of str choices, (lo, hi) int or float range, or ((from lo, hi), (to lo, hi))
    params: tuple[tuple[str, Any], ...] = ()
    trigger_at: tuple[float, float] = TRIGGER_AFTER_START  # [m] trigger along the route from its start
    three_way: bool = False  # the junction has exactly three approaches (T_Junction)
    lane_shift: bool = False  # the route moves two lanes to the left (SequentialLaneChange)
    after_junction: tuple[float, float] | None = None  # [m] past the junction exit (None: the default)


MULTI = ("interurban", "Town04", "Town03", "highway", "Town05", "Town06", "corridor")
TWO_WAY = ("downtown", "Town01", "suburb", "Town02", "Town07", "corridor")
SIDE = ("downtown", "Town03", "suburb", "Town01", "Town02", "corridor", "Town05", "Town07")
URBAN_J = ("downtown", "Town03", "suburb", "Town05", "Town01", "corridor", "Town02", "Town07", "Town04")
SIGNAL_J = ("downtown", "Town03", "Town05", "Town01", "corridor", "Town02", "Town07", "Town04")
NOSIGNAL_J = ("suburb", "downtown", "corridor", "Town03", "Town04", "Town06", "Town07", "interurban")
STOP_J = ("downtown", "suburb", "corridor", "interurban")
RAMP = ("highway", "Town04", "Town06", "interurban")
PARKING = ("downtown", "Town03", "suburb", "corridor", "Town05")  # parking lanes >= 2 m wide (parking-slot)


def _flow(
    speed: tuple[int, int], frm: tuple[int, int], to: tuple[int, int]
) -> tuple[tuple[str, object], ...]:
    return (("flow_speed", speed), ("source_dist_interval", (frm, to)))


RULES: dict[str, TypeRule] = {
    "Accident": TypeRule(MULTI, params=(("distance", (40, 44)), ("direction", "right"), ("speed", (53, 57)))),
    "AccidentTwoWays": TypeRule(
        TWO_WAY, params=(("distance", (40, 44)), ("frequency", ((32, 63), (109, 184))))
    ),
    "BlockedIntersection": TypeRule(URBAN_J, junction="turn"),
    "ConstructionObstacle": TypeRule(
        MULTI, params=(("distance", (40, 45)), ("direction", "right"), ("speed", (47, 55)))
    ),
    "ConstructionObstacleTwoWays": TypeRule(
        TWO_WAY, params=(("distance", (40, 45)), ("frequency", ((43, 70), (129, 200))))
    ),
    "ControlLoss": TypeRule(("Town01", "interurban", "Town02", "suburb", "Town07", "Town05")),
    "CrossingBicycleFlow": TypeRule(
        ("downtown", "corridor", "suburb"),
        junction="left",
        control="signal",
        params=_flow((8, 12), (5, 15), (25, 30)),
    ),
    "DynamicObjectCrossing": TypeRule(
        SIDE,
        params=(
            ("distance", (40, 50)),
            ("direction", "right"),
            ("blocker_model", ("static.prop.advertisement", "static.prop.container")),
            ("crossing_angle", (0, 11)),
        ),
    ),
    "EnterActorFlow": TypeRule(URBAN_J, junction="turn", params=_flow((12, 19), (17, 30), (30, 39))),
    "HardBreakRoute": TypeRule(
        ("interurban", "Town01", "Town04", "Town03", "highway"), trigger_at=(12.0, 14.0)
    ),
    "HazardAtSideLane": TypeRule(
        MULTI,
        params=(
            ("distance", (41, 45)),
            ("speed", (32, 59)),
            ("bicycle_speed", (6, 12)),
            ("bicycle_drive_distance", (40, 101)),
        ),
    ),
    "HazardAtSideLaneTwoWays": TypeRule(
        TWO_WAY,
        params=(
            ("distance", (41, 45)),
            ("frequency", (75, 100)),
            ("bicycle_speed", (7, 11)),
            ("bicycle_drive_distance", (80, 116)),
        ),
    ),
    # the cut-in takes ~5 s at the CAV's speed past the ramp: upstream extends the road's exit by 170 m
    "HighwayCutIn": TypeRule(RAMP, junction="straight", control="nosignal", after_junction=(100.0, 150.0)),
    "HighwayExit": TypeRule(RAMP, junction="right", params=_flow((10, 15), (11, 20), (33, 46))),
    "InterurbanActorFlow": TypeRule(
        ("interurban", "Town04", "suburb", "Town05", "Town07", "Town03"),
        junction="left",
        params=_flow((15, 16), (42, 53), (78, 98)),
    ),
    "InterurbanAdvancedActorFlow": TypeRule(
        ("suburb", "Town01", "interurban", "Town02", "Town07", "Town03"),
        junction="turn",
        params=(*_flow((16, 18), (36, 42), (84, 94)), ("direction", "right")),
    ),
    "InvadingTurn": TypeRule(TWO_WAY, params=(("distance", (50, 60)), ("offset", (0.18, 0.34)))),
    "MergerIntoSlowTraffic": TypeRule(
        (*RAMP, "Town03", "Town05"), junction="any", params=_flow((9, 10), (14, 16), (33, 42))
    ),
    "MergerIntoSlowTrafficV2": TypeRule(
        (*RAMP, "Town03", "Town05"), junction="any", params=_flow((10, 10), (11, 14), (30, 34))
    ),
    "NonSignalizedJunctionLeftTurn": TypeRule(
        NOSIGNAL_J, junction="left", control="nosignal", params=_flow((8, 11), (15, 24), (25, 30))
    ),
    "NonSignalizedJunctionLeftTurnEnterFlow": TypeRule(
        NOSIGNAL_J, junction="left", control="nosignal", params=_flow((8, 10), (15, 19), (26, 30))
    ),
    "NonSignalizedJunctionRightTurn": TypeRule(
        NOSIGNAL_J, junction="right", control="nosignal", params=_flow((8, 14), (16, 22), (25, 30))
    ),
    # direction: by CAV 0's turn (_adversary_side)
    "OppositeVehicleRunningRedLight": TypeRule(SIGNAL_J, junction="any", control="signal"),
    "OppositeVehicleTakingPriority": TypeRule(NOSIGNAL_J, junction="any", control="nosignal"),
    "ParkedObstacle": TypeRule(
        MULTI, params=(("distance", (40, 43)), ("direction", "right"), ("speed", (40, 59)))
    ),
    "ParkedObstacleTwoWays": TypeRule(
        TWO_WAY, params=(("distance", (40, 44)), ("frequency", ((31, 56), (106, 151))))
    ),
    "ParkingCrossingPedestrian": TypeRule(
        SIDE, params=(("distance", (36, 45)), ("direction", "right"), ("crossing_angle", (0, 12)))
    ),
    "ParkingCutIn": TypeRule(SIDE, params=(("direction", "right"),)),
    "ParkingExit": TypeRule(
        PARKING,
        params=(
            ("direction", "right"),
            ("front_vehicle_distance", (9, 9)),
            ("behind_vehicle_distance", (9, 9)),
        ),
        trigger_at=(0.0, 0.0),
    ),
    "PedestrianCrossing": TypeRule(URBAN_J, junction="straight"),
    "SequentialLaneChange": TypeRule(MULTI, trigger_at=(0.0, 0.0), lane_shift=True),
    "SignalizedJunctionLeftTurn": TypeRule(
        SIGNAL_J, junction="left", control="signal", params=_flow((9, 11), (15, 24), (25, 28))
    ),
    "SignalizedJunctionLeftTurnEnterFlow": TypeRule(
        SIGNAL_J, junction="left", control="signal", params=_flow((8, 10), (16, 24), (25, 30))
    ),
    "SignalizedJunctionRightTurn": TypeRule(
        SIGNAL_J, junction="right", control="signal", params=_flow((10, 14), (19, 24), (26, 38))
    ),
    "StaticCutIn": TypeRule(MULTI, params=(("distance", (40, 45)), ("direction", "right"))),
    "T_Junction": TypeRule(
        ("Town01", "Town02", "Town07", "Town04", "suburb", "downtown", "Town03", "Town05"),
        junction="turn",
        three_way=True,
        trigger_at=(25.0, 31.0),
    ),
    "VanillaNonSignalizedTurn": TypeRule(NOSIGNAL_J, junction="right", control="nosignal"),
    "VanillaNonSignalizedTurnEncounterStopsign": TypeRule(STOP_J, junction="left", control="stop"),
    "VanillaSignalizedTurnEncounterGreenLight": TypeRule(SIGNAL_J, junction="turn", control="signal"),
    "VanillaSignalizedTurnEncounterRedLight": TypeRule(SIGNAL_J, junction="turn", control="signal"),
    "VehicleOpensDoorTwoWays": TypeRule(
        SIDE,
        params=(
            ("distance", (37, 59)),
            ("direction", "right"),
            ("frequency", ((30, 40), (89, 98))),
            ("speed", (40, 60)),
        ),
    ),
    "VehicleTurningRoute": TypeRule(URBAN_J, junction="turn"),
    "VehicleTurningRoutePedestrian": TypeRule(URBAN_J, junction="turn"),
    "YieldToEmergencyVehicle": TypeRule(
        ("interurban", "Town04", "highway", "Town06", "Town03", "Town05"), params=(("distance", (26, 30)),)
    ),
}


__all__ = ["RULES", "TRIGGER_AFTER_START", "TypeRule"]
