"""The comparison report (``cmudrive report RUN [RUN...]``): hand-built runs of two agents x two seeds on
one route set give the mean ± std, grouping, empty categories and infraction markers the page shows;
runs that cannot be compared are refused naming the file; the page renders in headless Chromium with
every picture loaded (skipped, saying why, without a chromium binary)."""

from __future__ import annotations

import json
import math
import re
import shutil
import subprocess
from pathlib import Path

import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from typer.testing import CliRunner

from cmudrive.bench.compare import Stat, compare, mean_std
from cmudrive.bench.metrics import route_result
from cmudrive.bench.records import (
    INFRACTION_KEYS,
    STATUS_BLOCKED,
    STATUS_COMPLETED,
    STATUS_INVALID_ROUTE,
    STATUS_PERFECT,
    CavResult,
    Infraction,
    RouteResult,
)
from cmudrive.bench.report import EMPTY
from cmudrive.bench.runs import RunError, group_runs, load_run
from cmudrive.cli import app
from cmudrive.viz.compare_report import infraction_points, write_comparison
from cmudrive.viz.infraction_map import GID_PREFIX, draw_infractions

ROUTE_SET = "f" * 64  # the manifest's hash of the route set


def cav(cav_id: str, rc: float = 100.0, **infractions: Infraction) -> CavResult:
    events = {k: [] for k in INFRACTION_KEYS}
    for key, inf in infractions.items():
        events[key].append(inf)
    factor = math.prod(i.factor for i in infractions.values())
    penalised = any(k != "min_speed_infractions" for k in infractions)
    status = STATUS_BLOCKED if rc < 100 else STATUS_COMPLETED if penalised else STATUS_PERFECT
    return CavResult(cav_id, status, rc, factor, 200.0, events)


def inf(key: str, x: float, y: float, factor: float) -> Infraction:
    return Infraction(key, 10, 0.5, x, y, f"{key} at (x={x}, y={y})", factor)


def routes(town: str, agent: str, seed: int) -> list[RouteResult]:
    """Four routes on ``town``: r0 Accident (ClearNoon, 2 CAVs), r1 no scenario (ClearNoon, 2), r2 no
    scenario (HardRainNoon, 3), r3 PedestrianCrossing (FogMorning, 2), which pid's runs could not run.

    DS per route: expert seed 0: 100, 75 (a CAV blocked at 50 %), 100, 100 (a min-speed record: no
    penalty) -> 93.75; seed 1: 100, 100, 80 (a CAV at 40 %), 100 -> 95. pid seed 0: 60 (vehicle
    collision), 100, 100, invalid -> 86.67 over 3; seed 1: 100, 70 (red light), 100 -> 90."""
    two, three = [cav("0"), cav("1")], [cav("0"), cav("1"), cav("2")]
    cavs = {
        ("expert", 0): [
            two,
            [cav("0"), cav("1", 50.0)],
            three,
            [cav("0"), cav("1", min_speed_infractions=inf("min_speed_infractions", 100.0, -1.6, 1.0))],
        ],
        ("expert", 1): [two, two, [cav("0"), cav("1"), cav("2", 40.0)], two],
        ("pid", 0): [
            [cav("0", collisions_vehicle=inf("collisions_vehicle", 150.0, -1.6, 0.6)), cav("1")],
            two,
            three,
            [],
        ],
        ("pid", 1): [two, [cav("0"), cav("1", red_light=inf("red_light", 195.0, -1.6, 0.7))], three, []],
    }[agent, seed]
    setup = [("r0", "ClearNoon", "Accident"), ("r1", "ClearNoon", ""), ("r2", "HardRainNoon", ""),
             ("r3", "FogMorning", "PedestrianCrossing")]  # fmt: skip
    out = []
    for (rid, weather, scenario), cs in zip(setup, cavs, strict=True):
        r = route_result(rid, town, weather, scenario, cs, num_cavs=len(cs) or 2)
        if not cs:
            r.status = STATUS_INVALID_ROUTE
        out.append(r)
    return out


def write_run(
    root: Path, town: str, agent: str, seed: int, *, options: dict | None = None, route_set: str = ROUTE_SET
) -> Path:
    """A run folder as cmudrive eval writes it: results.json (with the manifest) and run.json."""
    root.mkdir(parents=True)
    spec = {"expert": "cmudrive.agents.expert:ExpertAgent", "pid": "cmudrive.agents.pid:PidAgent"}[agent]
    setup = {"kind": "eval", "agent": spec, "agent_options": options or {}, "agent_files": {}, "seed": seed,
             "max_memory": None, "config": {"tick_cap": 4000}, "job": None}  # fmt: skip
    manifest = {
        "format": "cmudrive.run",
        "version": 1,
        "setup": setup,
        "setup_sha256": f"{agent}{seed}".ljust(64, "0"),
        "runs": [{"routes": {"count": 4, "sha256": route_set, "file": str(root / "routes.xml")}, "code": {}}],
    }
    records = [r.to_json() for r in routes(town, agent, seed)]
    (root / "run.json").write_text(json.dumps(manifest))
    results = {"summary": {"num_expected": 4}, "routes": records, "run": manifest}
    (root / "results.json").write_text(json.dumps(results))
    return root


@pytest.fixture
def four_runs(tmp_path: Path, mini_net: Path) -> list[Path]:
    return [write_run(tmp_path / f"{a}-s{s}", str(mini_net), a, s) for a in ("expert", "pid") for s in (0, 1)]


def row(page: str, table: str, attr: str, key: str) -> list[str]:
    """The cells' text of the row ``attr=key`` of table ``table`` in the page."""
    body = page.split(f'<table id="{table}">', 1)[1].split("</table>", 1)[0]
    tr = re.search(rf'<tr {attr}="{re.escape(key)}">(.*?)</tr>', body, re.S)
    assert tr is not None, f"no row {key} in {table}"
    return [re.sub(r"<[^>]+>", "", c).strip() for c in re.findall(r"<td[^>]*>(.*?)</td>", tr.group(1), re.S)]


def test_mean_and_sample_std() -> None:
    stat = mean_std([93.75, 95.0])
    assert stat is not None and stat.mean == pytest.approx(94.375) and stat.n == 2
    assert stat.std == pytest.approx(1.25 / math.sqrt(2.0))  # n - 1 in the denominator
    assert mean_std([3.0]) == Stat(3.0, None, 1) and mean_std([]) is None
    assert Stat(94.375, 0.8839, 2).text() == "94.38 ± 0.88" and Stat(3.0, None, 1).text() == "3.00"


def test_two_agents_two_seeds_mean_std_grouping_and_empty_categories(four_runs: list[Path], tmp_path: Path):
    paths = write_comparison(four_runs, tmp_path / "out")
    page = (tmp_path / "out" / "index.html").read_text()
    assert paths[0].name == "index.html" and all(p.is_file() for p in paths)
    assert not (tmp_path / "out" / "summary.md").exists()  # the single-run outputs: one run only

    # grouping: seeds of one setup, said in the page, one table row per run
    assert "everything but the seed" in page
    runs_table = page.split('<table id="runs">', 1)[1].split("</table>", 1)[0]
    assert runs_table.count("<tr>") == 5  # head + 4 runs
    ds = row(page, "overall", "data-metric", "driving_score")
    assert ds[1:] == ["94.38 ± 0.88", "88.33 ± 2.36"]  # expert (93.75, 95), pid (86.67, 90)
    sr = row(page, "overall", "data-metric", "success_rate")
    assert sr[1:] == ["75.00 ± 0.00", "66.67 ± 0.00"]  # expert 3/4 twice (min speed: success); pid 2/3
    is_ = row(page, "overall", "data-metric", "infraction_score")
    assert is_[1:] == ["1.000 ± 0.000", "0.883 ± 0.024"]  # pid: (0.6 + 1 + 1) / 3 and (1 + 0.7 + 1) / 3

    # a category no run has is left out (types, weathers, abilities alike); one a group lacks is "-"
    types = page.split('id="by-scenario_type"')[1].split("</table>")[0]
    assert re.findall(r'<tr data-category="([^"]*)">', types) == ["Accident", "PedestrianCrossing", ""]
    weathers = page.split('id="by-weather"')[1].split("</table>")[0]
    assert re.findall(r'<tr data-category="([^"]*)">', weathers) == [
        "ClearNoon",
        "HardRainNoon",
        "FogMorning",
    ]
    assert "CloudySunset" not in page and "Give_Way" not in page and "VehicleTurningRoute" not in page
    fog = row(page, "by-weather", "data-category", "FogMorning")
    assert fog[1:6] == ["100.00 ± 0.00", "100.00 ± 0.00", "100.00 ± 0.00", "1.000 ± 0.000", "1"]
    assert fog[6:] == [EMPTY] * 5  # pid's runs could not run r3
    clear = row(page, "by-weather", "data-category", "ClearNoon")
    assert clear[1] == "93.75 ± 8.84" and clear[6] == "82.50 ± 3.54"  # expert (100, 87.5); pid (80, 85)
    braking = row(page, "by-ability", "data-category", "Emergency_Brake")
    assert braking[1] == "100.00 ± 0.00" and braking[7:] == [EMPTY] * 6

    # the same categories in the charts: one chart per breakdown that has some
    assert {p.name for p in paths if p.name.startswith("compare_")} == {
        "compare_overall.png", "compare_by_ability.png", "compare_by_scenario_type.png",
        "compare_by_num_cavs.png", "compare_by_weather.png",
    }  # fmt: skip
    csv_text = (tmp_path / "out" / "comparison.csv").read_text()
    assert "overall,all,expert,driving_score,94.375," in csv_text


def test_infraction_map_draws_one_marker_per_placed_record(
    four_runs: list[Path], mini_net: Path, tmp_path: Path
):
    """Three records with a place (expert's min-speed record, pid's collision and red light): three
    markers, one collection per (kind, group); the page names the count per group; a record without a
    place is counted apart."""
    runs = [load_run(p) for p in four_runs]
    comparison = compare(group_runs(runs))
    points = infraction_points(comparison)[str(mini_net)]
    fig = Figure()
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    counts = draw_infractions(ax, points)
    assert counts == {(0, "min_speed_infractions"): 1, (1, "collisions_vehicle"): 1, (1, "red_light"): 1}
    drawn = {
        c.get_gid(): len(c.get_offsets()) for c in ax.collections if str(c.get_gid()).startswith(GID_PREFIX)
    }
    assert drawn == {
        f"{GID_PREFIX}min_speed_infractions:0": 1,
        f"{GID_PREFIX}collisions_vehicle:1": 1,
        f"{GID_PREFIX}red_light:1": 1,
    }
    hollow = next(c for c in ax.collections if c.get_gid() == f"{GID_PREFIX}min_speed_infractions:0")
    assert len(hollow.get_facecolors()) == 0  # too slow: an outline, not a filled mark

    results = json.loads((four_runs[3] / "results.json").read_text())
    results["routes"][0]["cavs"][0]["infractions"]["collisions_vehicle"] = [
        dict(inf("collisions_vehicle", math.nan, math.nan, 1.0).__dict__)
    ]
    (four_runs[3] / "results.json").write_text(json.dumps(results))
    write_comparison(four_runs, tmp_path / "out")
    page = (tmp_path / "out" / "index.html").read_text()
    assert "3 markers: expert 1, pid 2; 1 records without a place not drawn" in page
    assert page.count('<img class="map"') == 1


def test_replay_links_for_runs_with_logs(four_runs: list[Path], tmp_path: Path):
    logs = four_runs[0] / "logs"
    logs.mkdir()
    (logs / "r1.npz").write_bytes(b"log")
    (logs / "r1.mp4").write_bytes(b"video")
    write_comparison(four_runs, tmp_path / "out")
    page = (tmp_path / "out" / "index.html").read_text()
    replays = page.split('<table id="replays">', 1)[1].split("</table>", 1)[0]
    assert replays.count("<tr>") == 2  # head + the one route with a log
    assert f"cmudrive replay {logs / 'r1.npz'} -o {logs / 'r1.mp4'}" in replays
    assert 'href="../expert-s0/logs/r1.npz"' in replays and 'href="../expert-s0/logs/r1.mp4"' in replays


def test_grouping_labels_and_one_run(tmp_path: Path, mini_net: Path) -> None:
    """Runs with other options are another group, labelled by them; with one run the single-run report is
    written too."""
    a = write_run(tmp_path / "a", str(mini_net), "expert", 0)
    b = write_run(tmp_path / "b", str(mini_net), "expert", 1, options={"speed": 5})
    groups = group_runs([load_run(a), load_run(b)])
    assert [g.label for g in groups] == ["expert", "expert (speed=5)"]
    stopped = tmp_path / "stopped"  # a run stopped before results.json: its route records are read
    (stopped / "routes").mkdir(parents=True)
    for r in routes(str(mini_net), "expert", 1):
        (stopped / "routes" / f"{r.route_id}.json").write_text(json.dumps(r.to_json()))
    assert [r.route_id for r in load_run(stopped).routes] == ["r0", "r1", "r2", "r3"]
    paths = write_comparison([a], tmp_path / "one")
    names = {p.name for p in paths}
    assert {"index.html", "summary.md", "routes.csv", "by_scenario_type.png"} <= names
    page = (tmp_path / "one" / "index.html").read_text()
    assert row(page, "overall", "data-metric", "driving_score")[1:] == ["93.75"]  # a value, no spread


def test_runs_that_cannot_be_compared_are_refused_naming_the_file(tmp_path: Path, mini_net: Path) -> None:
    a = write_run(tmp_path / "a", str(mini_net), "expert", 0)
    other = write_run(tmp_path / "other", str(mini_net), "pid", 0, route_set="e" * 64)
    with pytest.raises(
        RunError, match=rf"{other}/results\.json and {a}/results\.json are runs of different route"
    ):
        write_comparison([a, other], tmp_path / "out")
    (tmp_path / "empty").mkdir()
    with pytest.raises(RunError, match=rf"{tmp_path / 'empty'}: not a run folder \(no results\.json"):
        write_comparison([a, tmp_path / "empty"], tmp_path / "out")
    with pytest.raises(RunError, match=rf"{a}/run\.json: not a results file of cmudrive eval"):
        write_comparison([a / "run.json"], tmp_path / "out")
    with pytest.raises(RunError, match=rf"{tmp_path / 'nowhere'}: no such run folder or results file"):
        load_run(tmp_path / "nowhere")
    with pytest.raises(RunError, match="the same run is given twice"):
        write_comparison([a, a / "results.json"], tmp_path / "out")
    result = CliRunner().invoke(app, ["report", str(a), str(other), "-o", str(tmp_path / "cli")])
    assert result.exit_code == 1 and "different route sets" in result.output
    assert not (tmp_path / "cli" / "index.html").exists()


CHROMIUM = next(
    (shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome") if shutil.which(n)), None
)


@pytest.mark.skipif(
    CHROMIUM is None, reason="no chromium binary (apt-get install chromium) to render the page"
)
def test_page_renders_in_headless_chromium_with_every_image(four_runs: list[Path], tmp_path: Path) -> None:
    """The page as a browser builds it from disk: every <img> loaded (the page's own check writes the count
    into the DOM after load), the overall table's numbers, and a screenshot that is not blank."""
    write_comparison(four_runs, tmp_path / "out")
    url = (tmp_path / "out" / "index.html").as_uri()
    flags = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--virtual-time-budget=5000"]
    dom = subprocess.run(
        [*flags, "--dump-dom", url], capture_output=True, text=True, timeout=120, check=True
    ).stdout
    check = re.search(r'id="image-check"[^>]*data-loaded="(\d+)" data-total="(\d+)"', dom)
    assert check is not None, "the page's image check did not run"
    assert int(check.group(1)) == int(check.group(2)) == 6  # 5 charts, 1 map, and nothing broken
    assert 'data-broken="1"' not in dom  # an <img> the check found broken
    assert "94.38 ± 0.88" in dom and "88.33 ± 2.36" in dom

    shot = tmp_path / "shot.png"
    subprocess.run([*flags, f"--screenshot={shot}", "--window-size=1200,1600", url],
                   capture_output=True, timeout=120, check=True)  # fmt: skip
    from PIL import Image

    with Image.open(shot) as img:
        colours = img.convert("RGB").getcolors(maxcolors=1 << 20)
    assert colours is not None and len(colours) > 200  # text, tables and charts, not a blank page
