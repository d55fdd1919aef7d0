"""The console summary of `cmudrive eval`: why each failed route failed, per CAV."""

from __future__ import annotations

from cmudrive.cli.results import failures


def cav(cav_id: str, status: str, **infractions: int) -> dict[str, object]:
    return {
        "cav_id": cav_id,
        "status": status,
        "infractions": {k: [{"tick": t} for t in range(n)] for k, n in infractions.items()},
    }


def test_failures_name_each_cav_its_status_and_infractions() -> None:
    route = {
        "status": "Failed - Agent got blocked",
        "cavs": [
            cav("cav0", "Perfect", min_speed_infractions=3),
            cav("cav1", "Failed - Agent got blocked", vehicle_blocked=1, min_speed_infractions=1),
            cav("cav2", "Completed", collisions_vehicle=1, red_light=2),
        ],
    }
    # the blocked status is not repeated as an infraction; minimum speed (no penalty) is left out
    assert failures(route) == "cav1: got blocked; cav2: collisions_vehicle, red_light"


def test_a_crashed_route_without_cav_records_says_its_status() -> None:
    route = {"status": "Failed - Simulation crashed", "error": "Traceback ...", "cavs": []}
    assert failures(route) == "Failed - Simulation crashed"
