"""The report: loading result records (merged file or per-route folder), tables and charts on disk."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
from PIL import Image

from cmudrive.bench.metrics import route_result
from cmudrive.bench.records import INFRACTION_KEYS, STATUS_BLOCKED, STATUS_PERFECT, CavResult, RouteResult
from cmudrive.bench.report import ResultsError, load_results, write_report

WEATHERS = ("ClearNoon", "CloudySunset", "HardRainNoon", "ClearNight", "FogMorning")


def perfect(cav_id: str) -> CavResult:
    return CavResult(cav_id, STATUS_PERFECT, 100.0, 1.0, 250.0, {k: [] for k in INFRACTION_KEYS})


def ten_routes() -> list[RouteResult]:
    """Routes 0-9; route i has 2 + i % 3 CAVs; routes 0-5 are perfect (DS 100), routes 6-9 have one CAV
    blocked at 50 % of its route (RC^j = 100 - 50 / N, DS^j = RC^j)."""
    routes = []
    for i in range(10):
        n = 2 + i % 3
        cavs = [perfect(str(c)) for c in range(n)]
        if i >= 6:
            cavs[-1].route_completion, cavs[-1].status = 50.0, STATUS_BLOCKED
        scenario = ("Accident", "PedestrianCrossing", "T_Junction")[i % 3]
        routes.append(route_result(f"route_{i:02d}", "downtown", WEATHERS[i % 5], scenario, cavs))
    return routes


def write_folder(root: Path, routes: list[RouteResult]) -> Path:
    (root / "routes").mkdir(parents=True)
    for r in routes:
        (root / "routes" / f"{r.route_id}.json").write_text(json.dumps(r.to_json()))
    return root


def test_report_from_a_folder_of_route_records(tmp_path: Path):
    routes = ten_routes()
    expected_ds = sum(r.driving_score for r in routes) / 10
    # routes 6..9 have 2, 3, 4, 2 CAVs: DS^j = 75, 83.33, 87.5, 75
    assert expected_ds == pytest.approx((600.0 + 75.0 + (100 - 50 / 3) + 87.5 + 75.0) / 10)
    paths = write_report(write_folder(tmp_path / "res", routes), tmp_path / "out")

    names = {p.name for p in paths}
    charts = {"by_scenario_type.png", "by_num_cavs.png", "by_weather.png"}
    assert names == {"summary.md", "summary.csv", "routes.csv", *charts}
    assert all(p.is_file() and p.stat().st_size > 0 for p in paths)

    md = (tmp_path / "out" / "summary.md").read_text()
    assert f"| Driving score DS (0-100) | {expected_ds:.2f} |" in md
    assert "| Success rate SR (%) | 60.00 |" in md
    assert "| Accident | 4 | " in md and "| T_Junction | 3 | " in md
    assert "VehicleTurningRoute" not in md  # no route has it: left out, as in the charts

    with (tmp_path / "out" / "routes.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [r["route_id"] for r in rows] == [f"route_{i:02d}" for i in range(10)]
    assert float(rows[7]["driving_score"]) == pytest.approx(100 - 50 / 3)

    with (tmp_path / "out" / "summary.csv").open() as f:
        summary = {(r["breakdown"], r["group"]): r for r in csv.DictReader(f)}
    assert float(summary["overall", "all"]["driving_score"]) == pytest.approx(expected_ds)
    assert summary["by_num_cavs", "3"]["num_routes"] == "3"

    with Image.open(tmp_path / "out" / "by_scenario_type.png") as img:
        assert img.size == (1200, 675)  # 8 x 4.5 in at 150 dpi for three types (all 44: 15 x 6 in)


def test_merged_results_file_is_preferred_and_missing_routes_count_zero(tmp_path: Path):
    routes = ten_routes()
    root = write_folder(tmp_path / "res", routes[:3])  # a stale folder: results.json wins
    (root / "results.json").write_text(json.dumps({"summary": {}, "routes": [r.to_json() for r in routes]}))
    assert [r.route_id for r in load_results(root)] == [r.route_id for r in routes]
    assert len(load_results(root / "routes")) == 3  # the per-route folder itself

    write_report(root / "results.json", tmp_path / "out", expected_routes=20)
    ds = sum(r.driving_score for r in routes) / 20
    md = (tmp_path / "out" / "summary.md").read_text()
    assert f"| Driving score DS (0-100) | {ds:.2f} |" in md
    assert "| Routes evaluated / expected | 10 / 20 |" in md


def test_malformed_records_name_the_file(tmp_path: Path):
    root = write_folder(tmp_path / "res", ten_routes()[:2])
    bad = root / "routes" / "route_99.json"
    bad.write_text('{"route_id": "route_99", ')
    with pytest.raises(ResultsError, match=r"route_99\.json: malformed JSON"):
        load_results(root)
    bad.write_text('{"route_id": "route_99"}')
    with pytest.raises(ResultsError, match=r"route_99\.json: record is not a route result"):
        write_report(root, tmp_path / "out")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ResultsError, match="no route records"):
        load_results(tmp_path / "empty")
    with pytest.raises(ResultsError, match="no such results file or folder"):
        load_results(tmp_path / "nowhere")


def _one_route_file(tmp_path: Path, edit: dict[str, object], name: str = "results.json") -> Path:
    record = ten_routes()[0].to_json()
    record.update(edit)
    path = tmp_path / name
    path.write_text(json.dumps({"routes": [ten_routes()[1].to_json(), record]}))
    return path


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        ({"driving_score": 150.0}, r"driving_score must be in \[0, 100\], got 150\.0"),
        ({"route_completion": -500.0}, r"route_completion must be in \[0, 100\], got -500\.0"),
        ({"driving_score": 34.0, "route_completion": 34.0}, r"success True with driving_score 34\.0"),
        ({"driving_score": float("inf")}, "driving_score must be a finite number, got inf"),
        ({"num_cavs": -3}, r"num_cavs must be an integer in \[1, 16\], got -3"),
        ({"driving_score": "abc"}, "driving_score must be a finite number, got 'abc'"),
        ({"driving_score": None}, "driving_score must be a finite number, got None"),
        ({"status": "Winner"}, "unknown status 'Winner'"),
        ({"route_completion": 50.0, "driving_score": 50.0, "success": False}, "not the mean / product"),
    ],
)
def test_nonsense_records_are_refused_naming_file_record_and_field(
    tmp_path: Path, edit: dict[str, object], message: str
) -> None:
    """DS 150 with success, RC -500, success at DS 34, DS inf, negative CAV counts and
    non-numbers were summarised (DS 82.95, RC -242 %) or ended in a traceback."""
    path = _one_route_file(tmp_path, edit)
    with pytest.raises(
        ResultsError, match=r"results\.json: record 1 is not a route result \(route 'route_00': "
    ) as info:
        write_report(path, tmp_path / "out")
    assert info.match(message)
    assert not (tmp_path / "out" / "summary.md").exists()


def test_deeply_nested_results_are_an_error_not_a_recursion_error(tmp_path: Path) -> None:
    path = tmp_path / "results.json"
    path.write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(ResultsError, match=r"results\.json: JSON nested too deeply"):
        load_results(path)
    from cmudrive.bench.runner import finished_route_ids, record_path

    record = record_path(tmp_path / "run", "r1")
    record.parent.mkdir(parents=True)
    record.write_text("[" * 100_000 + "]" * 100_000)
    assert finished_route_ids(tmp_path / "run", ["r1"]) == set()  # --resume runs it again


def test_text_from_records_is_written_inertly(tmp_path: Path) -> None:
    """CSV cells that a spreadsheet runs as formulas get a leading quote; markdown cells are HTML-escaped;
    a group name that looks like mathtext does not break the charts."""
    routes = ten_routes()
    routes[0].scenario_type = '=HYPERLINK("http://x")'
    routes[1].weather = "<img src=x onerror=alert(1)>|"
    routes[2].weather = "$\\frac{$"
    routes[3].town = "@SUM(A1)"
    write_report(routes, tmp_path / "out")
    with (tmp_path / "out" / "routes.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert rows[0]["scenario_type"] == '\'=HYPERLINK("http://x")' and rows[3]["town"] == "'@SUM(A1)"
    with (tmp_path / "out" / "summary.csv").open() as f:
        groups = [r["group"] for r in csv.DictReader(f)]
    assert '\'=HYPERLINK("http://x")' in groups and not any(g.startswith(("=", "@")) for g in groups)
    md = (tmp_path / "out" / "summary.md").read_text()
    assert "<img" not in md and "| &lt;img src=x onerror=alert(1)&gt;\\| | 1 |" in md
