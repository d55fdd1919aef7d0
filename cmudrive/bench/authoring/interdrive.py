"""Import multi-vehicle scenario folders of the cooperative-driving peers as our routes: InterDrive (the
CARLA benchmark released with CoLMDriver) and the MDrive-style folders of the same ecosystem.

A *scenario folder* holds one leaderboard-style route file per vehicle (``<routes><route id town
[role model speed]>`` with ``<waypoint x y z yaw>`` in CARLA's world frame). InterDrive's files have no
``role``: every file is an ego vehicle, ``<name>_<k>.xml`` being ego ``k`` (CoLMDriver's evaluator keys the
files by the number after the last underscore). MDrive-style folders add, beside the ego files, files of
other actors with a ``role`` (``npc``, ``pedestrian``, ``bicycle``/``bike``, ``static``/``static_prop``), a
CARLA ``model`` and a ``speed`` [m/s], often under ``actors/`` and listed in ``actors_manifest.json``
(kind -> entries with ``file``, ``name``, ``model``, ``speed``; the manifest's values win over the file's
and its ``ego`` list gives the ego order).

One folder becomes one route, id = the folder's name: the egos as CAVs 0..N-1 in that order, their sparse
waypoints kept as keypoints (CARLA frame, as our route files speak it); every other file a free actor
(``ActorSpec``) whose actor type follows its CARLA blueprint (``actor_type_for``: ``walker.*`` a
pedestrian, ``vehicle.*`` a car, van, truck, bus, motorcycle or bicycle, ``static.prop.*`` a prop), so a
collision with it is charged as CARLA would (pedestrian 0.5, vehicle 0.6, layout 0.65); pedestrians,
bicycles and NPC vehicles follow their waypoints at their speed, static props and parked vehicles stand
where they are placed. The town is the routes' ``town``; the weather the ego files' ``<weather>`` or, as
CARLA's leaderboard does without one, a sun 70 deg up under 30 % cloud (our ``ClearNoon``); the background
is InterDrive's parameter file's: none (``NO_BACKGROUND``), or ``NPC_BACKGROUND`` for its NPC variant; its
lights are off (``lights="off"``: the source holds every light green, so the CAVs must negotiate each
junction; ours run without signals, by the junction's right of way).
Every CAV route is planned on our import of the town before the route is kept, so a vehicle that cannot
be planned is an error naming the scenario, the vehicle and its file.
"""

from __future__ import annotations

import json
import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cmudrive.bench.authoring.bench2drive import ImportResult, town_table
from cmudrive.bench.authoring.import_repair import repair_keypoints, separate_starts
from cmudrive.bench.route_spec import (
    ActorSpec,
    BackgroundSpec,
    CavSpec,
    RouteSpec,
    RouteSpecError,
)
from cmudrive.bench.routes import parse_xml, route_id_problem
from cmudrive.maps import MapError, RoadMap, RouteError, load_map
from cmudrive.sim.weather import weather_from_carla

MANIFEST = "actors_manifest.json"
NO_BACKGROUND = BackgroundSpec(vehicles=0, pedestrians=0)  # scenario_parameter_Interdrive(_no_npc).yaml
NPC_BACKGROUND = BackgroundSpec(vehicles=50, pedestrians=50)  # scenario_parameter_Interdrive_npc.yaml
# all three parameter files set turn_off_light: every light held green, the CAVs negotiate each junction;
# ours are switched off for the route (RouteSpec.lights), so its right of way applies
SOURCE_LIGHTS = "off"
CARLA_DEFAULT_WEATHER = {"sun_altitude_angle": 70.0, "cloudiness": 30.0}  # a route without <weather>

# role -> (the CARLA model it stands for when none is given, its speed [m/s] when none is given)
ROLE_DEFAULTS: dict[str, tuple[str, float]] = {
    "ego": ("vehicle.lincoln.mkz_2017", 0.0),
    "npc": ("vehicle.tesla.model3", 8.0),
    "pedestrian": ("walker.pedestrian.0001", 1.5),
    "bicycle": ("vehicle.diamondback.century", 4.0),
    "bike": ("vehicle.diamondback.century", 4.0),
    "static": ("static.prop.trafficcone01", 0.0),
    "static_prop": ("static.prop.trafficcone01", 0.0),
}
STATIC_ROLES = frozenset({"static", "static_prop"})

# CARLA vehicle blueprints that are not a passenger car; any other ``vehicle.*`` is a car
_VEHICLE_MODELS: dict[str, str] = {
    **dict.fromkeys(
        ("vehicle.bh.crossbike", "vehicle.diamondback.century", "vehicle.gazelle.omafiets"), "bicycle"
    ),
    **dict.fromkeys(
        (
            "vehicle.harley-davidson.low_rider",
            "vehicle.kawasaki.ninja",
            "vehicle.yamaha.yzf",
            "vehicle.vespa.zx125",
        ),
        "motorcycle",
    ),
    **dict.fromkeys(
        (
            "vehicle.carlamotors.carlacola",
            "vehicle.carlamotors.european_hgv",
            "vehicle.carlamotors.firetruck",
        ),
        "truck",
    ),
    **dict.fromkeys(
        (
            "vehicle.volkswagen.t2",
            "vehicle.volkswagen.t2_2021",
            "vehicle.mercedes.sprinter",
            "vehicle.ford.ambulance",
            "vehicle.tesla.cybertruck",
        ),
        "van",
    ),
    "vehicle.mitsubishi.fusorosa": "bus",
}
# words of CARLA static prop blueprints -> our prop types, first match wins; any other prop is a cone
_PROP_WORDS: tuple[tuple[str, str], ...] = (
    ("cone", "cone"),
    ("warning", "warning_sign"),
    ("barrier", "warning_sign"),
    ("container", "container"),
    ("advertisement", "advertisement"),
    ("vending", "vending_machine"),
)


def actor_type_for(model: str) -> str:
    """Our actor type for a CARLA blueprint: ``walker.*`` -> pedestrian; ``vehicle.*`` -> bicycle,
    motorcycle, truck, van, bus or car (``_VEHICLE_MODELS``); ``static.*`` -> a prop (``_PROP_WORDS``,
    else a cone). ValueError for any other family."""
    if model.startswith("walker."):
        return "pedestrian"
    if model.startswith("vehicle."):
        return _VEHICLE_MODELS.get(model, "car")
    if model.startswith("static."):
        return next((kind for word, kind in _PROP_WORDS if word in model), "cone")
    raise ValueError(f"CARLA blueprint {model!r} is neither walker.*, vehicle.* nor static.*")


@dataclass(frozen=True)
class _RouteFile:
    """One route file of a scenario folder (an ego's or another actor's), read."""

    path: Path
    rel: str  # path relative to the scenario folder, with '/'
    town: str
    role: str
    model: str
    speed: float | None  # [m/s], None when the file gives none
    points: np.ndarray  # (n, 3) CARLA [m]
    yaw: float  # [deg] CARLA yaw of the first waypoint
    weather: dict[str, float] | None


def _number(raw: object, what: str) -> float:
    """A finite number from an attribute or manifest value; RouteSpecError naming ``what`` otherwise."""
    try:
        value = float(str(raw))
    except ValueError:
        raise RouteSpecError(f"non-numeric {what}={raw!r}") from None
    if not math.isfinite(value):
        raise RouteSpecError(f"non-finite {what}={raw!r}")
    return value


def _coord(elem: ET.Element, attr: str, what: str, default: float | None) -> float:
    raw = elem.get(attr)
    if raw is None:
        if default is None:
            raise RouteSpecError(f"{what}: missing attribute {attr!r}")
        return default
    return _number(raw, f"{what} {attr}")


def _read_file(path: Path, folder: Path, entry: dict[str, object]) -> _RouteFile:
    """The file's one ``<route>``: town, role, model, speed, waypoints and weather; ``entry`` is its
    manifest entry (its kind, model and speed win over the file's)."""
    routes = parse_xml(path, "routes").findall("route")
    if len(routes) != 1:
        raise RouteSpecError(
            f"holds {len(routes)} <route> elements; a vehicle file holds one", path=str(path)
        )
    route = routes[0]
    try:
        town = route.get("town") or ""
        if not town:
            raise RouteSpecError("the <route> has no town")
        role = str(entry.get("kind") or route.get("role") or "ego")
        if role not in ROLE_DEFAULTS:
            raise RouteSpecError(f"unknown role {role!r}; known: {', '.join(ROLE_DEFAULTS)}")
        model = str(entry.get("model") or route.get("model") or ROLE_DEFAULTS[role][0])
        raw_speed = entry.get("speed", route.get("speed"))
        speed = None if raw_speed is None else _number(raw_speed, "speed")
        wps = route.findall("waypoint")
        if not wps:
            raise RouteSpecError("the <route> has no <waypoint>")
        points = np.array(
            [
                [_coord(w, k, f"waypoint {i}", 0.0 if k == "z" else None) for k in "xyz"]
                for i, w in enumerate(wps)
            ]
        )
        weathers = route.findall("weather")
        weather = None
        if weathers:
            weather = {k: _coord(weathers[0], k, "<weather>", None) for k in weathers[0].attrib if k != "id"}
        yaw = _coord(wps[0], "yaw", "waypoint 0", 0.0)
    except RouteSpecError as exc:
        raise RouteSpecError(exc.problem, path=str(path)) from None
    rel = path.relative_to(folder).as_posix()
    return _RouteFile(path, rel, town, role, model, speed, points, yaw, weather)


def _manifest(folder: Path) -> tuple[dict[str, dict[str, object]], list[str]]:
    """``actors_manifest.json`` of a folder: file -> its entry (with its ``kind``), and the ego files in
    the manifest's order. Empty without a manifest."""
    path = folder / MANIFEST
    if not path.is_file():
        return {}, []
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise RouteSpecError(f"not readable as JSON: {exc}", path=str(path)) from None
    if not isinstance(data, dict):
        raise RouteSpecError("the manifest is not a JSON object (kind -> list of entries)", path=str(path))
    entries: dict[str, dict[str, object]] = {}
    egos: list[str] = []
    for kind, items in data.items():
        for item in items if isinstance(items, list) else []:
            if not isinstance(item, dict) or not isinstance(item.get("file"), str):
                raise RouteSpecError(f"a {kind!r} entry has no 'file'", path=str(path))
            rel = Path(item["file"]).as_posix()
            if not (folder / rel).is_file():
                raise RouteSpecError(f"lists {rel}, which is not in {folder}", path=str(path))
            entries[rel] = {**item, "kind": kind}
            if kind == "ego":
                egos.append(rel)
    return entries, egos


_TRAILING_NUMBER = re.compile(r"_(\d+)$")


def _ego_order(egos: list[_RouteFile], listed: list[str], scenario: str) -> list[_RouteFile]:
    """Egos in the manifest's order, else by the number after the last underscore of the file name."""
    if listed:
        by_rel = {e.rel: e for e in egos}
        return [by_rel[r] for r in listed if r in by_rel] + [e for e in egos if e.rel not in listed]
    numbered = []
    for ego in egos:
        match = _TRAILING_NUMBER.search(ego.path.stem)
        if match is None:
            raise RouteSpecError(
                "cannot order the ego vehicles: the file name does not end in _<number>",
                path=str(ego.path),
                route_id=scenario,
            )
        numbered.append((int(match.group(1)), ego))
    numbers = [n for n, _ in numbered]
    dup = sorted({n for n in numbers if numbers.count(n) > 1})
    if dup:
        raise RouteSpecError(f"two ego files end in _{dup[0]}", route_id=scenario)
    return [e for _, e in sorted(numbered, key=lambda item: item[0])]


def _actor(vf: _RouteFile, actor_id: str) -> ActorSpec:
    try:
        kind = actor_type_for(vf.model)
    except ValueError as exc:
        raise RouteSpecError(str(exc), path=str(vf.path)) from None
    static = vf.role in STATIC_ROLES
    speed = 0.0 if static else (ROLE_DEFAULTS[vf.role][1] if vf.speed is None else vf.speed)
    try:
        return ActorSpec(actor_id, kind, vf.points, yaw=vf.yaw, speed=speed, static=static, model=vf.model)
    except RouteSpecError as exc:
        raise RouteSpecError(exc.problem, path=str(vf.path)) from None


def read_scenario_folder(
    folder: str | Path,
    background: BackgroundSpec = NO_BACKGROUND,
    seed: int = 0,
    towns: dict[str, tuple[str, ...]] | None = None,
) -> RouteSpec:
    """One scenario folder as one route (see the module docstring), not yet planned on its town.
    ``towns`` maps town names to the folders they are looked up in first (``town_table``); a town not in
    it is refused. RouteSpecError names the file, the scenario and, where it applies, the vehicle."""
    return _read_scenario(Path(folder), background, seed, towns)[0]


def _read_scenario(
    folder: Path, background: BackgroundSpec, seed: int, towns: dict[str, tuple[str, ...]] | None
) -> tuple[RouteSpec, list[str]]:
    """The route of a scenario folder and the file of each CAV (relative to the folder), in CAV order."""
    scenario = folder.name
    if route_id_problem(scenario):
        raise RouteSpecError(
            f"the folder name is not a usable route id: {route_id_problem(scenario)}", str(folder)
        )
    try:
        entries, listed = _manifest(folder)
        files = [
            _read_file(p, folder, entries.get(p.relative_to(folder).as_posix(), {}))
            for p in _xml_files(folder)
        ]
    except RouteSpecError as exc:
        raise exc.within(route_id=scenario) from None
    egos = _ego_order([f for f in files if f.role == "ego"], listed, scenario)
    if not egos:
        raise RouteSpecError("no ego vehicle file", path=str(folder), route_id=scenario)
    towns_seen = sorted({f.town for f in files})
    if len(towns_seen) > 1:
        raise RouteSpecError(f"its files name several towns: {', '.join(towns_seen)}", str(folder), scenario)
    town = towns_seen[0]
    table = town_table(None) if towns is None else towns
    if town not in table:
        raise RouteSpecError(
            f"town {town} is not available; available: {', '.join(sorted(table))}", str(folder), scenario
        )
    cavs = []
    for k, ego in enumerate(egos):
        try:
            cavs.append(CavSpec(k, ego.points))
        except RouteSpecError as exc:
            raise RouteSpecError(exc.problem, str(ego.path), scenario, k) from None
    weather_params = next((e.weather for e in egos if e.weather is not None), CARLA_DEFAULT_WEATHER)
    try:
        weather = weather_from_carla(weather_params).name
    except ValueError as exc:
        raise RouteSpecError(f"<weather>: {exc}", str(egos[0].path), scenario) from None
    others = [f for f in files if f.role != "ego"]
    stems = [f.path.stem for f in others]
    actors = []
    for vf in others:
        name = entries.get(vf.rel, {}).get("name")
        actor_id = str(name) if name else (vf.path.stem if stems.count(vf.path.stem) == 1 else vf.rel[:-4])
        actors.append(_actor(vf, actor_id))
    try:
        spec = RouteSpec(
            scenario,
            town,
            weather,
            seed,
            tuple(cavs),
            (),
            town_dirs=table[town],
            actors=tuple(actors),
            background=background,
            lights=SOURCE_LIGHTS,
        )
    except RouteSpecError as exc:
        raise exc.within(path=str(folder), route_id=scenario) from None
    return spec, [e.rel for e in egos]


def _xml_files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.rglob("*.xml") if p.is_file())


def check_planned(spec: RouteSpec, road_map: RoadMap, files: list[str]) -> None:
    """Plan every CAV of ``spec`` on ``road_map``; a RouteSpecError naming the scenario, the CAV and its
    file (``files[k]`` is CAV k's) when one cannot be planned or two start on top of each other."""
    try:
        spec.dense_routes(road_map)
    except RouteError as exc:
        text = str(exc)
        named = sorted({int(k) for k in re.findall(r"CAVs? (\d+)", text) + re.findall(r"and (\d+) \(", text)})
        which = "; ".join(f"CAV {k} is {files[k]}" for k in named if k < len(files))
        raise RouteSpecError(text + (f" ({which})" if which else "")) from None


def scenario_folders(path: str | Path) -> list[Path]:
    """The scenario folders at ``path``: ``path`` itself when it holds route files, else its sub-folders
    that do, in natural order (r2 before r10). RouteSpecError when there are none."""
    path = Path(path)
    if not path.is_dir():
        raise RouteSpecError("not a folder", path=str(path))
    if any(p.is_file() for p in path.glob("*.xml")):
        return [path]
    subs = [d for d in path.iterdir() if d.is_dir() and any(d.glob("*.xml"))]
    if not subs:
        raise RouteSpecError("holds no route files (*.xml) and no scenario folders with any", path=str(path))

    def natural(p: Path) -> list[object]:
        return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", p.name)]

    return sorted(subs, key=natural)


def import_scenario_folders(
    path: str | Path, npc: bool = False, seed: int = 0, towns: list[str] | None = None
) -> ImportResult:
    """Every scenario folder at ``path`` (one folder, or a folder of them) as routes, each planned on its
    town; ``(scenario, reason)`` in ``skipped`` for every one that cannot be read or planned. ``npc``: the
    background of InterDrive's NPC variant instead of none."""
    table = town_table(towns)
    background = NPC_BACKGROUND if npc else NO_BACKGROUND
    result = ImportResult()
    maps: dict[str, RoadMap] = {}
    for folder in scenario_folders(path):
        try:
            spec, files = _read_scenario(folder, background, seed, table)
            if spec.town not in maps:
                maps[spec.town] = load_map(spec.town_path())
            spec, notes = repair_keypoints(spec, maps[spec.town])
            spec, moved = separate_starts(spec, maps[spec.town])
            notes += moved
            check_planned(spec, maps[spec.town], files)
        except RouteSpecError as exc:
            named = exc.route_id is not None or f"route {folder.name!r}" in exc.problem
            result.skipped.append((folder.name, str(exc if named else exc.within(route_id=folder.name))))
            continue
        except MapError as exc:  # the town's network did not load
            result.skipped.append((folder.name, f"route {folder.name!r}: {exc}"))
            continue
        result.routes.append(spec)
        result.notes.extend(
            (spec.id, f"{note} ({files[int(note.split()[1].rstrip(':'))]})") for note in notes
        )
    return result


__all__ = [
    "NO_BACKGROUND",
    "NPC_BACKGROUND",
    "actor_type_for",
    "check_planned",
    "import_scenario_folders",
    "read_scenario_folder",
    "scenario_folders",
]
