"""``cmudrive export RUN --format leaderboard``: a run folder's results as leaderboard files on disk.

Reads ``RUN/results.json`` (our route records), the route file the run evaluated (named in
``RUN/run.json``, or given) and the route logs of ``--record`` (``RUN/logs/<stem>.npz``), and writes::

    OUT/checkpoint.json                    the leaderboard checkpoint (``leaderboard.checkpoint``)
    OUT/routes.xml                         a leaderboard route file whose ids match the records
    OUT/<save_name>/metric_info.json       per record whose route has a log: per-frame ego kinematics

The records and their arithmetic are in ``cmudrive.bench.leaderboard``; this module finds the inputs,
checks them (each problem an ``ExportError`` naming the file) and writes the route XML and the
``metric_info.json`` frames. Field by field: ``docs/formats.md``, "Leaderboard export".
"""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from cmudrive.bench.leaderboard import (
    CHECKPOINT_FILE,
    COMFORT_FRAMES,
    METRIC_INFO_FILE,
    PER_CAV,
    PER_ROUTE,
    ROUTES_FILE,
    ExportError,
    LeaderboardExport,
    cav_records,
    checkpoint,
    route_records,
)
from cmudrive.bench.records import STATUS_INVALID_ROUTE, RouteResult, record_stem, write_json_atomic
from cmudrive.maps.coords import map_yaw_to_carla

RESULTS_FILE = "results.json"
MANIFEST_FILE = "run.json"
LOGS_DIR = "logs"
FORMATS = ("leaderboard",)


# ------------------------------------------------------------------------------------------------------
# inputs


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise ExportError(f"{path}: cannot be read as JSON ({exc})") from None


def load_run(run: Path) -> tuple[list[RouteResult], int]:
    """The route records of ``RUN/results.json`` and the number of routes the run expected (its summary's
    ``num_expected``, else the records)."""
    from cmudrive.bench.report import ResultsError, load_results

    run = Path(run)
    if not run.is_dir():
        raise ExportError(f"{run}: not a folder (expected the output folder of cmudrive eval)")
    path = run / RESULTS_FILE
    if not path.is_file():
        raise ExportError(f"{path}: no such file; {run} is not the output folder of a cmudrive eval run")
    try:
        routes = load_results(path)
    except ResultsError as exc:
        raise ExportError(str(exc)) from None
    data = _read_json(path)
    summary = data.get("summary") if isinstance(data, dict) else None
    expected = summary.get("num_expected") if isinstance(summary, dict) else None
    total = expected if isinstance(expected, int) and expected >= len(routes) else len(routes)
    return routes, total


def route_file_of(run: Path) -> Path:
    """The route file ``RUN/run.json`` names (its latest invocation's)."""
    path = Path(run) / MANIFEST_FILE
    if not path.is_file():
        raise ExportError(
            f"{path}: no such file, so the route file of the run is unknown: pass --routes FILE"
        )
    manifest = _read_json(path)
    runs = manifest.get("runs") if isinstance(manifest, dict) else None
    entry = runs[-1].get("routes") if isinstance(runs, list) and runs and isinstance(runs[-1], dict) else None
    name = entry.get("file") if isinstance(entry, dict) else None
    if not isinstance(name, str):
        raise ExportError(f"{path} names no route file (a run started from Python): pass --routes FILE")
    return Path(name)


def route_specs(routes: Sequence[RouteResult], routes_file: Path, named_by: str) -> list[Any]:
    """The ``RouteSpec`` of every record from ``routes_file``, checked against the records' route hashes
    (``provenance.route_sha256``) so that the exported waypoints are the ones the run drove."""
    from cmudrive.bench.routes import RouteSpecError, read_routes, route_sha256

    if not routes_file.is_file():
        raise ExportError(f"route file {routes_file} ({named_by}) does not exist: pass --routes FILE")
    try:
        by_id = {s.id: s for s in read_routes(routes_file)}
    except (RouteSpecError, OSError) as exc:
        raise ExportError(f"route file {routes_file}: {exc}") from None
    specs = []
    for r in routes:
        spec = by_id.get(r.route_id)
        if spec is None:
            raise ExportError(f"route file {routes_file} has no route {r.route_id!r} of the results")
        if len(spec.cavs) != r.num_cavs:
            raise ExportError(
                f"route {r.route_id!r} of {routes_file} has {len(spec.cavs)} CAVs, its record {r.num_cavs}: "
                "pass the route file of the run with --routes"
            )
        want = (r.provenance or {}).get("route_sha256")
        if isinstance(want, str) and route_sha256(spec) != want:
            raise ExportError(
                f"route {r.route_id!r} of {routes_file} is not the route the run evaluated (its waypoints, "
                "town, weather, seed or scenarios differ): pass the route file of the run with --routes"
            )
        specs.append(spec)
    return specs


# ------------------------------------------------------------------------------------------------------
# route XML


def _num(value: float) -> str:
    return repr(float(value))


def _weathers(name: str) -> ET.Element:
    """The preset's CARLA parameters at the route's start and end (``route_percentage`` 0 and 100)."""
    from cmudrive.sim.weather import get_weather

    w = get_weather(name)
    params = {
        "cloudiness": w.cloudiness,
        "precipitation": w.precipitation,
        "fog_density": w.fog_density,
        "wetness": w.wetness,
        "sun_altitude_angle": w.sun_altitude_deg,
    }
    block = ET.Element("weathers")
    for percentage in ("0", "100"):
        ET.SubElement(
            block, "weather", {"route_percentage": percentage, **{k: _num(v) for k, v in params.items()}}
        )
    return block


def route_element(lb_id: int, record: dict[str, Any], spec: Any, cav: int) -> ET.Element:
    """One leaderboard ``<route>``: id ``lb_id``, the record's town, CAV ``cav``'s waypoints (CARLA frame,
    as in our route file), the route's scenarios and its weather preset's CARLA parameters."""
    from cmudrive.bench.routes import _route_to_xml

    elem = ET.Element("route", {"id": str(lb_id), "town": record["town_name"]})
    ours = _route_to_xml(spec)
    elem.append(ours.find(f"cav[@id='{cav}']/waypoints"))  # type: ignore[arg-type]
    scenarios = ours.find("scenarios")
    elem.append(scenarios if scenarios is not None else ET.Element("scenarios"))
    elem.append(_weathers(spec.weather))
    return elem


def write_route_xml(
    path: Path, rows: Sequence[tuple[dict[str, Any], RouteResult, int]], specs: dict[str, Any]
) -> None:
    root = ET.Element("routes")
    for record, route, cav in rows:
        root.append(ET.Comment(f" cmudrive route {route.route_id}" + (f", CAV {cav} " if cav >= 0 else " ")))
        root.append(route_element(record["index"], record, specs[route.route_id], max(cav, 0)))
    ET.indent(root, space="  ")
    tmp = path.with_name(f".tmp.{path.name}")
    ET.ElementTree(root).write(tmp, encoding="utf-8", xml_declaration=True)
    tmp.replace(path)


# ------------------------------------------------------------------------------------------------------
# metric_info.json


def metric_frames(pose: np.ndarray, ticks: np.ndarray, dt: float) -> list[dict[str, list[float]]]:
    """Bench2Drive's per-frame ego record (``get_metric_info``) of one CAV, CARLA frame.

    ``pose`` (n, 4): x [m], y [m], yaw [rad], speed [m/s] in the map frame at log ticks ``ticks`` (n,),
    ``dt`` [s] per tick. Each frame: ``location`` [x, y, z] [m] (z 0: our maps are flat), ``rotation``
    [roll, pitch, yaw] [deg] (CARLA yaw: clockwise), ``forward_vector`` and ``right_vector`` (unit),
    ``acceleration`` [m/s^2] (the time derivative of speed x forward, central differences) and
    ``angular_velocity`` [deg/s] (z: the derivative of CARLA's yaw), as CARLA reports them."""
    n = len(ticks)
    if n == 0:
        return []
    t = np.asarray(ticks, np.float64) * dt
    yaw = np.unwrap(pose[:, 2])
    cos, sin = np.cos(yaw), np.sin(yaw)
    forward = np.column_stack([cos, -sin])  # CARLA frame: y mirrored
    right = np.column_stack([sin, cos])
    velocity = pose[:, 3:4] * forward
    if n >= 2:
        accel = np.gradient(velocity, t, axis=0)
        yaw_rate = -np.degrees(np.gradient(yaw, t))  # [deg/s], CARLA's yaw turns the other way
    else:
        accel, yaw_rate = np.zeros((1, 2)), np.zeros(1)
    carla_yaw = map_yaw_to_carla(pose[:, 2])
    frames = []
    for k in range(n):
        frames.append(
            {
                "acceleration": [float(accel[k, 0]), float(accel[k, 1]), 0.0],
                "angular_velocity": [0.0, 0.0, float(yaw_rate[k])],
                "forward_vector": [float(forward[k, 0]), float(forward[k, 1]), 0.0],
                "right_vector": [float(right[k, 0]), float(right[k, 1]), 0.0],
                "location": [float(pose[k, 0]), -float(pose[k, 1]), 0.0],
                "rotation": [0.0, 0.0, float(carla_yaw[k])],
            }
        )
    return frames


def _cav_frames(log: Any, cav: int) -> tuple[np.ndarray, np.ndarray]:
    pose = log.cav_pose(cav)
    ticks = np.flatnonzero(~np.isnan(pose[:, 0]))
    return pose[ticks], ticks


def metric_info(log: Any, cav: int) -> dict[str, dict[str, list[float]]]:
    """``metric_info.json`` of one record: CAV ``cav``'s frames keyed by log tick; ``cav = -1``: every
    CAV's frames one after the other, keyed ``<cav>:<tick>``, each CAV's cut to whole
    ``COMFORT_FRAMES`` windows so that no smoothness window holds two CAVs."""
    if cav >= 0:
        pose, ticks = _cav_frames(log, cav)
        return {str(int(k)): f for k, f in zip(ticks, metric_frames(pose, ticks, log.dt), strict=True)}
    out: dict[str, dict[str, list[float]]] = {}
    for i in range(log.num_cavs):
        pose, ticks = _cav_frames(log, i)
        keep = len(ticks) // COMFORT_FRAMES * COMFORT_FRAMES
        frames = metric_frames(pose, ticks, log.dt)[:keep]
        out.update({f"{i}:{int(k)}": f for k, f in zip(ticks[:keep], frames, strict=True)})
    return out


def _load_log(path: Path, route: RouteResult) -> Any:
    from cmudrive.bench.route_log import RouteLogError, load_route_log

    try:
        log = load_route_log(path)
    except RouteLogError as exc:
        raise ExportError(str(exc)) from None
    if log.route_id != route.route_id or log.num_cavs != route.num_cavs:
        raise ExportError(
            f"route log {path} is of route {log.route_id!r} with {log.num_cavs} CAVs, not of "
            f"{route.route_id!r} with {route.num_cavs}"
        )
    return log


def _write_compact(path: Path, data: Any) -> None:
    """JSON without indentation (a 4000-frame route is ~1.4 MB so), through a temporary file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".tmp.{path.name}")
    tmp.write_text(json.dumps(data, separators=(",", ":")), encoding="utf-8")
    tmp.replace(path)


# ------------------------------------------------------------------------------------------------------
# the export


def export_leaderboard(
    run: str | Path,
    out: str | Path | None = None,
    *,
    per: str = PER_CAV,
    routes_file: str | Path | None = None,
    metric_info_required: bool | None = None,
) -> LeaderboardExport:
    """Write ``run``'s results as leaderboard files into ``out`` (default ``RUN/leaderboard-<per>``).

    ``per``: "cav" (one leaderboard route per CAV) or "route" (one per route, the multi-agent scores).
    ``routes_file``: the route file of the run (default: the one ``RUN/run.json`` names).
    ``metric_info_required``: None writes ``metric_info.json`` where a route log exists; True makes a
    missing log an error naming it; False writes none. Routes recorded "Failed - Invalid route" never
    ran and are left out (as from our DS). ``out`` must be new or empty."""
    if per not in (PER_CAV, PER_ROUTE):
        raise ExportError(f"--per must be {PER_CAV!r} or {PER_ROUTE!r}, got {per!r}")
    run = Path(run)
    routes, total = load_run(run)
    invalid = [r.route_id for r in routes if r.status == STATUS_INVALID_ROUTE]
    routes = [r for r in routes if r.status != STATUS_INVALID_ROUTE]
    total -= len(invalid)
    if not routes:
        raise ExportError(f"{run / RESULTS_FILE}: no route that ran, nothing to export")
    if routes_file is None:
        spec_file, named_by = route_file_of(run), f"named by {run / MANIFEST_FILE}"
    else:
        spec_file, named_by = Path(routes_file), "given"
    specs = route_specs(routes, spec_file, named_by)
    names = [s.scenarios[0].name if s.scenarios else "" for s in specs]
    logs = {r.route_id: run / LOGS_DIR / f"{record_stem(r.route_id)}.npz" for r in routes}
    if metric_info_required:
        missing = [str(p) for p in logs.values() if not p.is_file()]
        if missing:
            raise ExportError(
                f"no route log {missing[0]}"
                + (f" (and {len(missing) - 1} more)" if len(missing) > 1 else "")
                + ": metric_info.json needs the logs of eval --record"
            )
    out = Path(out) if out is not None else run / f"leaderboard-{per}"
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ExportError(f"{out}: exists and is not an empty folder; pick another -o or remove it")
    out.mkdir(parents=True, exist_ok=True)

    rows = cav_records(routes, names) if per == PER_CAV else route_records(routes, names)
    records = [rec for rec, _, _ in rows]
    result = LeaderboardExport(
        out / CHECKPOINT_FILE, out / ROUTES_FILE, records=len(records), invalid=invalid
    )
    write_route_xml(result.routes, rows, {s.id: s for s in specs})
    if metric_info_required is not False:
        for route in routes:
            path = logs[route.route_id]
            if not path.is_file():
                result.without_log.append(route.route_id)
                continue
            log = _load_log(path, route)
            for rec, _, cav in (row for row in rows if row[1] is route):
                target = out / rec["save_name"] / METRIC_INFO_FILE
                _write_compact(target, metric_info(log, cav))
                result.metric_info.append(target)
    write_json_atomic(result.checkpoint, checkpoint(records, total if per == PER_ROUTE else len(records)))
    return result
