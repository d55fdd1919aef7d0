"""Result records: what one CAV and one route score, as plain dataclasses that serialise to JSON.

These are the shared vocabulary of the criteria (which fill them), the metrics (which aggregate them),
the evaluator (which writes one JSON file per finished route) and the report. Keys follow the CARLA
leaderboard / Bench2Drive results files where they exist (``reference/SCORING.md``).

A record read back (``RouteResult.from_json``: the report, ``--resume``, the workers' results) is
checked (:func:`record_problems`) before anything is computed from it: every field of its type, scores
finite and in range (RC in [0, 100] %, IS in [0, 1], DS in [0, 100]), statuses known, CAV counts 1 to
``MAX_RECORD_CAVS``, and the scores consistent with each other as ``metrics.route_result`` makes them
(DS = RC x IS, success exactly when DS = 100, a success only with status Perfect or Completed, a
Perfect route a success, RC the mean and IS the product of the CAVs' values), and each infraction's
CARLA-frame place the mirror image of its map-frame place (``Infraction``). A record that breaks one
raises ``ValueError`` naming the route and the field: a hand-edited or crafted results file is refused,
never averaged into a summary.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
import tempfile
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, TypeGuard

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
# the route cannot run (unknown town, unplannable waypoints, a bad scenario parameter; found before the run
# starts, ``cmudrive eval --skip-invalid``): not scored, left out of DS / SR / RC and counted apart
STATUS_INVALID_ROUTE = "Failed - Invalid route"


@dataclass
class Infraction:
    """One infraction event of one CAV.

    The place is given in both frames: ``x``, ``y`` in the map frame (SUMO's network frame, x east, y
    north), ``carla_x``, ``carla_y`` in CARLA's world frame, the frame of route files and leaderboard
    results (the mirror image in y: ``cmudrive.maps.coords``). The CARLA pair is derived from the map pair
    when not given (records written before it existed read back with it filled in), and a record whose
    pairs disagree is refused (``record_problems``)."""

    key: str  # one of INFRACTION_KEYS
    tick: int  # tick of the event (0 = first tick of the route)
    time: float  # simulated time [s]
    x: float  # map frame [m]
    y: float  # map frame [m]
    message: str  # human-readable, as in leaderboard results; coordinates in it are map frame
    factor: float = 1.0  # multiplier applied to the CAV's infraction score (1.0: recorded only)
    actor: str | None = None  # the other actor (collisions, emergency vehicle), else None
    carla_x: float | None = None  # CARLA world frame [m] (= x); None on input: derived from x
    carla_y: float | None = None  # CARLA world frame [m] (= -y); None on input: derived from y

    def __post_init__(self) -> None:
        if self.carla_x is None and _is_number(self.x):
            self.carla_x = float(self.x)
        if self.carla_y is None and _is_number(self.y):
            self.carla_y = -float(self.y)


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
    # the agent's destroy() raised or overran after the route's ticks: the scores and statuses stand
    cleanup_error: str | None = None
    # False while the route's scenario behaviour is not simulated yet (the scenario engine has not landed:
    # the route is scored under its type, but no scenario actor ran); None for a route without scenario
    scenario_simulated: bool | None = None
    # V2V link counters (messages, received, dropped, out_of_range, not_yet, bytes, bytes_per_message,
    # cav_ticks, named, named_taken: v2v.link.LinkStats) for agents that take part in V2V; None otherwise
    v2v: dict[str, float] | None = None
    # what produced the record (the runner stamps it; bench/manifest.py): setup_sha256 (the run's setup in
    # OUT/run.json), route_sha256 (the route as run, routes.route_sha256) and code (the code version)
    provenance: dict[str, Any] | None = None

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @staticmethod
    def from_json(data: dict[str, Any]) -> RouteResult:
        """The record of ``to_json`` output; ``ValueError`` naming the route and the field when the data
        is not a valid, self-consistent record (:func:`record_problems`), ``TypeError`` on unknown or
        missing keys."""
        if not isinstance(data, dict):
            raise ValueError(f"a route record must be an object, got {type(data).__name__}")
        cav_data = data.get("cavs", [])
        if not isinstance(cav_data, list) or not all(isinstance(c, dict) for c in cav_data):
            raise ValueError(f"route {_short(data.get('route_id'))}: cavs must be a list of objects")
        cavs = []
        for c in cav_data:
            c = dict(c)
            infractions = c.get("infractions", {})
            if not isinstance(infractions, dict) or not all(
                isinstance(v, list) and all(isinstance(i, dict) for i in v) for v in infractions.values()
            ):
                raise ValueError(
                    f"route {_short(data.get('route_id'))}: infractions must map keys to lists of objects"
                )
            c["infractions"] = {k: [Infraction(**i) for i in v] for k, v in infractions.items()}
            cavs.append(CavResult(**c))
        fields = {k: v for k, v in data.items() if k != "cavs"}
        record = RouteResult(cavs=cavs, **fields)
        problems = record_problems(record)
        if problems:
            raise ValueError(f"route {_short(record.route_id)}: {'; '.join(problems[:5])}")
        return record


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


# ------------------------------------------------------------------------------------- record validation
MAX_ROUTE_ID_CHARS = 255  # [-] a route id (a file-name length): printable characters only, no control
MAX_TEXT_CHARS = 4096  # [-] town (a name or a .net.xml path: PATH_MAX), weather, scenario type
MAX_RECORD_CAVS = 16  # [-] CAVs of a route (routes.MAX_CAVS)
SCORE_TOLERANCE = 1e-6  # [score points] DS = RC x IS and RC = mean of the CAVs' RC_i within this
SUCCESS_TOLERANCE = 1e-9  # [score points] DS counts as 100 within this (metrics.SUCCESS_TOLERANCE)
COORD_TOLERANCE = 1e-9  # [-] relative: an infraction's CARLA-frame pair equals its mirrored map pair
# every STATUS_* string defined above (a status added there is known here without a second list)
STATUSES = frozenset(v for k, v in dict(globals()).items() if k.startswith("STATUS_") and isinstance(v, str))


def route_id_problem(route_id: object) -> str | None:
    """Why ``route_id`` cannot be a route id, or None: ids are 1 to ``MAX_ROUTE_ID_CHARS`` printable
    characters (no newline, tab or other control character), as they go into messages, file names and
    CSV rows. The committed sets use ``<Type>_<k>`` ids up to 49 characters; Bench2Drive's are numbers."""
    if not isinstance(route_id, str) or not route_id:
        return f"route id must be a non-empty string, got {_short(route_id)}"
    if len(route_id) > MAX_ROUTE_ID_CHARS:
        return (
            f"route id {_short(route_id)} is {len(route_id)} characters long (at most {MAX_ROUTE_ID_CHARS})"
        )
    bad = sorted({c for c in route_id if not c.isprintable()})
    if bad:
        return f"route id {_short(route_id)} holds unprintable characters {bad} (printable ones only)"
    return None


def _short(value: object, chars: int = 40) -> str:
    text = repr(value)
    return text if len(text) <= chars else f"{text[:chars]}..."


def _is_number(value: object) -> TypeGuard[float]:
    """An int or float that is not a bool (NaN and infinities included)."""
    return isinstance(value, int | float) and not isinstance(value, bool)


def _finite(value: object) -> TypeGuard[float]:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _number(value: object, name: str, lo: float, hi: float, problems: list[str]) -> bool:
    """Append a problem unless ``value`` is a finite int/float (not a bool) in [lo, hi]."""
    if not _finite(value):
        problems.append(f"{name} must be a finite number, got {_short(value)}")
        return False
    if not lo <= value <= hi:
        problems.append(f"{name} must be in [{lo:g}, {hi:g}], got {value!r}")
        return False
    return True


def _integer(value: object, name: str, lo: int, hi: float, problems: list[str]) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        problems.append(f"{name} must be an integer in [{lo}, {hi:g}], got {_short(value)}")


def _cav_problems(c: CavResult, problems: list[str]) -> bool:
    """Problems of one CAV's record; True when its RC_i and IS_i are usable numbers."""
    where = f"CAV {_short(c.cav_id)}"
    if not isinstance(c.cav_id, str):
        problems.append(f"{where}: cav_id must be a string")
    if c.status not in STATUSES:
        problems.append(f"{where}: unknown status {_short(c.status)}")
    ok = _number(c.route_completion, f"{where}: route_completion", 0.0, 100.0, problems)
    ok &= _number(c.infraction_score, f"{where}: infraction_score", 0.0, 1.0, problems)
    _number(c.route_length, f"{where}: route_length", 0.0, math.inf, problems)
    _integer(c.ticks, f"{where}: ticks", 0, math.inf, problems)
    for name in ("comfort", "first_junction_completion"):
        value = getattr(c, name)
        if value is not None:
            _number(value, f"{where}: {name}", 0.0, 1.0 if name == "comfort" else 100.0, problems)
    if not isinstance(c.min_speed_checkpoints, list):
        problems.append(f"{where}: min_speed_checkpoints must be a list")
    else:
        for v in c.min_speed_checkpoints:
            if not _number(v, f"{where}: min_speed_checkpoints", 0.0, math.inf, problems):
                break
    for key, events in c.infractions.items():
        if key not in PENALTIES:
            problems.append(f"{where}: unknown infraction key {_short(key)}")
        for e in events:
            if not isinstance(e.key, str) or not isinstance(e.message, str):
                problems.append(f"{where}: {key} infraction key and message must be strings")
            _integer(e.tick, f"{where}: {key} tick", 0, math.inf, problems)
            _number(e.factor, f"{where}: {key} factor", 0.0, 1.0, problems)
            numbers = ("time", "x", "y", "carla_x", "carla_y")
            for name in numbers:  # NaN where the CAV's position was unknown: shown, not scored
                value = getattr(e, name)
                if not _is_number(value):
                    problems.append(f"{where}: {key} {name} must be a number, got {_short(value)}")
            if all(_is_number(getattr(e, n)) for n in numbers) and not _same_place(e):
                problems.append(
                    f"{where}: {key} carla_x, carla_y ({e.carla_x!r}, {e.carla_y!r}) are not the map "
                    f"frame's x, -y ({e.x!r}, {-e.y!r})"
                )
    return ok


def _same_place(e: Infraction) -> bool:
    """The CARLA-frame pair is the map-frame pair mirrored in y (NaN where the map pair is NaN)."""
    assert e.carla_x is not None and e.carla_y is not None
    return all(
        a == b or (math.isnan(a) and math.isnan(b)) or abs(a - b) <= COORD_TOLERANCE * max(1.0, abs(a))
        for a, b in ((e.carla_x, e.x), (e.carla_y, -e.y))
    )


def record_problems(r: RouteResult) -> list[str]:
    """What is wrong with a route record (empty: nothing); see the module docstring for the rules."""
    problems: list[str] = []
    id_problem = route_id_problem(r.route_id)
    if id_problem:
        problems.append(id_problem)
    for name in ("town", "weather", "scenario_type"):
        value = getattr(r, name)
        if not isinstance(value, str) or len(value) > MAX_TEXT_CHARS or not value.isprintable():
            problems.append(f"{name} must be a string of at most {MAX_TEXT_CHARS} printable characters")
    before = len(problems)
    _integer(r.num_cavs, "num_cavs", 1, MAX_RECORD_CAVS, problems)
    if len(problems) == before and len(r.cavs) > r.num_cavs:
        problems.append(f"{len(r.cavs)} CAV results for num_cavs {r.num_cavs}")
    if r.status not in STATUSES:
        problems.append(f"unknown status {_short(r.status)}")
    _integer(r.seed, "seed", 0, 2**31 - 1, problems)
    _integer(r.ticks, "ticks", 0, math.inf, problems)
    _number(r.wall_time, "wall_time", 0.0, math.inf, problems)
    if r.error is not None and not isinstance(r.error, str):
        problems.append("error must be a string or null")
    if r.scenario_simulated is not None and not isinstance(r.scenario_simulated, bool):
        problems.append("scenario_simulated must be true, false or null")
    if r.v2v is not None and (
        not isinstance(r.v2v, dict)
        or not all(
            isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
            for v in r.v2v.values()
        )
    ):
        problems.append("v2v must map counter names to finite numbers")
    cavs_ok = all([_cav_problems(c, problems) for c in r.cavs])
    if not isinstance(r.success, bool):
        problems.append(f"success must be true or false, got {_short(r.success)}")
    scores_ok = _number(r.route_completion, "route_completion", 0.0, 100.0, problems)
    scores_ok &= _number(r.infraction_score, "infraction_score", 0.0, 1.0, problems)
    scores_ok &= _number(r.driving_score, "driving_score", 0.0, 100.0, problems)
    if not scores_ok or not isinstance(r.success, bool):
        return problems
    if abs(r.driving_score - r.route_completion * r.infraction_score) > SCORE_TOLERANCE:
        problems.append(
            f"driving_score {r.driving_score!r} is not route_completion x infraction_score "
            f"({r.route_completion!r} x {r.infraction_score!r})"
        )
    if r.success != (abs(r.driving_score - 100.0) <= SUCCESS_TOLERANCE):
        problems.append(f"success {r.success} with driving_score {r.driving_score!r} (success is DS = 100)")
    if r.success and r.status not in (STATUS_PERFECT, STATUS_COMPLETED):
        problems.append(f"success with status {r.status!r} (only a Perfect or Completed route succeeds)")
    if r.status == STATUS_PERFECT and not r.success:
        problems.append("status Perfect without success")
    if r.cavs and cavs_ok:
        rc = math.fsum(c.route_completion for c in r.cavs) / len(r.cavs)
        is_ = math.prod(c.infraction_score for c in r.cavs)
        if abs(rc - r.route_completion) > SCORE_TOLERANCE or abs(is_ - r.infraction_score) > SCORE_TOLERANCE:
            problems.append(
                f"route_completion {r.route_completion!r} / infraction_score {r.infraction_score!r} are not "
                f"the mean / product of the CAVs' ({rc!r} / {is_!r})"
            )
    return problems
