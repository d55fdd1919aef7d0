"""Result records: what one CAV and one route score, as plain dataclasses that serialise to JSON.

These are the shared vocabulary of the criteria (which fill them), the metrics (which aggregate them),
the evaluator (which writes one JSON file per finished route) and the report. Keys follow the CARLA
leaderboard / Bench2Drive results files where they exist (``reference/SCORING.md``).
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import tempfile
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

# infraction keys, as in leaderboard results files, with their penalty factor (None: not a fixed factor)
PENALTIES: dict[str, float | None] = {
    "collisions_pedestrian": 0.50,
    "collisions_vehicle": 0.60,
    "collisions_layout": 0.65,
    "red_light": 0.70,
    "stop_infraction": 0.80,
    "scenario_timeouts": 0.70,
    "yield_emergency_vehicle_infractions": 0.70,
    "outside_route_lanes": None,  # factor 1 - percent / 100, percent of the route driven outside
    "min_speed_infractions": None,  # recorded only (Bench2Drive): factor 1
    "route_dev": None,  # ends the CAV's evaluation, no factor
    "vehicle_blocked": None,  # ends the CAV's evaluation, no factor
    "route_timeout": None,  # ends the CAV's evaluation, no factor
}
INFRACTION_KEYS: tuple[str, ...] = tuple(PENALTIES)

STATUS_RUNNING = "Running"
STATUS_PERFECT = "Perfect"
STATUS_COMPLETED = "Completed"
STATUS_DEVIATED = "Failed - Agent deviated from the route"
STATUS_BLOCKED = "Failed - Agent got blocked"
STATUS_TIMEOUT = "Failed - Agent timed out"
STATUS_TICK_CAP = "Failed - TickRuntime"
STATUS_AGENT_CRASHED = "Failed - Agent crashed"
STATUS_SIM_CRASHED = "Failed - Simulation crashed"


@dataclass
class Infraction:
    """One infraction event of one CAV."""

    key: str  # one of INFRACTION_KEYS
    tick: int  # tick of the event (0 = first tick of the route)
    time: float  # simulated time [s]
    x: float  # map frame [m]
    y: float  # map frame [m]
    message: str  # human-readable, as in leaderboard results
    factor: float = 1.0  # multiplier applied to the CAV's infraction score (1.0: recorded only)
    actor: str | None = None  # the other actor (collisions, emergency vehicle), else None


@dataclass
class CavResult:
    """Scores of one CAV on one route."""

    cav_id: str
    status: str
    route_completion: float  # RC_i [%], 0..100
    infraction_score: float  # IS_i, 0..1
    route_length: float  # [m] of its dense route
    infractions: dict[str, list[Infraction]] = field(default_factory=lambda: {k: [] for k in INFRACTION_KEYS})
    min_speed_checkpoints: list[float] = field(default_factory=list)  # [%] ego / traffic speed per checkpoint
    comfort: float | None = None  # share of comfortable 20-frame windows (Bench2Drive "smoothness")
    ticks: int = 0  # ticks the CAV was evaluated
    # [%] route completion at which the CAV is past its route's first junction (Bench2Drive: the first
    # junction point of the dense route + 8 points, as a share of the route); None: unknown or no junction.
    # Read by the Traffic_Signs ability (``metrics.passes_traffic_signs``).
    first_junction_completion: float | None = None

    @property
    def driving_score(self) -> float:
        return max(self.route_completion * self.infraction_score, 0.0)


@dataclass
class RouteResult:
    """Scores of one route (2-16 CAVs), with the paper's aggregation (``metrics.route_scores``)."""

    route_id: str
    town: str
    weather: str
    scenario_type: str  # type of the route's (first) scenario, "" when it has none
    num_cavs: int
    status: str  # the route's status: "Perfect", "Completed", or the first CAV failure / crash
    route_completion: float  # RC^j [%]: mean over CAVs
    infraction_score: float  # IS^j: product over CAVs
    driving_score: float  # DS^j = RC^j * IS^j
    success: bool  # SS^j: DS^j == 100
    cavs: list[CavResult] = field(default_factory=list)
    seed: int = 0
    ticks: int = 0  # ticks simulated
    wall_time: float = 0.0  # [s]
    error: str | None = None  # traceback text when the agent or the simulation crashed
    # False while the route's scenario behaviour is not simulated yet (the scenario engine has not landed:
    # the route is scored under its type, but no scenario actor ran); None for a route without scenario
    scenario_simulated: bool | None = None
    # V2V link counters (messages, received, dropped, out_of_range, not_yet, bytes, bytes_per_message) for
    # agents that take part in V2V; None otherwise
    v2v: dict[str, float] | None = None
    # what produced the record (the runner stamps it; bench/manifest.py): setup_sha256 (the run's setup in
    # OUT/run.json), route_sha256 (the route as run, routes.route_sha256) and code (the code version)
    provenance: dict[str, Any] | None = None

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @staticmethod
    def from_json(data: dict[str, Any]) -> RouteResult:
        cavs = []
        for c in data.get("cavs", []):
            c = dict(c)
            c["infractions"] = {k: [Infraction(**i) for i in v] for k, v in c.get("infractions", {}).items()}
            cavs.append(CavResult(**c))
        fields = {k: v for k, v in data.items() if k != "cavs"}
        return RouteResult(cavs=cavs, **fields)


RECORD_STEM_CHARS = 80  # longest route id used as a file name as it is
_SAFE_ID = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9_.-]*", re.ASCII)


def record_stem(route_id: str) -> str:
    """File name stem of a route's record and log. An id of letters, digits and ``_.-`` (not starting
    with a dot) up to ``RECORD_STEM_CHARS`` long is its own stem (``smoke_00.json``); any other id gets
    its file-safe form cut to that length, ``~`` and a hash of the exact id. No safe id contains ``~``, so
    two ids never share a file ("a/b" and "a_b"), and a long id never makes a name the file system
    refuses."""
    if len(route_id) <= RECORD_STEM_CHARS and _SAFE_ID.fullmatch(route_id):
        return route_id
    readable = "".join(c if c.isascii() and (c.isalnum() or c in "-_.") else "_" for c in route_id)
    digest = hashlib.sha256(route_id.encode("utf-8", "surrogatepass")).hexdigest()[:12]
    return f"{readable[:RECORD_STEM_CHARS].lstrip('.')}~{digest}"


def write_json_atomic(path: Path, data: Any) -> None:
    """Write JSON to ``path`` through a temporary file and a rename, with the umask's permissions."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".tmp.", suffix=".json", dir=path.parent)  # short: ids can be long
    try:
        with os.fdopen(fd, "w") as fh:
            json.dump(data, fh, indent=1)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp's 0600 would hide the results from other users
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
