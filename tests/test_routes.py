"""Route files: exact round trip, validation errors that name file/route/CAV, the Leaderboard 2.0 importer,
multi-CAV generation on the committed towns, and the committed smoke route file."""

from __future__ import annotations

import pickle
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from cmudrive.bench.authoring.bench2drive import import_leaderboard_routes
from cmudrive.bench.authoring.route_gen import (
    MIN_START_GAP,
    START_RING,
    START_RING_WIDENED,
    add_cavs,
    generate_routes,
)
from cmudrive.bench.routes import CavSpec, RouteSpec, RouteSpecError, ScenarioSpec, read_routes, write_routes
from cmudrive.cli.routes import generate_main
from cmudrive.maps import RouteError, available_towns, densify, load_map

FIXTURES = Path(__file__).parent / "fixtures"
SMOKE = Path(__file__).resolve().parents[1] / "cmudrive" / "assets" / "routes" / "smoke.xml"

# CAV 0 of the fixture's downtown route: real points of the network, CARLA frame (y mirrored)
DOWNTOWN_WPS = [[166.21, -277.78, 0.0], [216.21, -277.88, 0.0], [316.21, -278.39, 0.0], [416.2, -279.63, 0.0]]


def _spec(route_id: str = "r1", n_cavs: int = 2, **kw: object) -> RouteSpec:
    cavs = tuple(CavSpec(i, np.array(DOWNTOWN_WPS) + np.array([0.0, 0.0, i])) for i in range(n_cavs))
    args: dict[str, object] = dict(id=route_id, town="downtown", weather="ClearNoon", seed=7, cavs=cavs)
    args.update(kw)
    return RouteSpec(**args)  # type: ignore[arg-type]


def _route_xml(
    rid: str = "r1", attrs: str = 'town="downtown" weather="ClearNoon"', cavs: str | None = None
) -> str:
    pos = '<position x="166.21" y="-277.78" z="0"/><position x="316.21" y="-278.39" z="0"/>'
    if cavs is None:
        cavs = "".join(f'<cav id="{i}"><waypoints>{pos}</waypoints></cav>' for i in range(2))
    return f'<route id="{rid}" {attrs}>{cavs}</route>'


def _write(tmp_path: Path, *routes: str, name: str = "routes.xml") -> Path:
    path = tmp_path / name
    path.write_text("<routes>" + "".join(routes) + "</routes>")
    return path


# ------------------------------------------------------------------------------------------- file format
def test_round_trip_is_exact_and_rewrites_byte_identically(tmp_path: Path) -> None:
    wps = np.array([[0.1, -0.0, 1e-7], [1.0 / 3.0, 123456.789012345, -2.5], [5.0, 6.0, 7.0]])
    scenarios = (
        ScenarioSpec(
            "Accident_1", "Accident", (181.21, -277.81, 0.0, -0.1), {"distance": "42", "direction": "right"}
        ),
        ScenarioSpec(
            "EnterActorFlow_1",
            "EnterActorFlow",
            (1.0, 2.0, 3.0, 90.0),
            {
                "start_actor_flow": {"x": "1", "y": "2", "z": "0.5"},
                "source_dist_interval": {"from": "20", "to": "50"},
            },
        ),
    )
    routes = [
        _spec("a", 3, scenarios=scenarios, weather="FogMorning"),
        RouteSpec(
            "b & <c>", "nets/Town03.net.xml", "ClearNight", 0, (CavSpec(0, wps), CavSpec(1, wps[::-1]))
        ),
    ]
    routes.append(replace(routes[0], id="lights off", lights="off"))
    path = tmp_path / "out" / "routes.xml"
    write_routes(routes, path, comment="made by a test\nsecond line")
    back = read_routes(path)
    assert back == routes
    assert [r.lights for r in back] == ["on", "on", "off"] and path.read_text().count('lights="off"') == 1
    assert back[0].scenarios[1].params["source_dist_interval"] == {"from": "20", "to": "50"}
    assert back[0].scenarios[0].params["distance"] == "42"
    write_routes(back, tmp_path / "again.xml", comment="made by a test\nsecond line")
    assert (tmp_path / "again.xml").read_bytes() == path.read_bytes()
    assert "made by a test" in path.read_text()
    assert [p.name for p in path.parent.iterdir()] == ["routes.xml"]  # no temporary file left behind


def test_map_waypoints_mirror_y() -> None:
    spec = _spec()
    xy = spec.map_waypoints(1)
    assert xy.shape == (4, 2)
    assert np.allclose(xy, np.array(DOWNTOWN_WPS)[:, :2] * [1.0, -1.0])
    assert spec.cavs[0].waypoints.flags.writeable is False
    x, y, yaw = ScenarioSpec("s", "ControlLoss", (10.0, -20.0, 0.0, -90.0)).map_trigger()
    assert (x, y, yaw) == pytest.approx((10.0, 20.0, np.pi / 2))


def _cavs_xml(*ids: int) -> str:
    two = '<position x="0" y="0" z="0"/><position x="1" y="0" z="0"/>'
    return "".join(f'<cav id="{i}"><waypoints>{two}</waypoints></cav>' for i in ids)


SEVENTEEN = _cavs_xml(*range(17))
BAD_ROUTES = {
    "missing town": (_route_xml(attrs='weather="ClearNoon"'), None, "missing town"),
    "unknown weather": (_route_xml(attrs='town="downtown" weather="Sunny"'), None, "unknown weather 'Sunny'"),
    "unknown lights": (
        _route_xml(attrs='town="downtown" weather="ClearNoon" lights="blinking"'),
        None,
        "lights must be one of on, off, got 'blinking'",
    ),
    "missing waypoints": (
        _route_xml(
            cavs='<cav id="0"><waypoints><position x="1" y="2"/><position x="3" y="4"/></waypoints></cav>'
            '<cav id="1"></cav>'
        ),
        1,
        "missing <waypoints>",
    ),
    "one CAV": (
        _route_xml(
            cavs='<cav id="0"><waypoints><position x="1" y="2"/><position x="3" y="4"/></waypoints></cav>'
        ),
        None,
        "needs 2-16 <cav> elements, got 1",
    ),
    "17 CAVs": (_route_xml(cavs=SEVENTEEN), None, "needs 2-16 <cav> elements, got 17"),
    "CAV ids": (
        _route_xml(cavs=_cavs_xml(0, 2)),
        None,
        "CAV ids must be 0..1, each once; got [0, 2]",
    ),
    "one waypoint": (
        _route_xml(
            cavs='<cav id="0"><waypoints><position x="1" y="2"/><position x="3" y="4"/></waypoints></cav>'
            '<cav id="1"><waypoints><position x="1" y="2"/></waypoints></cav>'
        ),
        1,
        "needs at least 2 waypoints, got 1",
    ),
    "non-numeric": (
        _route_xml(
            cavs='<cav id="0"><waypoints><position x="1" y="2"/><position x="abc" y="4"/></waypoints></cav>'
            '<cav id="1"><waypoints><position x="1" y="2"/><position x="3" y="4"/></waypoints></cav>'
        ),
        0,
        "waypoint 1: non-numeric x='abc'",
    ),
    "nan": (
        _route_xml(
            cavs='<cav id="0"><waypoints><position x="1" y="nan"/><position x="3" y="4"/></waypoints></cav>'
            '<cav id="1"><waypoints><position x="1" y="2"/><position x="3" y="4"/></waypoints></cav>'
        ),
        0,
        "waypoint 0: non-finite y='nan'",
    ),
    "scenario type": (
        _route_xml()[: -len("</route>")]
        + '<scenarios><scenario name="a" type="Acident"><trigger_point x="1" y="2" z="0" yaw="0"/></scenario>'
        "</scenarios></route>",
        None,
        "unknown scenario type 'Acident'; did you mean Accident",
    ),
    "single-ego file": (
        '<route id="r1" town="downtown"><waypoints><position x="1" y="2" z="0"/></waypoints></route>',
        None,
        "single-ego Leaderboard/Bench2Drive route file",
    ),
}


@pytest.mark.parametrize("case", list(BAD_ROUTES))
def test_each_validation_error_names_file_route_and_cav(tmp_path: Path, case: str) -> None:
    xml, cav, message = BAD_ROUTES[case]
    path = _write(tmp_path, xml)
    with pytest.raises(RouteSpecError) as info:
        read_routes(path)
    text = str(info.value)
    assert text.startswith(f"{path}, route 'r1'")
    assert message in text
    assert (f"CAV {cav}:" in text) == (cav is not None)
    assert info.value.route_id == "r1" and info.value.cav_id == cav and info.value.path == str(path)


def test_duplicate_route_ids_and_unreadable_files(tmp_path: Path) -> None:
    path = _write(tmp_path, _route_xml("r1"), _route_xml("r1"))
    with pytest.raises(RouteSpecError, match=r"route 'r1': duplicate route id"):
        read_routes(path)
    with pytest.raises(RouteSpecError, match="route file not found"):
        read_routes(tmp_path / "nope.xml")
    (tmp_path / "bad.xml").write_text("<routes><route")
    with pytest.raises(RouteSpecError, match=r"bad\.xml: not readable as XML"):
        read_routes(tmp_path / "bad.xml", strict=False)
    with pytest.raises(RouteSpecError, match="duplicate route ids"):
        write_routes([_spec("x"), _spec("x")], tmp_path / "dup.xml")


def test_lenient_reading_keeps_the_good_routes_and_lists_the_bad(tmp_path: Path) -> None:
    path = _write(
        tmp_path,
        _route_xml("good1"),
        _route_xml("bad", attrs='town="downtown" weather="Sunny"'),
        _route_xml("good2"),
        _route_xml("good1"),
        '<route town="downtown" weather="ClearNoon"/>',
    )
    routes, errors = read_routes(path, strict=False)
    assert [r.id for r in routes] == ["good1", "good2"]
    assert [e[0] for e in errors] == ["bad", "good1", "#5"]
    assert "unknown weather" in errors[0][1] and str(path) in errors[0][1]
    assert "duplicate route id" in errors[1][1] and "missing route id" in errors[2][1]
    with pytest.raises(RouteSpecError, match="route 'bad'"):
        read_routes(path)


def test_single_cav_routes_need_min_cavs_1(tmp_path: Path) -> None:
    spec = _spec(n_cavs=1)
    with pytest.raises(RouteSpecError, match="needs 2-16 CAVs, got 1"):
        write_routes([spec], tmp_path / "one.xml")
    write_routes([spec], tmp_path / "one.xml", min_cavs=1)
    assert read_routes(tmp_path / "one.xml", min_cavs=1) == [spec]
    with pytest.raises(RouteSpecError, match="got 1"):
        read_routes(tmp_path / "one.xml")


def test_spec_constructors_validate_and_errors_pickle() -> None:
    with pytest.raises(RouteSpecError, match=r"route 'r1': CAV ids must be 0\.\.1 in order"):
        _spec(cavs=(CavSpec(1, np.zeros((2, 3))), CavSpec(0, np.zeros((2, 3)))))
    with pytest.raises(RouteSpecError, match="duplicate scenario names"):
        trigger = (0.0, 0.0, 0.0, 0.0)
        _spec(
            scenarios=(
                ScenarioSpec("a", "ControlLoss", trigger),
                ScenarioSpec("a", "HardBreakRoute", trigger),
            )
        )
    with pytest.raises(RouteSpecError, match="shape"):
        CavSpec(0, np.zeros((3, 2)))
    assert ScenarioSpec("a", "Accident", (0, 0, 0, 0), {"distance": {"value": "4"}}).params == {
        "distance": "4"
    }
    err = RouteSpecError("bad", "f.xml", "r", 3)
    assert str(pickle.loads(pickle.dumps(err))) == str(err) == "f.xml, route 'r': CAV 3: bad"


# ------------------------------------------------------------------------------------------ LB2.0 import
def test_leaderboard_import_maps_waypoints_weather_scenarios_and_skips_unknown_towns() -> None:
    result = import_leaderboard_routes(FIXTURES / "leaderboard_routes.xml")
    assert [r.id for r in result.routes] == ["1"]
    available = ", ".join(available_towns())
    assert result.skipped == [
        ("2", f"town Town12 is not available; available: {available}"),
        ("3", f"town Town13 is not available; available: {available}"),
    ]
    spec = result.routes[0]
    assert spec.town == "downtown" and spec.seed == 0 and len(spec.cavs) == 1
    assert spec.weather == "HardRainNoon"  # the route_percentage 0 weather (rain), not the clear one at 100 %
    assert spec.cavs[0].waypoints.tolist() == [*DOWNTOWN_WPS, [516.2, -279.78, 0.0]]
    assert [(s.name, s.type) for s in spec.scenarios] == [
        ("HazardAtSideLaneTwoWays_1", "HazardAtSideLaneTwoWays"),
        ("ParkedObstacleTwoWays_1", "ParkedObstacleTwoWays"),
    ]
    assert spec.scenarios[0].trigger == (181.21, -277.81, 0.0, -0.1)
    assert spec.scenarios[0].params == {
        "distance": "42",
        "frequency": "90",
        "bicycle_drive_distance": "100",
        "bicycle_speed": "9",
    }
    assert spec.scenarios[1].params["frequency"] == {"from": "45", "to": "130"}
    route = densify(load_map("downtown"), spec.map_waypoints(0))  # the fixture's points are on the town
    assert route.length == pytest.approx(350.0, abs=2.0)


def test_leaderboard_import_with_user_towns(tmp_path: Path) -> None:
    result = import_leaderboard_routes(
        FIXTURES / "leaderboard_routes.xml", towns=["Town12", "nets/Town13.net.xml"]
    )
    assert result.skipped == []
    by_id = {r.id: r for r in result.routes}
    # a network file serves its town by name: the route keeps "Town13", and looks in nets/ first
    assert by_id["2"].town == "Town12" and by_id["3"].town == "Town13"
    assert by_id["3"].town_dirs == (str(Path("nets").resolve()),) and by_id["2"].town_dirs == ()
    assert by_id["2"].weather == "ClearNoon" and by_id["3"].weather == "ClearNight"  # sun at -40 deg
    assert by_id["2"].scenarios[0].params["start_actor_flow"] == {"x": "-1272.0", "y": "2771.5", "z": "361.3"}
    # extra CAVs need the map: the made-up Town12 has none, so that route is skipped with the reason
    result = import_leaderboard_routes(
        FIXTURES / "leaderboard_routes.xml", towns=["Town12"], extra_cavs=3, seed=4
    )
    assert [r.id for r in result.routes] == ["1"] and len(result.routes[0].cavs) == 4
    assert [s[0] for s in result.skipped] == ["2", "3"] and "Town12" in result.skipped[0][1]
    again = import_leaderboard_routes(FIXTURES / "leaderboard_routes.xml", extra_cavs=3, seed=4)
    assert again.routes == result.routes  # per-route draws do not depend on the other routes
    write_routes(result.routes, tmp_path / "imported.xml")
    assert read_routes(tmp_path / "imported.xml") == result.routes


# ---------------------------------------------------------------------------------------- CAV generation
def _starts(spec: RouteSpec) -> tuple[np.ndarray, np.ndarray, list[float]]:
    m = load_map(spec.town)
    routes = [densify(m, spec.map_waypoints(c.id)) for c in spec.cavs]
    return (
        np.array([r.xy[0] for r in routes]),
        np.array([r.lane[0] for r in routes]),
        [r.length for r in routes],
    )


@pytest.mark.parametrize("n_total", [2, 16])
def test_add_cavs_on_downtown(n_total: int) -> None:
    base = import_leaderboard_routes(FIXTURES / "leaderboard_routes.xml").routes[0]
    spec = add_cavs(base, n_total, np.random.default_rng(11))
    assert len(spec.cavs) == n_total and [c.id for c in spec.cavs] == list(range(n_total))
    assert spec.cavs[0] == base.cavs[0] and spec.scenarios == base.scenarios
    starts, lanes, lengths = _starts(spec)  # every CAV's keypoints densify on the town
    assert len(set(lanes.tolist())) == n_total  # distinct start lanes
    gaps = np.linalg.norm(starts[:, None] - starts[None], axis=2) + np.eye(n_total) * 1e9
    assert gaps.min() >= MIN_START_GAP
    radius = np.linalg.norm(starts[1:] - starts[0], axis=1)
    assert radius.min() >= START_RING[0] and radius.max() <= START_RING_WIDENED[-1]
    if n_total == 2:
        assert radius.max() <= START_RING[1]
    assert min(lengths[1:]) >= 150.0 - 1.0
    m = load_map("downtown")
    route0 = densify(m, base.map_waypoints(0))
    ahead = set(route0.lane[route0.distance <= 60.0].tolist())
    assert not ahead & set(lanes[1:].tolist())  # nobody starts on CAV 0's lanes in its first 60 m
    assert add_cavs(base, n_total, np.random.default_rng(11)) == spec  # deterministic by the generator


def test_add_cavs_rejects_bad_counts_and_off_map_routes() -> None:
    base = _spec(n_cavs=1)
    with pytest.raises(ValueError, match=r"n_total must be in 1\.\.16"):
        add_cavs(base, 17, np.random.default_rng(0))
    far = RouteSpec(
        "far", "downtown", "ClearNoon", 0, (CavSpec(0, np.array([[5e3, 5e3, 0], [6e3, 5e3, 0]])),)
    )
    with pytest.raises(RouteError, match="route 'far' on 'downtown', CAV 0"):
        add_cavs(far, 3, np.random.default_rng(0))


def test_generate_routes_is_deterministic_by_seed() -> None:
    a = generate_routes("suburb", 2, 3, weather="FogMorning", seed=5)
    assert a == generate_routes("suburb", 2, 3, weather="FogMorning", seed=5)
    assert a != generate_routes("suburb", 2, 3, weather="FogMorning", seed=6)
    assert [r.id for r in a] == ["suburb_000", "suburb_001"] and [r.seed for r in a] == [5, 6]
    for spec in a:
        assert spec.weather == "FogMorning" and spec.scenarios == () and len(spec.cavs) == 3
        _, _, lengths = _starts(spec)
        assert 200.0 <= min(lengths) and max(lengths) <= 400.0
    with pytest.raises(ValueError, match="unknown weather"):
        generate_routes("suburb", 1, 3, weather="Sunny")


def test_generate_command_writes_a_readable_file_with_its_command(tmp_path: Path) -> None:
    out = tmp_path / "gen.xml"
    assert (
        generate_main(["generate", "-o", str(out), "-s", "3", "-p", "t", "suburb:2:ClearNight", "downtown"])
        == 0
    )
    routes = read_routes(out)
    assert [(r.id, r.town, len(r.cavs), r.weather) for r in routes] == [
        ("t_00", "suburb", 2, "ClearNight"),
        ("t_01", "downtown", 4, "ClearNoon"),
    ]
    assert "cmudrive routes generate" in out.read_text()


# ------------------------------------------------------------------------------------- committed routes
def test_committed_smoke_routes_parse_and_densify() -> None:
    routes = read_routes(SMOKE)
    assert [r.town for r in routes] == ["downtown", "downtown", "suburb", "interurban"]
    assert all(2 <= len(r.cavs) <= 4 for r in routes) and all(r.scenarios == () for r in routes)
    assert "cmudrive routes generate" in SMOKE.read_text()
    for spec in routes:
        m = load_map(spec.town)
        for cav in spec.cavs:
            route = densify(m, spec.map_waypoints(cav.id))
            assert 200.0 <= route.length <= 400.0, (spec.id, cav.id, route.length)


# ------------------------------------------------------------------------------------------ input bounds
def test_oversized_route_files_are_refused_before_planning(tmp_path: Path) -> None:
    """A CAV with more waypoints than MAX_WAYPOINTS, a file with more than MAX_FILE_WAYPOINTS and a file
    larger than MAX_FILE_BYTES are refused with the file (and route, CAV) named, in seconds: a 45 MB
    file once took minutes in planning."""
    from cmudrive.bench import routes as routes_module
    from cmudrive.bench.route_check import check_route_file

    pos = '<position x="166.21" y="-277.78" z="0"/>'
    many = _route_xml(
        "many",
        cavs='<cav id="0"><waypoints>' + pos * (routes_module.MAX_WAYPOINTS + 1) + "</waypoints></cav>"
        '<cav id="1"><waypoints>' + pos * 2 + "</waypoints></cav>",
    )
    path = _write(tmp_path, many, _route_xml("good"))
    t0 = time.monotonic()
    checks = check_route_file(path)
    assert time.monotonic() - t0 < 30.0
    assert [c.route_id for c in checks] == ["good", "many"]
    assert f"route 'many': CAV 0: {routes_module.MAX_WAYPOINTS + 1} waypoints, more than" in str(
        checks[1].problem
    )
    per_route = routes_module.MAX_WAYPOINTS // 2
    n_routes = routes_module.MAX_FILE_WAYPOINTS // (2 * per_route) + 1
    cavs = "".join(f'<cav id="{i}"><waypoints>{pos * per_route}</waypoints></cav>' for i in range(2))
    crowded = _write(tmp_path, *(_route_xml(f"r{k}", cavs=cavs) for k in range(n_routes)), name="c.xml")
    with pytest.raises(RouteSpecError, match=rf"c\.xml: {2 * per_route * n_routes} waypoints, more than"):
        read_routes(crowded, strict=False)
    huge = tmp_path / "huge.xml"
    huge.write_text("<routes><!--" + "x" * routes_module.MAX_FILE_BYTES + "-->" + _route_xml() + "</routes>")
    with pytest.raises(RouteSpecError, match=r"huge\.xml: the file is 16\.0 MiB, larger than the 16 MiB"):
        read_routes(huge, strict=False)


def test_route_ids_are_printable_and_bounded(tmp_path: Path) -> None:
    long_id, newline_id = "a" * 5000, "two&#10;lines"
    path = _write(tmp_path, _route_xml(long_id), _route_xml(newline_id), _route_xml("Accident_0 (b)"))
    routes, errors = read_routes(path, strict=False)
    assert [r.id for r in routes] == ["Accident_0 (b)"]
    assert [e[0] for e in errors] == ["#1", "#2"]  # the bad id is not repeated as a label
    assert "is 5000 characters long (at most 255)" in errors[0][1] and len(errors[0][1]) < 300
    assert "unprintable characters ['\\n']" in errors[1][1]
    with pytest.raises(RouteSpecError, match="unprintable"):
        _spec("tab\tid")
    lb = tmp_path / "lb.xml"
    lb.write_text(
        '<routes><route id="x&#10;y" town="Town03"><waypoints><position x="1" y="2" z="0"/>'
        '<position x="50" y="2" z="0"/></waypoints></route></routes>'
    )
    result = import_leaderboard_routes(lb)
    assert result.routes == [] and "unprintable" in result.skipped[0][1]


def test_cavs_starting_on_one_spot_are_refused_naming_them(tmp_path: Path) -> None:
    """16 CAVs on one start spawn inside each other (once: RC 19.6); `routes check` and the
    evaluator's planning (``dense_routes``) refuse them and name the CAVs."""
    from cmudrive.bench.route_check import check_route_file

    stacked = _spec("stacked", n_cavs=16)
    with pytest.raises(RouteError, match=r"route 'stacked' on 'downtown': CAVs 0 and 1 \(0\.0 m\), "):
        stacked.dense_routes(load_map("downtown"))
    behind = np.array(DOWNTOWN_WPS[1:])
    near = np.array(DOWNTOWN_WPS) + np.array([3.0, 0.0, 0.0])  # 3 m ahead on the same lane
    spaced = _spec("spaced", cavs=(CavSpec(0, np.array(DOWNTOWN_WPS)), CavSpec(1, behind)))
    close = _spec("close", cavs=(CavSpec(0, np.array(DOWNTOWN_WPS)), CavSpec(1, near)))
    write_routes([stacked, spaced, close], tmp_path / "r.xml")
    checks = {c.route_id: c.problem for c in check_route_file(tmp_path / "r.xml")}
    assert checks["spaced"] is None
    assert "CAVs 0 and 1 (3.0 m)" in str(checks["close"])
    assert "CAVs 0 and 1 (0.0 m), CAVs 0 and 2 (0.0 m)" in str(checks["stacked"])
    assert "and 115 more pairs" in str(checks["stacked"])


def test_eval_reads_routes_under_the_same_bounds(tmp_path: Path) -> None:
    """`cmudrive eval` reads its routes with read_routes: an oversized CAV and a bad id are refused with
    their reasons before any world starts; with --skip-invalid they are skipped, and a file with nothing
    left is refused."""
    from typer.testing import CliRunner

    from cmudrive.bench.routes import MAX_WAYPOINTS
    from cmudrive.cli import app

    pos = '<position x="166.21" y="-277.78" z="0"/>'
    cavs = f'<cav id="0"><waypoints>{pos * (MAX_WAYPOINTS + 1)}</waypoints></cav>'
    cavs += f'<cav id="1"><waypoints>{pos * 2}</waypoints></cav>'
    path = _write(tmp_path, _route_xml("many", cavs=cavs), _route_xml("bad&#10;id"))
    args = ["eval", "--routes", str(path), "--out", str(tmp_path / "out")]
    result = CliRunner().invoke(app, args)
    text = " ".join(result.output.split())
    assert result.exit_code == 1 and "2 routes cannot be read" in text
    assert f"{path}, route 'many': CAV 0: {MAX_WAYPOINTS + 1} waypoints" in text
    assert "route '#2': route id 'bad\\nid' holds unprintable characters" in text
    result = CliRunner().invoke(app, [*args, "--skip-invalid"])
    text = " ".join(result.output.split())
    assert result.exit_code == 1 and "no route to run (every route is invalid)" in text
    assert f"skipping route many: {path}, route 'many': CAV 0: {MAX_WAYPOINTS + 1} waypoints" in text
    assert "skipping route #2:" in text and "unprintable characters" in text
