"""Import OpenDRIVE (.xodr) and OpenStreetMap (.osm, .osm.xml) maps into SUMO networks.

``import_map(src, dst)`` runs SUMO's netconvert and returns an :class:`ImportReport`. An OpenDRIVE
import (e.g. a CARLA town) takes two netconvert passes:

1. netconvert reads the .xodr with our lane type map (``data/opendrive_typemap.xml``: sidewalks become
   pedestrian-only lanes, parking lanes ``custom1``-only, shoulders non-drivable lanes), keeps the
   OpenDRIVE coordinates unshifted (``--offset.disable-normalization``), writes each lane's OpenDRIVE
   road and lane id as its ``origId`` parameter (``--output.original-names``), builds crossings and
   walking areas where sidewalks meet, and builds one traffic light per junction from OpenDRIVE
   traffic-light signals.
2. We read the .xodr ourselves for what netconvert leaves out and let netconvert re-read its network
   with a node/edge patch: stop signs (signal type 206) make ``priority_stop``/``allway_stop``
   junctions, road speed limits (``<road><type><speed>``) become lane speeds, traffic lights are
   guessed where the file has no signals (:class:`ImportOptions`), every junction records its
   OpenDRIVE junction id, and dead-end stubs (degenerate roads of a few micrometres that netconvert turns
   into a 0.1 m edge ending nowhere, :class:`~cmudrive.maps.opendrive.DeadEndStub`) are removed with
   their connections sent on to the road that continues.
3. Vehicle lanes whose shape netconvert ends past the road that follows, with the join's internal lane
   leading back, are cut back in the written network (:mod:`cmudrive.maps.lane_ends`).

An OpenStreetMap import is one pass (UTM projection, OSM signals, sidewalks and crossings). Frames are
described in :mod:`cmudrive.maps.coords`, options and limitations in ``docs/opendrive_import.md``.
``opendrive_id_map(net)`` reads the OpenDRIVE ids back from an imported network.
"""

from __future__ import annotations

import re
import shutil
import tempfile
import time
import xml.etree.ElementTree as ET
from collections import Counter, defaultdict
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from cmudrive.maps.errors import MapError
from cmudrive.maps.lane_ends import repair_lane_ends
from cmudrive.maps.loader import file_sha256
from cmudrive.maps.netconvert import find_netconvert, run_netconvert, write_with_fixed_header
from cmudrive.maps.opendrive import (
    Xodr,
    dead_end_stubs,
    edges_by_road,
    guess_tls,
    read_net,
    read_xodr,
    section_of,
    sign_approaches,
    write_patches,
    write_stub_connections,
)

SourceKind = Literal["opendrive", "osm"]
TlsPolicy = Literal["auto", "opendrive", "guess", "none"]
TlsSource = Literal["opendrive", "osm", "guessed", "none"]

TYPEMAP = Path(__file__).resolve().parent / "data" / "opendrive_typemap.xml"
CURVE_RESOLUTION = 1.0  # [m] sampling step of OpenDRIVE arcs, spirals and polynomials
GUESS_MIN_APPROACHES = 3  # [edges] driving edges entering a junction for a guessed traffic light
GUESS_MIN_EXITS = 2  # [edges] driving edges leaving a junction for a guessed traffic light
GUESS_MAX_SPEED = 25.0  # [m/s] (90 km/h) no guessed light where a faster road enters (highway ramps)
STOP_SIGN = "206"  # OpenDRIVE signal type of a stop sign (German catalogue, used by CARLA)
YIELD_SIGN = "205"  # OpenDRIVE signal type of a yield sign; netconvert itself lowers the road's priority
JUNCTION_PARAM = "opendrive.junction"  # junction parameter: its OpenDRIVE junction id
STOP_SIGNALS_PARAM = "opendrive.stopSignals"  # junction parameter: its OpenDRIVE stop-sign ids
WARNING_KINDS = 12  # distinct warning kinds kept in a report
_LABELS = {"opendrive": ("OpenDRIVE", "OpenDRIVE"), "osm": ("OpenStreetMap", "osm")}  # kind: name, root
_OSM_OPTIONS = (
    "--proj.utm", "--geometry.remove", "--ramps.guess", "--junctions.join", "--roundabouts.guess",
    "--tls.guess-signals", "--tls.discard-simple", "--tls.join",
    "--osm.sidewalks", "--osm.crossings", "--sidewalks.guess", "--crossings.guess", "--walkingareas",
)  # fmt: skip


@dataclass(frozen=True)
class ImportOptions:
    """How ``import_map`` treats a source.

    ``tls``: ``"opendrive"`` builds traffic lights from the file's signals only (OpenDRIVE signals, OSM
    ``highway=traffic_signals``); ``"guess"`` also lights every junction without signals or signs where
    at least ``GUESS_MIN_APPROACHES`` driving edges enter, ``GUESS_MIN_EXITS`` leave and no road faster
    than ``GUESS_MAX_SPEED`` enters (OSM: netconvert's ``--tls.guess``); ``"auto"`` (default) is
    ``"opendrive"`` when the file has traffic-light signals and ``"guess"`` otherwise; ``"none"`` builds
    none. ``signal_groups`` builds programs from OpenDRIVE ``<controller>`` groups (netconvert's docs
    warn that this can give invalid programs). ``road_speeds`` applies ``<road><type><speed>`` limits.
    """

    tls: TlsPolicy = "auto"
    signal_groups: bool = False
    road_speeds: bool = True
    curve_resolution: float = CURVE_RESOLUTION  # [m]


@dataclass(frozen=True)
class ImportReport:
    """What one import produced; counts are over the written network (normal edges unless named)."""

    dst: Path
    source: Path
    kind: SourceKind
    tls_source: TlsSource  # where the traffic lights came from: "guessed" if any was guessed, "none" if none
    edges: int
    driving_lanes: int  # lanes that allow passenger cars
    tls: int  # traffic-light programs (one per controlled junction)
    stop_junctions: int  # priority_stop and allway_stop junctions
    sidewalks: int  # pedestrian-only lanes
    crossings: int  # crossing edges
    walking_areas: int  # walking-area edges
    source_tl_signals: int  # traffic-light signals in the .xodr (0 for OSM)
    source_stop_signs: int  # stop signs in the .xodr (0 for OSM)
    source_controllers: int  # signal controllers (<controller>) in the .xodr (0 for OSM)
    seconds: float  # [s] wall time of the whole import
    warnings: tuple[str, ...] = ()  # netconvert warnings as "count x message", most frequent kind first
    lane_end_repairs: tuple[str, ...] = ()  # vehicle lanes cut back to the next road (lane_ends)


@dataclass(frozen=True)
class OpenDriveIdMap:
    """OpenDRIVE ids of an imported network, read back from its parameters (``opendrive_id_map``).

    ``road_edges``: road id -> its normal edges (right-hand side ``-R``, ``-R#k`` first, then the
    left-hand ``R``, ``R#k``, each by lane section). ``lanes``: (road id, lane section index, OpenDRIVE
    lane id) -> lane id. The section index is netconvert's (``#k``): the OpenDRIVE laneSection index,
    except that netconvert drops sections shorter than 0.1 m, splits sections where a lane's speed
    changes or a tapering lane's width crosses 1.8 m, and halves a road that starts and ends at the
    same junction; ``lanes_of`` collects a lane over all sections. ``connecting_roads``: junction road id ->
    internal lane ids of the connections built from it. ``junctions``: OpenDRIVE junction id -> junction
    id (equal, unless netconvert joined junctions). ``tl_signals``: traffic-light signal id -> traffic
    light id; ``stop_signals``: stop-sign id -> junction id. Not mapped: lanes of type ``none``,
    sidewalks inside junctions (walking areas replace them), objects, and all other signals.
    """

    road_edges: dict[str, tuple[str, ...]]
    lanes: dict[tuple[str, int, int], str]
    connecting_roads: dict[str, tuple[str, ...]]
    junctions: dict[str, str]
    tl_signals: dict[str, str]
    stop_signals: dict[str, str]

    def lanes_of(self, road: str, lane: int) -> tuple[str, ...]:
        """Lane ids of OpenDRIVE lane ``lane`` of ``road`` over all its lane sections, in section order."""
        return tuple(self.lanes[k] for k in sorted(k for k in self.lanes if k[0] == road and k[2] == lane))


# --------------------------------------------------------------------------------------------------
# the import


CARLA_TOWNS = tuple(f"Town0{k}" for k in range(1, 8))  # CARLA's towns committed as imported networks


def carla_town_source(folder: Path, town: str) -> Path:
    """The .xodr of a CARLA town in ``folder``: ``with-signals/<town>.xodr`` (the RoadRunner export with its
    real light signals, which the leaderboard's coordinates use) when present, else ``<town>.xodr``."""
    for candidate in (folder / "with-signals" / f"{town}.xodr", folder / f"{town}.xodr"):
        if candidate.is_file():
            return candidate
    raise MapError(f"no {town}.xodr in {folder} (nor in {folder / 'with-signals'})")


def import_map(src: Path | str, dst: Path | str, options: ImportOptions | None = None) -> ImportReport:
    """Convert the OpenDRIVE or OpenStreetMap file ``src`` into the SUMO network ``dst``.

    Raises MapError for bad input and NetconvertError when netconvert is missing or fails, naming
    ``src``. ``dst`` is replaced atomically on success; a failed import leaves nothing behind.
    """
    start = time.perf_counter()
    src, dst, options = Path(src), Path(dst), options or ImportOptions()
    kind = detect_source(src)
    if dst.is_dir():
        raise MapError(f"cannot import {src}: the output {dst} is a folder")
    xodr = read_xodr(src) if kind == "opendrive" else None
    find_netconvert()  # fail before creating anything when netconvert is missing
    created_parent = not dst.parent.exists()
    dst.parent.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix=f".{dst.name}.", dir=dst.parent))
    try:
        result = work / "result.net.xml"
        repaired: tuple[str, ...] = ()
        if xodr is not None:
            tls_source, logs = _import_opendrive(src, result, xodr, options, work)
            text, repairs = repair_lane_ends(result.read_text(encoding="utf-8"))
            result.write_text(text, encoding="utf-8")
            repaired = tuple(f"{r.lane} (-{r.dropped} points, via {r.internal})" for r in repairs)
        else:
            tls_source, logs = _import_osm(src, result, options, work)
        net = read_net(result)
        if not net.edges:
            raise MapError(f"{src} produced a network without roads")
        warnings = summarise_warnings(line for log in logs for line in _lines(log))
        write_with_fixed_header(
            result,
            dst,
            lambda tool: (
                f"{src.name} (sha256 {file_sha256(src)[:16]}) imported by cmudrive.maps.importer "
                f"with {tool}; rebuild: cmudrive maps import {src.name} -o {dst.name}"
            ),
            str(src),
        )
    except BaseException:
        shutil.rmtree(work, ignore_errors=True)
        if created_parent and not any(dst.parent.iterdir()):
            dst.parent.rmdir()
        raise
    finally:
        shutil.rmtree(work, ignore_errors=True)
    lanes = [lane for edge in net.edges.values() for lane in edge.lanes]
    return ImportReport(
        dst=dst,
        source=src,
        kind=kind,
        tls_source=tls_source if net.tls else "none",
        edges=len(net.edges),
        driving_lanes=sum(lane.allows("passenger") for lane in lanes),
        tls=len(net.tls),
        stop_junctions=sum(t in ("priority_stop", "allway_stop") for t in net.junction_types.values()),
        sidewalks=sum(lane.allow == {"pedestrian"} for lane in lanes),
        crossings=net.functions["crossing"],
        walking_areas=net.functions["walkingarea"],
        source_tl_signals=len(xodr.tl_signal_ids()) if xodr else 0,
        source_stop_signs=len({s.id for s in xodr.signs(STOP_SIGN)}) if xodr else 0,
        source_controllers=xodr.controllers if xodr else 0,
        seconds=time.perf_counter() - start,
        warnings=warnings,
        lane_end_repairs=repaired,
    )


def detect_source(src: Path) -> SourceKind:
    """Kind of map file ``src``, from its name and its root element; MapError if it is neither."""
    if not src.is_file():
        raise MapError(f"map source not found (or not a file): {src}")
    name = src.name.lower()
    if name.endswith(".xodr"):
        kind: SourceKind = "opendrive"
    elif name.endswith((".osm", ".osm.xml")):
        kind = "osm"
    else:
        raise MapError(f"unsupported map format for {src}: expected .xodr, .osm or .osm.xml")
    label, expected = _LABELS[kind]
    try:
        root = next(elem.tag for _, elem in ET.iterparse(src, events=("start",)))
    except (ET.ParseError, OSError, UnicodeDecodeError, StopIteration) as exc:
        raise MapError(f"{src} is not an {label} file (not readable XML: {exc})") from exc
    if root != expected:
        raise MapError(f"{src} is not an {label} file: root element <{root}>, expected <{expected}>")
    return kind


def _import_opendrive(
    src: Path, dst: Path, xodr: Xodr, options: ImportOptions, work: Path
) -> tuple[TlsSource, list[Path]]:
    policy = options.tls if options.tls != "auto" else ("opendrive" if xodr.tl_signal_ids() else "guess")
    first, logs = work / "pass1.net.xml", [work / "pass1.log", work / "pass2.log"]
    args = [
        "--opendrive-files", str(src), "--type-files", str(TYPEMAP),
        "--offset.disable-normalization", "--output.original-names",
        "--opendrive.curve-resolution", f"{options.curve_resolution:g}",
        "--crossings.guess", "--walkingareas", "--error-log", str(logs[0]), "--aggregate-warnings", "-1",
    ]  # fmt: skip
    if policy == "none":
        args.append("--tls.discard-loaded")
    elif options.signal_groups:
        args.append("--opendrive.signal-groups")
    if not TYPEMAP.is_file():
        raise MapError(f"cannot import {src}: the lane type map {TYPEMAP} is missing from the installation")
    run_netconvert(args, first, source=str(src))

    net = read_net(first)
    stops = sign_approaches(xodr, net, STOP_SIGN)
    signed = set(stops) | set(sign_approaches(xodr, net, YIELD_SIGN))
    guessed = guess_tls(xodr, net, signed) if policy == "guess" else []
    stubs = dead_end_stubs(first)
    nodes, edges = work / "patch.nod.xml", work / "patch.edg.xml"
    write_patches(nodes, edges, xodr, net, stops, options.road_speeds, frozenset(s.stub for s in stubs))
    args = [
        "--sumo-net-file", str(first), "--node-files", str(nodes), "--edge-files", str(edges),
        "--offset.disable-normalization", "--output.original-names",
        "--error-log", str(logs[1]), "--aggregate-warnings", "-1",
    ]  # fmt: skip
    if guessed:
        args += ["--tls.set", ",".join(guessed)]
    if stubs:  # degenerate roads: drive on into the sibling road, as CARLA does
        connections = work / "stubs.con.xml"
        write_stub_connections(connections, stubs)
        args += ["--connection-files", str(connections)]
        args += ["--remove-edges.explicit", ",".join(s.stub for s in stubs)]
    run_netconvert(args, dst, source=str(src))
    return ("guessed" if guessed else "opendrive" if policy != "none" else "none"), logs


def _import_osm(src: Path, dst: Path, options: ImportOptions, work: Path) -> tuple[TlsSource, list[Path]]:
    log = work / "osm.log"
    args = ["--osm-files", str(src), "--output.original-names", *_OSM_OPTIONS]
    args += ["--error-log", str(log), "--aggregate-warnings", "-1"]
    typemaps = _sumo_typemaps("osmNetconvert.typ.xml", "osmNetconvertPedestrians.typ.xml")
    if typemaps:
        args += ["--type-files", ",".join(typemaps)]
    if options.tls == "none":
        args.append("--tls.discard-loaded")
    elif options.tls == "guess":
        args.append("--tls.guess")
    run_netconvert(args, dst, source=str(src))
    return ("none" if options.tls == "none" else "osm"), [log]


def _sumo_typemaps(*names: str) -> list[str]:
    """SUMO's own OSM type maps (shipped beside netconvert), when this installation has them."""
    folder = find_netconvert().resolve().parent.parent / "data" / "typemap"
    paths = [folder / name for name in names]
    return [str(p) for p in paths] if all(p.is_file() for p in paths) else []


# --------------------------------------------------------------------------------------------------
# warnings and the id map


def _lines(path: Path) -> list[str]:
    return path.read_text(encoding="utf-8", errors="replace").splitlines() if path.exists() else []


_QUOTED = re.compile(r"(?<!\w)'[^']*'")
_NUMBER = re.compile(r"-?\d+(\.\d+)?")


def summarise_warnings(lines: Iterable[str], keep: int = WARNING_KINDS) -> tuple[str, ...]:
    """Group netconvert warnings by kind, ids and numbers masked: ("37 x Lane '%' is not ...", ...)."""
    kinds: Counter[str] = Counter(
        _NUMBER.sub("#", _QUOTED.sub("'%'", line.removeprefix("Warning: ").strip()))
        for line in lines
        if line.startswith("Warning: ")
    )
    return tuple(f"{n} x {message}" for message, n in kinds.most_common(keep))


def opendrive_id_map(net_path: Path | str) -> OpenDriveIdMap:
    """Read the OpenDRIVE road, lane, junction and signal ids back from a network ``import_map`` wrote."""
    net = read_net(Path(net_path))
    road_edges: dict[str, tuple[str, ...]] = {}
    lanes: dict[tuple[str, int, int], str] = {}
    for road, edges in edges_by_road(net).items():
        sections = {e.id: section_of(e.id, road) for e in edges}
        order = {e_id: (2, 0) if sec is None else (int(not sec[0]), sec[1]) for e_id, sec in sections.items()}
        road_edges[road] = tuple(sorted(sections, key=lambda e_id: (order[e_id], e_id)))
        for edge in edges:
            sec = sections[edge.id]
            for lane in edge.lanes:
                for lane_road, _, lane_id in (tok.rpartition("_") for tok in lane.orig):
                    if lane_road == road and sec is not None and lane_id.lstrip("-").isdigit():
                        lanes[(road, sec[1], int(lane_id))] = lane.id
    connecting: dict[str, list[str]] = defaultdict(list)
    for lane in net.internal_lanes:
        for tok in lane.orig:
            connecting[tok.rpartition("_")[0]].append(lane.id)
    params = net.junction_params
    return OpenDriveIdMap(
        road_edges=road_edges,
        lanes=lanes,
        connecting_roads={road: tuple(ids) for road, ids in connecting.items()},
        junctions={p[JUNCTION_PARAM]: j for j, p in params.items() if JUNCTION_PARAM in p},
        tl_signals={
            signal: tls
            for tls, p in net.tls.items()
            for key, value in p.items()
            if key.startswith("linkSignalID:")
            for signal in value.split()
        },
        stop_signals={
            signal: j for j, p in params.items() for signal in p.get(STOP_SIGNALS_PARAM, "").split()
        },
    )
