"""Multi-CAV route files: reading, checking and writing (the data model they hold is
:mod:`cmudrive.bench.route_spec`, its names re-exported here).

A route is one town, one weather preset, one SUMO seed, 1-16 CAV routes and any number of scenarios
(``docs/route_format.md`` has the schema)::

    <routes>
      <route id="smoke_00" town="downtown" weather="ClearNoon" seed="0">
        <cav id="0"><waypoints><position x="141.0" y="-199.9" z="0.0"/> ...</waypoints></cav>
        <cav id="1"> ... </cav>
        <scenarios>
          <scenario name="Accident_1" type="Accident">
            <trigger_point x="..." y="..." z="..." yaw="..."/> <distance value="40"/> ...
          </scenario>
        </scenarios>
      </route>
    </routes>

Positions and trigger points are CARLA world coordinates (metres, yaw in degrees; the mirror image in y of
our map frame, see ``cmudrive.maps.coords``). CAV 0 drives the scenario route. A route file holds 2-16 CAVs
per route (``MIN_CAVS``..``MAX_CAVS``); a :class:`RouteSpec` in memory may hold one (a single-ego route as
imported from Bench2Drive), and ``min_cavs=1`` reads and writes such files.

Generating routes (placing CAVs by the road topology) is ``cmudrive.bench.authoring.route_gen``'s job.
"""

from __future__ import annotations

import hashlib
import math
import os
import re
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Literal, overload

import numpy as np

from cmudrive.bench.records import route_id_problem
from cmudrive.bench.route_spec import (
    MAX_ACTORS,
    MAX_CAVS,
    MAX_COORDINATE,
    MAX_SEED,
    MIN_CAVS,
    ActorSpec,
    BackgroundSpec,
    CavSpec,
    ParamValue,
    RouteSpec,
    RouteSpecError,
    ScenarioSpec,
    start_conflicts,
)

# Input bounds. Reading and planning are linear in the waypoints (each keypoint is snapped and joined to
# the next by one lane-graph search, ~0.3 ms per waypoint on a laptop core), so these bounds cap the work
# of `routes check` and of route setup in `eval`: a 45 MB file of 800 k waypoints took minutes without an
# answer. The committed sets hold at most 9 waypoints per CAV and 6909 in a file (cmudrive220.xml, 0.5 MB).
MAX_FILE_BYTES = 16 * 2**20  # [bytes] a route file (Bench2Drive's and Leaderboard 2.0's are ~1-3 MB)
MAX_WAYPOINTS = 2000  # [-] per CAV: a 20 km route (MAX_ROUTE_LENGTH) with a keypoint every 10 m
MAX_FILE_WAYPOINTS = 100_000  # [-] <position>/<waypoint> elements in a file (~30 s of planning)

# numbers as route files write them: ASCII decimal only (str.isdigit and float accept "²", "١٢", "1_000")
_INT = re.compile(r"[0-9]+", re.ASCII)
_FLOAT = re.compile(  # (nan and inf pass here to be refused as non-finite)
    r"[+-]?(?:(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|nan|inf|infinity)", re.ASCII | re.IGNORECASE
)
_XML_SPACE = " \t\r\n"  # what XML calls white space (a no-break space is not)

# attributes an XML route file may hold
_ROUTE_ATTRS = frozenset({"id", "town", "weather", "seed", "lights"})
_POSITION_ATTRS = frozenset({"x", "y", "z", "pitch", "roll", "yaw"})  # pitch/roll/yaw are ignored
_TRIGGER_ATTRS = frozenset({"x", "y", "z", "yaw", "pitch", "roll"})  # pitch/roll are ignored


def _number(elem: ET.Element, attr: str, what: str, default: float | None = None) -> float:
    raw = elem.get(attr)
    if raw is None:
        if default is not None:
            return default
        raise RouteSpecError(f"{what}: missing attribute {attr!r}")
    if not _FLOAT.fullmatch(raw.strip(_XML_SPACE)):
        raise RouteSpecError(f"{what}: non-numeric {attr}={raw!r} (ASCII decimal numbers only)")
    value = float(raw)
    if not math.isfinite(value):
        raise RouteSpecError(f"{what}: non-finite {attr}={raw!r}")
    if attr in ("x", "y", "z") and abs(value) > MAX_COORDINATE:
        raise RouteSpecError(f"{what}: {attr}={raw} is beyond +-{MAX_COORDINATE:.0e} m, off any map")
    return value


def _integer(raw: str | None, what: str, largest: int) -> int:
    """A non-negative ASCII decimal integer up to ``largest``; RouteSpecError naming ``what``."""
    text = (raw or "").strip(_XML_SPACE)
    if not _INT.fullmatch(text) or len(text) > 18 or int(text) > largest:  # (int() refuses 4300+ digits)
        raise RouteSpecError(f"{what} must be an integer in 0..{largest}, got {raw!r}")
    return int(text)


def _check_attrs(elem: ET.Element, allowed: frozenset[str], what: str) -> None:
    unknown = sorted(set(elem.attrib) - allowed)
    if unknown:
        raise RouteSpecError(f"{what}: unknown attributes {unknown}; allowed: {sorted(allowed)}")


def points_from_xml(elems: Iterable[ET.Element], cav_id: int | None = None) -> np.ndarray:
    """``<position x y z/>`` (or Leaderboard 1.0 ``<waypoint>``) elements -> (n, 3) CARLA points; z defaults
    to 0 and pitch/roll/yaw are ignored."""
    elems = list(elems)
    if len(elems) > MAX_WAYPOINTS:
        raise RouteSpecError(
            f"{len(elems)} waypoints, more than the {MAX_WAYPOINTS} a CAV may have (waypoints are keypoints "
            "of the route, ~50 m apart: see docs/route_format.md)",
            cav_id=cav_id,
        )
    rows = []
    for i, elem in enumerate(elems):
        try:
            _check_attrs(elem, _POSITION_ATTRS, f"waypoint {i}")
            rows.append([_number(elem, k, f"waypoint {i}", 0.0 if k == "z" else None) for k in "xyz"])
        except RouteSpecError as exc:
            raise RouteSpecError(exc.problem, cav_id=cav_id) from None
    return np.array(rows, dtype=np.float64).reshape(-1, 3)


def scenario_from_xml(elem: ET.Element, index: int) -> ScenarioSpec:
    """A ``<scenario name type>`` element with its ``<trigger_point>`` and parameter elements."""
    name = elem.get("name") or ""
    what = f"scenario {name or index!r}"
    _check_attrs(elem, frozenset({"name", "type"}), what)
    if not name:
        raise RouteSpecError(f"scenario {index}: missing name")
    if elem.get("type") is None:
        raise RouteSpecError(f"{what}: missing type")
    triggers = elem.findall("trigger_point")
    if len(triggers) != 1:
        raise RouteSpecError(f"{what}: needs exactly one <trigger_point>, got {len(triggers)}")
    trig = triggers[0]
    _check_attrs(trig, _TRIGGER_ATTRS, f"{what} trigger_point")
    trigger = tuple(
        _number(trig, k, f"{what} trigger_point", 0.0 if k == "z" else None) for k in ("x", "y", "z", "yaw")
    )
    params: dict[str, ParamValue] = {}
    for child in elem:
        if child.tag == "trigger_point":
            continue
        if child.tag in params:
            raise RouteSpecError(f"{what}: parameter <{child.tag}> given twice")
        attrs = dict(child.attrib)
        params[child.tag] = attrs["value"] if set(attrs) == {"value"} else attrs
    return ScenarioSpec(name=name, type=str(elem.get("type")), trigger=trigger, params=params)  # type: ignore[arg-type]


def _route_from_xml(elem: ET.Element, min_cavs: int) -> RouteSpec:
    for tag, hint in (("waypoints", "its waypoints"), ("weathers", "a <weathers> element")):
        if elem.find(tag) is not None:
            raise RouteSpecError(
                f"has {hint} directly under <route>: this looks like a single-ego Leaderboard/Bench2Drive "
                "route file; convert it with cmudrive.bench.authoring.bench2drive.import_leaderboard_routes"
            )
    _check_attrs(elem, _ROUTE_ATTRS, "<route>")
    unknown = sorted({c.tag for c in elem} - {"cav", "scenarios", "actors", "background"})
    if unknown:
        raise RouteSpecError(
            f"unknown elements {unknown} in <route>; allowed: <cav>, <scenarios>, <actors>, <background>"
        )
    for attr in ("town", "weather"):
        if not elem.get(attr):
            raise RouteSpecError(f"missing {attr}")
    seed = _integer(elem.get("seed", "0"), "seed", MAX_SEED)
    cavs = [_cav_from_xml(c, i) for i, c in enumerate(elem.findall("cav"))]
    if not min_cavs <= len(cavs) <= MAX_CAVS:
        raise RouteSpecError(f"needs {min_cavs}-{MAX_CAVS} <cav> elements, got {len(cavs)}")
    ids = sorted(c.id for c in cavs)
    if ids != list(range(len(cavs))):
        raise RouteSpecError(f"CAV ids must be 0..{len(cavs) - 1}, each once; got {[c.id for c in cavs]}")
    scenarios: list[ScenarioSpec] = []
    for block in elem.findall("scenarios"):
        for child in block:
            if child.tag != "scenario":
                raise RouteSpecError(f"unknown element <{child.tag}> in <scenarios>")
            scenarios.append(scenario_from_xml(child, len(scenarios)))
    return RouteSpec(
        id=str(elem.get("id")),
        town=str(elem.get("town")),
        weather=str(elem.get("weather")),
        seed=seed,
        cavs=tuple(sorted(cavs, key=lambda c: c.id)),
        scenarios=tuple(scenarios),
        actors=_actors_from_xml(elem),
        background=_background_from_xml(elem),
        lights=str(elem.get("lights", "on")),
    )


_ACTOR_ATTRS = frozenset({"id", "type", "yaw", "speed", "static", "model"})


def _actors_from_xml(route: ET.Element) -> tuple[ActorSpec, ...]:
    """The ``<actors>`` block: ``<actor id type [yaw] [speed] [static] [model]>`` with ``<position>``s."""
    blocks = route.findall("actors")
    if len(blocks) > 1:
        raise RouteSpecError(f"{len(blocks)} <actors> elements; at most one")
    elems = list(blocks[0]) if blocks else []
    if len(elems) > MAX_ACTORS:
        raise RouteSpecError(f"{len(elems)} actors, more than the {MAX_ACTORS} a route may have")
    actors = []
    for k, elem in enumerate(elems):
        what = f"actor {elem.get('id') or k!r}"
        if elem.tag != "actor":
            raise RouteSpecError(f"unknown element <{elem.tag}> in <actors>")
        _check_attrs(elem, _ACTOR_ATTRS, what)
        bad = sorted({c.tag for c in elem} - {"position"})
        if bad:
            raise RouteSpecError(f"{what}: unknown elements {bad}; allowed: <position>")
        static = elem.get("static", "false")
        if static not in ("true", "false"):
            raise RouteSpecError(f"{what}: static must be 'true' or 'false', got {static!r}")
        try:
            points = points_from_xml(elem.findall("position"))
        except RouteSpecError as exc:
            raise RouteSpecError(f"{what}: {exc.problem}") from None
        actors.append(
            ActorSpec(
                id=elem.get("id") or "",
                type=elem.get("type") or "",
                waypoints=points,
                yaw=_number(elem, "yaw", what, 0.0),
                speed=_number(elem, "speed", what, 0.0),
                static=static == "true",
                model=elem.get("model", ""),
            )
        )
    return tuple(actors)


def _background_from_xml(route: ET.Element) -> BackgroundSpec | None:
    """``<background vehicles pedestrians/>``, or None when the route has none."""
    blocks = route.findall("background")
    if not blocks:
        return None
    if len(blocks) > 1:
        raise RouteSpecError(f"{len(blocks)} <background> elements; at most one")
    _check_attrs(blocks[0], frozenset({"vehicles", "pedestrians"}), "<background>")
    return BackgroundSpec(
        *(_integer(blocks[0].get(k), f"<background> {k}", 10**6) for k in ("vehicles", "pedestrians"))
    )


def _cav_from_xml(elem: ET.Element, index: int) -> CavSpec:
    cav_id = _integer(elem.get("id"), f"the id of <cav> number {index}", 10**9)
    try:
        _check_attrs(elem, frozenset({"id"}), "<cav>")
        unknown = sorted({c.tag for c in elem} - {"waypoints"})
        if unknown:
            raise RouteSpecError(f"unknown elements {unknown} in <cav>; allowed: <waypoints>")
        blocks = elem.findall("waypoints")
        if len(blocks) != 1:
            raise RouteSpecError(
                "missing <waypoints>" if not blocks else f"{len(blocks)} <waypoints> elements"
            )
        bad = sorted({c.tag for c in blocks[0]} - {"position"})
        if bad:
            raise RouteSpecError(f"unknown elements {bad} in <waypoints>; allowed: <position>")
        return CavSpec(cav_id, points_from_xml(blocks[0].findall("position"), cav_id))
    except RouteSpecError as exc:
        raise RouteSpecError(exc.problem, cav_id=cav_id) from None


def parse_xml(path: str | Path, root_tag: str) -> ET.Element:
    """Root element of an XML file, checked to be ``<root_tag>``; RouteSpecError naming the file otherwise.
    A file larger than ``MAX_FILE_BYTES`` is refused before it is parsed, one with more than
    ``MAX_FILE_WAYPOINTS`` waypoints before any is read."""
    try:
        size = os.stat(path).st_size
        if size > MAX_FILE_BYTES:
            raise RouteSpecError(
                f"the file is {size / 2**20:.1f} MiB, larger than the {MAX_FILE_BYTES // 2**20} MiB a route "
                "file may be",
                path=str(path),
            )
        root = ET.parse(path).getroot()
    except FileNotFoundError:
        raise RouteSpecError("route file not found", path=str(path)) from None
    except (ET.ParseError, OSError, LookupError, UnicodeError) as exc:  # LookupError: unknown encoding
        raise RouteSpecError(f"not readable as XML: {exc}", path=str(path)) from None
    if root.tag != root_tag:
        raise RouteSpecError(f"root element is <{root.tag}>, expected <{root_tag}>", path=str(path))
    count = sum(1 for e in root.iter() if e.tag in ("position", "waypoint"))
    if count > MAX_FILE_WAYPOINTS:
        raise RouteSpecError(
            f"{count} waypoints, more than the {MAX_FILE_WAYPOINTS} a route file may hold", path=str(path)
        )
    return root


def _reported_id(elem: ET.Element, k: int) -> str:
    """The id a route is reported under: its own, or ``#k`` (1-based position) when it has none or a bad
    one."""
    raw_id = elem.get("id")
    return raw_id if raw_id and route_id_problem(raw_id) is None else f"#{k}"


def route_ids(path: str | Path) -> list[str]:
    """The ids of a route file's routes in file order, as :func:`read_routes` reports them (``#k`` for a
    route without a usable id), without reading the routes themselves."""
    return [_reported_id(elem, k) for k, elem in enumerate(parse_xml(path, "routes"), start=1)]


@overload
def read_routes(
    path: str | Path, strict: Literal[True] = True, min_cavs: int = MIN_CAVS
) -> list[RouteSpec]: ...
@overload
def read_routes(
    path: str | Path, strict: Literal[False], min_cavs: int = MIN_CAVS
) -> tuple[list[RouteSpec], list[tuple[str, str]]]: ...
def read_routes(
    path: str | Path, strict: bool = True, min_cavs: int = MIN_CAVS
) -> list[RouteSpec] | tuple[list[RouteSpec], list[tuple[str, str]]]:
    """Read a route file.

    ``strict=True`` raises :class:`RouteSpecError` (naming the file, route and CAV) on the first bad route;
    ``strict=False`` returns ``(good_routes, [(route_id, error message), ...])``. A route without an id is
    reported as ``#k`` (its 1-based position), as is one whose id breaks the id rules
    (:func:`route_id_problem`). A file that cannot be read at all, or is too large (``MAX_FILE_BYTES``,
    ``MAX_FILE_WAYPOINTS``), always raises."""
    root = parse_xml(path, "routes")
    routes: list[RouteSpec] = []
    errors: list[tuple[str, str]] = []
    seen: set[str] = set()
    for k, elem in enumerate(root, start=1):
        raw_id = elem.get("id")
        rid = _reported_id(elem, k)
        try:
            if elem.tag != "route":
                raise RouteSpecError(f"unknown element <{elem.tag}> in <routes>")
            if not raw_id:
                raise RouteSpecError("missing route id")
            problem = route_id_problem(raw_id)
            if problem:
                raise RouteSpecError(problem)
            if rid in seen:
                raise RouteSpecError("duplicate route id")
            seen.add(rid)
            spec = _route_from_xml(elem, min_cavs)
            routes.append(replace(spec, town_dirs=(str(Path(path).resolve().parent),)))
        except RouteSpecError as exc:
            err = exc.within(path=str(path), route_id=rid)
            if strict:
                raise err from None
            errors.append((rid, str(err)))
    return routes if strict else (routes, errors)


# ------------------------------------------------------------------------------------------------- writing
def _num(value: float) -> str:
    return repr(float(value))  # shortest string that reads back to the same float


def _route_to_xml(spec: RouteSpec) -> ET.Element:
    attrs = {"id": spec.id, "town": spec.town, "weather": spec.weather, "seed": str(spec.seed)}
    elem = ET.Element("route", attrs | ({"lights": spec.lights} if spec.lights != "on" else {}))
    for cav in spec.cavs:
        wps = ET.SubElement(ET.SubElement(elem, "cav", {"id": str(cav.id)}), "waypoints")
        for x, y, z in cav.waypoints:
            ET.SubElement(wps, "position", {"x": _num(x), "y": _num(y), "z": _num(z)})
    if spec.scenarios:
        block = ET.SubElement(elem, "scenarios")
        for sc in spec.scenarios:
            s = ET.SubElement(block, "scenario", {"name": sc.name, "type": sc.type})
            ET.SubElement(
                s, "trigger_point", dict(zip(("x", "y", "z", "yaw"), map(_num, sc.trigger), strict=True))
            )
            for key, value in sc.params.items():
                ET.SubElement(s, key, {"value": value} if isinstance(value, str) else dict(value))
    if spec.actors:
        block = ET.SubElement(elem, "actors")
        for actor in spec.actors:
            attrs = {"id": actor.id, "type": actor.type, "yaw": _num(actor.yaw), "speed": _num(actor.speed)}
            attrs |= {"static": "true"} if actor.static else {}
            attrs |= {"model": actor.model} if actor.model else {}
            a = ET.SubElement(block, "actor", attrs)
            for x, y, z in actor.waypoints:
                ET.SubElement(a, "position", {"x": _num(x), "y": _num(y), "z": _num(z)})
    if spec.background is not None:
        bg = spec.background
        ET.SubElement(elem, "background", {"vehicles": str(bg.vehicles), "pedestrians": str(bg.pedestrians)})
    return elem


def route_sha256(spec: RouteSpec) -> str:
    """SHA-256 of a route as a route file writes it: id, town, weather, seed, every CAV's waypoints, the
    scenarios, the free actors, the background and the lights (a route without the last three hashes as
    before), not the folders its town is looked up in. Equal routes have equal hashes, whichever file they
    were read from (a run's provenance records it per route)."""
    return hashlib.sha256(ET.tostring(_route_to_xml(spec), encoding="utf-8")).hexdigest()


def shift_seeds(routes: Sequence[RouteSpec], seed: int) -> list[RouteSpec]:
    """``routes`` with ``seed`` added to every route's seed (modulo ``MAX_SEED + 1``): the same routes with
    other background traffic and pedestrians (``cmudrive eval --seed``)."""
    if not seed:
        return list(routes)
    return [replace(s, seed=(s.seed + seed) % (MAX_SEED + 1)) for s in routes]


def write_routes(
    routes: Sequence[RouteSpec], path: str | Path, comment: str | None = None, min_cavs: int = MIN_CAVS
) -> None:
    """Write ``routes`` to ``path`` atomically (temporary file + rename); ``read_routes`` gives them back
    exactly. ``comment`` (no ``--`` inside) goes into a header comment."""
    path = Path(path)
    ids = [r.id for r in routes]
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        raise RouteSpecError(f"duplicate route ids {dup}", path=str(path))
    for r in routes:
        if not min_cavs <= len(r.cavs) <= MAX_CAVS:
            raise RouteSpecError(f"needs {min_cavs}-{MAX_CAVS} CAVs, got {len(r.cavs)}", str(path), r.id)
    if comment is not None and ("--" in comment or comment.endswith("-")):
        raise ValueError("an XML comment may not contain '--' or end with '-'")
    root = ET.Element("routes")
    root.extend(_route_to_xml(r) for r in routes)
    ET.indent(root, space="  ")
    text = '<?xml version="1.0" encoding="utf-8"?>\n'
    if comment:
        text += "<!--\n" + "\n".join(f"  {line}".rstrip() for line in comment.splitlines()) + "\n-->\n"
    text += ET.tostring(root, encoding="unicode") + "\n"
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


__all__ = [
    "MAX_CAVS",
    "MIN_CAVS",
    "ActorSpec",
    "BackgroundSpec",
    "CavSpec",
    "RouteSpec",
    "RouteSpecError",
    "ScenarioSpec",
    "points_from_xml",
    "read_routes",
    "route_id_problem",
    "route_ids",
    "route_sha256",
    "scenario_from_xml",
    "shift_seeds",
    "start_conflicts",
    "write_routes",
]
