"""Export a ``cmudrive eval`` run as CARLA Leaderboard 2.0 / Bench2Drive results, for their own tools.

Users coming from the leaderboard and Bench2Drive have scripts that read the leaderboard's checkpoint
JSON (``_checkpoint.records`` with ``scores.score_composed``, ``infractions`` as message lists, ``meta``,
``global_record``, ``entry_status``), a leaderboard route XML whose ids match the records' ids
(``RouteScenario_<n>_rep0`` <-> ``<route id="<n>">``) and, for smoothness, one ``metric_info.json`` of
per-frame ego kinematics per route. Our ``results.json`` holds the same information in our own shape;
:func:`export_leaderboard` writes theirs from a run folder, without rounding what it does not have to, so
that their arithmetic reproduces ours where the definitions agree (``docs/formats.md``, "Leaderboard
export", says field by field how each value is filled and where the definitions differ).

A leaderboard "route" has one ego. ``per="cav"`` writes one record per CAV (a CAV is what an ego is):
scores RC_i, IS_i, RC_i x IS_i. ``per="route"`` writes one record per route with the paper's
multi-agent route scores RC^j, IS^j, DS^j and the infractions of all its CAVs.

Positions are written in CARLA's world frame (our map frame mirrored in y, ``cmudrive.maps.coords``):
infraction messages, route waypoints and every vector of ``metric_info.json``. Every minimum-speed
checkpoint is listed (Bench2Drive's criterion records one event per checkpoint; their efficiency is the
mean of all of them), with enough digits that their parse of the message gives back our value.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cmudrive.bench.records import (
    INFRACTION_KEYS,
    STATUS_COMPLETED,
    STATUS_PERFECT,
    CavResult,
    Infraction,
    RouteResult,
    record_stem,
)

PER_CAV = "cav"
PER_ROUTE = "route"
CHECKPOINT_FILE = "checkpoint.json"  # the leaderboard's --checkpoint file
ROUTES_FILE = "routes.xml"  # leaderboard route file with the records' ids
METRIC_INFO_FILE = "metric_info.json"  # per record, in OUT/<save_name>/ (Bench2Drive's layout)
DT = 0.05  # [s] one tick (20 Hz), the duration of a tick in ``meta.duration_game``
COMFORT_FRAMES = 20  # [frames] Bench2Drive's smoothness window: per-route metric_info keeps whole windows
MIN_KM_DRIVEN = 0.001  # [km] the leaderboard's floor on the distance driven in per-km rates
SPEED_DIGITS = 6  # [decimals] of a min-speed percentage in its message (the leaderboard writes 2)
POSITION_DIGITS = 3  # [decimals, m] of a position in a message, as the leaderboard
# infraction keys whose leaderboard message ends with the place "at (x=.., y=.., z=..)"
LOCATED_KEYS = frozenset(
    {
        "collisions_pedestrian",
        "collisions_vehicle",
        "collisions_layout",
        "red_light",
        "stop_infraction",
        "route_dev",
        "vehicle_blocked",
    }
)
OUTSIDE_KEY = "outside_route_lanes"
MIN_SPEED_KEY = "min_speed_infractions"
SCORE_KEYS = ("score_composed", "score_route", "score_penalty")
# the leaderboard's global "values", in the order of its "labels" (infraction keys or scores_mean keys)
LABELS: tuple[tuple[str, str], ...] = (
    ("Avg. driving score", "score_composed"),
    ("Avg. route completion", "score_route"),
    ("Avg. infraction penalty", "score_penalty"),
    ("Collisions with pedestrians", "collisions_pedestrian"),
    ("Collisions with vehicles", "collisions_vehicle"),
    ("Collisions with layout", "collisions_layout"),
    ("Red lights infractions", "red_light"),
    ("Stop sign infractions", "stop_infraction"),
    ("Off-road infractions", "outside_route_lanes"),
    ("Route deviations", "route_dev"),
    ("Route timeouts", "route_timeout"),
    ("Agent blocked", "vehicle_blocked"),
    ("Yield emergency vehicles infractions", "yield_emergency_vehicle_infractions"),
    ("Scenario timeouts", "scenario_timeouts"),
    ("Min speed infractions", "min_speed_infractions"),
)
_MAP_PLACE = re.compile(r" at \(x=[^()]*\)$")  # the map-frame place our criteria end a message with


class ExportError(ValueError):
    """A run folder that cannot be exported; the message names the file."""


@dataclass
class LeaderboardExport:
    """What :func:`export_leaderboard` wrote."""

    checkpoint: Path  # OUT/checkpoint.json
    routes: Path  # OUT/routes.xml
    metric_info: list[Path] = field(default_factory=list)  # OUT/<save_name>/metric_info.json
    records: int = 0  # leaderboard records written
    without_log: list[str] = field(default_factory=list)  # our route ids without a route log
    invalid: list[str] = field(default_factory=list)  # "Failed - Invalid route" routes, left out


# ------------------------------------------------------------------------------------------------------
# records


def lb_route_id(index: int) -> str:
    """The leaderboard's id of record ``index`` (its sort key and the route XML's ``id`` after the ``_``)."""
    return f"RouteScenario_{index}_rep0"


def _place(inf: Infraction) -> str:
    x, y = inf.carla_x, inf.carla_y
    return f"at (x={x:.{POSITION_DIGITS}f}, y={y:.{POSITION_DIGITS}f}, z=0.0)"


def infraction_message(inf: Infraction) -> str:
    """The leaderboard message of one of our infractions: our text, its place in CARLA's frame (our
    messages name the map frame's place)."""
    text = _MAP_PLACE.sub("", inf.message)
    return f"{text} {_place(inf)}" if inf.key in LOCATED_KEYS else text


def min_speed_message(percent: float) -> str:
    """Bench2Drive's message of one minimum-speed checkpoint [%], with ``SPEED_DIGITS`` decimals."""
    return f"Average speed is {percent:.{SPEED_DIGITS}f}% of the surrounding traffic's one"


def _outside_metres(c: CavResult) -> float:
    """[m] driven outside the route lanes: the share (1 - factor) of the completed route distance."""
    share = 1.0 - math.prod(i.factor for i in c.infractions.get(OUTSIDE_KEY, []))
    return share * c.route_length * c.route_completion / 100.0


def outside_message(metres: float, driven: float) -> str:
    """The leaderboard's outside-lanes message: its 9th word is the distance [m] (their global statistics
    read it there)."""
    percent = 100.0 * metres / driven if driven > 0.0 else 0.0
    return (
        f"Agent went outside its route lanes for about {metres:.{POSITION_DIGITS}f} meters "
        f"({percent:.2f}% of the completed route)"
    )


def _cav_infractions(c: CavResult, suffix: str = "") -> dict[str, list[str]]:
    """Every leaderboard key of one CAV, each a list of messages (``suffix`` names the CAV)."""
    out: dict[str, list[str]] = {k: [] for k in INFRACTION_KEYS}
    for key in INFRACTION_KEYS:
        if key in (OUTSIDE_KEY, MIN_SPEED_KEY):
            continue
        out[key] = [infraction_message(i) + suffix for i in c.infractions.get(key, [])]
    if c.infractions.get(OUTSIDE_KEY):
        driven = c.route_length * c.route_completion / 100.0
        out[OUTSIDE_KEY] = [outside_message(_outside_metres(c), driven) + suffix]
    out[MIN_SPEED_KEY] = [min_speed_message(v) + suffix for v in c.min_speed_checkpoints]
    return out


def _record(
    index: int,
    route: RouteResult,
    scenario_name: str,
    status: str,
    scores: tuple[float, float, float],
    infractions: dict[str, list[str]],
    meta: dict[str, Any],
) -> dict[str, Any]:
    town = Path(route.town).name.removesuffix(".net.xml")
    route_id = lb_route_id(index)
    save = record_stem(f"{route_id}_{town}_{scenario_name or 'none'}_{route.weather}")
    return {
        "index": index,
        "route_id": route_id,
        "scenario_name": scenario_name,
        "weather_id": route.weather,
        "save_name": save,
        "town_name": town,
        "status": status,
        "num_infractions": sum(len(v) for v in infractions.values()),
        "infractions": infractions,
        "scores": dict(zip(("score_route", "score_penalty", "score_composed"), scores, strict=True)),
        "meta": meta,
    }


def cav_records(
    routes: Sequence[RouteResult], scenario_names: Sequence[str]
) -> list[tuple[dict[str, Any], RouteResult, int]]:
    """One record per CAV, in route then CAV order, with (our route, CAV index) beside each. A CAV
    without a result (its route crashed before any CAV was scored) gets the route's status and scores
    0 / 1 / 0."""
    out: list[tuple[dict[str, Any], RouteResult, int]] = []
    for route, name in zip(routes, scenario_names, strict=True):
        for i in range(route.num_cavs):
            c = route.cavs[i] if i < len(route.cavs) else None
            meta = {
                "route_length": c.route_length if c else 0.0,
                "duration_game": (c.ticks if c else 0) * DT,
                "duration_system": route.wall_time / route.num_cavs,
                "cmudrive": {"route_id": route.route_id, "cav": i, "cav_id": c.cav_id if c else f"cav{i}"},
            }
            if c is None:
                empty: dict[str, list[str]] = {k: [] for k in INFRACTION_KEYS}
                rec = _record(len(out), route, name, route.status, (0.0, 1.0, 0.0), empty, meta)
            else:
                scores = (c.route_completion, c.infraction_score, c.driving_score)
                rec = _record(len(out), route, name, c.status, scores, _cav_infractions(c), meta)
            out.append((rec, route, i))
    return out


def route_records(
    routes: Sequence[RouteResult], scenario_names: Sequence[str]
) -> list[tuple[dict[str, Any], RouteResult, int]]:
    """One record per route with RC^j, IS^j, DS^j and every CAV's infractions (each message ends with
    the CAV's id in brackets, ``(cav1)``; the outside-lanes distances of all CAVs are summed into one
    message, as the leaderboard's global statistics read only the first); with (our route, -1) beside
    each."""
    out: list[tuple[dict[str, Any], RouteResult, int]] = []
    for j, (route, name) in enumerate(zip(routes, scenario_names, strict=True)):
        infractions: dict[str, list[str]] = {k: [] for k in INFRACTION_KEYS}
        for c in route.cavs:
            for key, messages in _cav_infractions(c, f" ({c.cav_id})").items():
                if key != OUTSIDE_KEY:
                    infractions[key] += messages
        outside = [c for c in route.cavs if c.infractions.get(OUTSIDE_KEY)]
        if outside:
            metres = math.fsum(_outside_metres(c) for c in outside)
            driven = math.fsum(c.route_length * c.route_completion / 100.0 for c in route.cavs)
            infractions[OUTSIDE_KEY] = [outside_message(metres, driven)]
        meta = {
            "route_length": math.fsum(c.route_length for c in route.cavs),
            "duration_game": route.ticks * DT,
            "duration_system": route.wall_time,
            "cmudrive": {"route_id": route.route_id, "num_cavs": route.num_cavs},
        }
        scores = (route.route_completion, route.infraction_score, route.driving_score)
        out.append((_record(j, route, name, route.status, scores, infractions, meta), route, -1))
    return out


# ------------------------------------------------------------------------------------------------------
# global record and the checkpoint file


def global_record(records: Sequence[dict[str, Any]], total: int) -> dict[str, Any]:
    """The leaderboard's ``global_record`` over ``records``, ``total`` routes expected: score means over
    ``total`` and their sample standard deviations, infractions per km driven (outside lanes: km), the
    status downgraded Perfect -> Completed -> Failed with the failed records in ``meta.exceptions``. Not
    rounded (the leaderboard rounds to 3 and 6 decimals)."""
    n = max(total, 1)
    means = {k: math.fsum(r["scores"][k] for r in records) / n for k in SCORE_KEYS}
    if total <= 1:
        std = dict.fromkeys(SCORE_KEYS, 0.0)
    else:
        std = {
            k: math.sqrt(math.fsum((r["scores"][k] - means[k]) ** 2 for r in records) / (total - 1))
            for k in SCORE_KEYS
        }
    km = max(
        math.fsum(r["meta"]["route_length"] / 1000.0 * r["scores"]["score_route"] / 100.0 for r in records),
        MIN_KM_DRIVEN,
    )
    per_km: dict[str, float] = {}
    for key in INFRACTION_KEYS:
        if key == OUTSIDE_KEY:  # the distance outside [km], from the messages' 9th word, not per km
            per_km[key] = math.fsum(
                float(r["infractions"][key][0].split(" ")[8]) / 1000.0
                for r in records
                if r["infractions"][key]
            )
        else:
            per_km[key] = sum(len(r["infractions"][key]) for r in records) / km
    status, exceptions = STATUS_PERFECT, []
    for r in records:
        if "Failed" in r["status"]:
            exceptions.append([r["route_id"], r["index"], r["status"]])
            status = "Failed"
        elif status == STATUS_PERFECT and r["status"] != STATUS_PERFECT:
            status = STATUS_COMPLETED
    return {
        "index": -1,
        "route_id": -1,
        "status": status,
        "infractions": per_km,
        "scores_mean": means,
        "scores_std_dev": std,
        "meta": {
            "total_length": math.fsum(r["meta"]["route_length"] for r in records),
            "duration_game": math.fsum(r["meta"]["duration_game"] for r in records),
            "duration_system": math.fsum(r["meta"]["duration_system"] for r in records),
            "exceptions": exceptions,
        },
    }


def checkpoint(records: Sequence[dict[str, Any]], total: int) -> dict[str, Any]:
    """The whole leaderboard results file: ``_checkpoint`` (global record, progress, records),
    ``entry_status``, ``eligible``, ``sensors``, ``values``, ``labels``."""
    glob = global_record(records, total)
    crashed = any("Simulation crashed" in r["status"] for r in records)
    entry_status = "Crashed" if crashed else "Finished"

    def value(key: str) -> str:
        return str(glob["scores_mean"][key] if key in SCORE_KEYS else glob["infractions"][key])

    return {
        "_checkpoint": {"global_record": glob, "progress": [len(records), total], "records": list(records)},
        "entry_status": entry_status,
        "eligible": entry_status == "Finished",
        "sensors": [],
        "values": [value(key) for _, key in LABELS],
        "labels": [label for label, _ in LABELS],
    }
