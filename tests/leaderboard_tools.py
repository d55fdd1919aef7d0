"""The arithmetic the leaderboard's and Bench2Drive's tools do on an exported run, re-implemented from
their documented behaviour (``tests/test_leaderboard_export.py`` checks that they give our numbers):
Bench2Drive's ``merge_route_json.py`` (DS = mean of ``score_composed``, success by status and infraction
lists), ``ability_benchmark.py`` (the ability groups of the route XML's scenario types, Traffic_Signs by
completion past the first junction) and ``efficiency_smoothness_benchmark.py`` (the first ``<number>%`` of
every min-speed message, values above 1000 dropped, mean per record, mean of records).
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

# Bench2Drive v0.0.4's ability groups, as its ability script lists them (test-side: their grouping)
THEIR_GROUPS: dict[str, set[str]] = {
    "Overtaking": {
        "Accident",
        "AccidentTwoWays",
        "ConstructionObstacle",
        "ConstructionObstacleTwoWays",
        "HazardAtSideLaneTwoWays",
        "HazardAtSideLane",
        "ParkedObstacleTwoWays",
        "ParkedObstacle",
        "VehicleOpensDoorTwoWays",
    },
    "Merging": {
        "CrossingBicycleFlow",
        "EnterActorFlow",
        "HighwayExit",
        "InterurbanActorFlow",
        "HighwayCutIn",
        "InterurbanAdvancedActorFlow",
        "MergerIntoSlowTrafficV2",
        "MergerIntoSlowTraffic",
        "NonSignalizedJunctionLeftTurn",
        "NonSignalizedJunctionRightTurn",
        "NonSignalizedJunctionLeftTurnEnterFlow",
        "ParkingExit",
        "SequentialLaneChange",
        "SignalizedJunctionLeftTurn",
        "SignalizedJunctionRightTurn",
        "SignalizedJunctionLeftTurnEnterFlow",
    },
    "Emergency_Brake": {
        "BlockedIntersection",
        "DynamicObjectCrossing",
        "HardBreakRoute",
        "OppositeVehicleTakingPriority",
        "OppositeVehicleRunningRedLight",
        "ParkingCutIn",
        "PedestrianCrossing",
        "ParkingCrossingPedestrian",
        "StaticCutIn",
        "VehicleTurningRoute",
        "VehicleTurningRoutePedestrian",
        "ControlLoss",
    },
    "Give_Way": {"InvadingTurn", "YieldToEmergencyVehicle"},
    "Traffic_Signs": {
        "BlockedIntersection",
        "OppositeVehicleTakingPriority",
        "OppositeVehicleRunningRedLight",
        "PedestrianCrossing",
        "VehicleTurningRoute",
        "VehicleTurningRoutePedestrian",
        "EnterActorFlow",
        "CrossingBicycleFlow",
        "NonSignalizedJunctionLeftTurn",
        "NonSignalizedJunctionRightTurn",
        "NonSignalizedJunctionLeftTurnEnterFlow",
        "SignalizedJunctionLeftTurn",
        "SignalizedJunctionRightTurn",
        "SignalizedJunctionLeftTurnEnterFlow",
        "T_Junction",
        "VanillaNonSignalizedTurn",
        "VanillaSignalizedTurnEncounterGreenLight",
        "VanillaSignalizedTurnEncounterRedLight",
        "VanillaNonSignalizedTurnEncounterStopsign",
    },
}
# every key their StatisticsManager gives a record's infractions
THEIR_INFRACTION_KEYS = {
    "collisions_layout",
    "collisions_pedestrian",
    "collisions_vehicle",
    "red_light",
    "stop_infraction",
    "outside_route_lanes",
    "min_speed_infractions",
    "yield_emergency_vehicle_infractions",
    "scenario_timeouts",
    "route_dev",
    "vehicle_blocked",
    "route_timeout",
}
SPEED_PERCENT = re.compile(r"\b\d+\.?\d*%")  # the number their efficiency script takes from a message
RECORD_ID = re.compile(r"^RouteScenario_(\d+)_rep(\d+)$")  # their StatisticsManager sorts records by it


def their_success(rec: dict[str, Any]) -> bool:
    return rec["status"] in ("Completed", "Perfect") and not any(
        v for k, v in rec["infractions"].items() if k != "min_speed_infractions"
    )


def their_merged_ds(records: list[dict[str, Any]]) -> float:
    return sum(r["scores"]["score_composed"] for r in records) / len(records)


def their_efficiency(records: list[dict[str, Any]]) -> float:
    per_record = []
    for rec in records:
        if not rec["infractions"]["min_speed_infractions"]:
            continue
        values = [
            float(SPEED_PERCENT.search(m).group().rstrip("%"))
            for m in rec["infractions"]["min_speed_infractions"]
        ]  # type: ignore[union-attr]
        kept = [v for v in values if v <= 1000]
        per_record.append(sum(kept) / len(kept))
    return sum(per_record) / len(per_record)


def their_abilities(
    records: list[dict[str, Any]], routes_xml: Path, junction: dict[str, float]
) -> dict[str, float]:
    """Success rate [%] per ability and the mean; ``junction[xml id]`` stands in for the share of the XML
    route up to its first junction + 8 points, which their script gets from CARLA's route planner."""
    stats = {name: [0, 0] for name in THEIR_GROUPS}
    for route in ET.parse(routes_xml).getroot().findall("route"):
        scenario = route.find("scenarios").find("scenario").get("type")  # type: ignore[union-attr]
        rec = next((r for r in records if r["route_id"].split("_")[1] == route.get("id")), None)
        assert rec is not None, f"no record for XML route {route.get('id')}"
        ok = their_success(rec)
        for name, types in THEIR_GROUPS.items():
            if scenario in types:
                stats[name][1] += 1
                stats[name][0] += ok
        if scenario in THEIR_GROUPS["Traffic_Signs"] and not ok:
            past = rec["scores"]["score_route"] / 100.0 > junction[str(route.get("id"))]
            if past and not rec["infractions"]["stop_infraction"] and not rec["infractions"]["red_light"]:
                stats["Traffic_Signs"][0] += 1
    # their script divides by zero for a group without routes: those are left out here, and the mean
    # (theirs: over the 5 groups) is over the groups present
    rates = {name: 100.0 * s / n for name, (s, n) in stats.items() if n}
    rates["mean"] = sum(rates.values()) / len(rates)
    return rates
