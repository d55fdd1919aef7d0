"""Route sets by name and route subsets (``cmudrive.bench.route_sets``), as a leaderboard user names them."""

from __future__ import annotations

from pathlib import Path

import pytest

from cmudrive.bench.route_sets import RouteSelectionError, resolve_routes, select_subset
from cmudrive.bench.routes import read_routes, route_ids, write_routes

SMOKE = Path(__file__).resolve().parents[1] / "cmudrive" / "assets" / "routes" / "smoke.xml"
IDS = ["Accident_0", "Accident_1", "3", "HighwayCutIn_2", "ParkedObstacle_0", "Construction_4"]


def test_subset_takes_ids_indices_and_inclusive_ranges_in_file_order() -> None:
    assert select_subset(IDS, "HighwayCutIn_2,Accident_0") == ["Accident_0", "HighwayCutIn_2"]
    assert select_subset(IDS, "0-1") == ["Accident_0", "Accident_1"]
    assert select_subset(IDS, "5, 1,1-2") == ["Accident_1", "3", "Construction_4"]
    assert select_subset(IDS, "4-4") == ["ParkedObstacle_0"]


def test_an_exact_id_wins_over_an_index() -> None:
    assert select_subset(IDS, "3") == ["3"]  # the route named "3", not the fourth route
    assert select_subset(IDS, "2") == ["3"]  # index 2 is that same route


def test_unknown_ids_and_indices_past_the_end_are_named() -> None:
    with pytest.raises(RouteSelectionError, match=r"no route 'Acident_0'.*did you mean 'Accident_0'"):
        select_subset(IDS, "Acident_0")
    with pytest.raises(RouteSelectionError, match=r"index 9 is past the end of f.xml, which holds 6 routes"):
        select_subset(IDS, "2-9", "f.xml")
    with pytest.raises(RouteSelectionError, match="runs backwards"):
        select_subset(IDS, "4-2")
    with pytest.raises(RouteSelectionError, match="no route id, index or range"):
        select_subset(IDS, " , ")


def test_route_ids_keep_file_order_with_invalid_routes(tmp_path: Path) -> None:
    specs = read_routes(SMOKE)  # smoke_00 becomes unreadable: no weather "Sunny"
    write_routes(specs[:2], tmp_path / "r.xml")
    text = (tmp_path / "r.xml").read_text().replace('weather="ClearNoon"', 'weather="Sunny"', 1)
    (tmp_path / "r.xml").write_text(text)
    good, bad = read_routes(tmp_path / "r.xml", strict=False)
    assert [b[0] for b in bad] == ["smoke_00"] and [g.id for g in good] == ["smoke_01"]
    assert route_ids(tmp_path / "r.xml") == ["smoke_00", "smoke_01"]


def test_a_set_name_wins_over_a_folder_of_that_name(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "smoke").mkdir()
    assert resolve_routes("smoke") == SMOKE
    with pytest.raises(RouteSelectionError, match=r"\./smoke: is a folder, not a route file"):
        resolve_routes("./smoke")
    with pytest.raises(RouteSelectionError, match=r"'smoek'.*did you mean 'smoke'"):
        resolve_routes("smoek")
    (tmp_path / "mine").write_text("<routes/>")  # a bare name that is a file stays a path
    assert resolve_routes("mine") == Path("mine")
