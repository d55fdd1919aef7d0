"""Loading maps: the cache, town names, and bad input that must fail clearly and leave nothing behind."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from cmudrive.maps import MapError, NetconvertError, load_map, resolve_map_path
from cmudrive.maps.cache import cache_dir
from cmudrive.maps.loader import file_sha256
from cmudrive.maps.netconvert import run_netconvert


def test_cache_round_trip_gives_identical_arrays(mini_net: Path, tmp_path: Path) -> None:
    net = tmp_path / "mini.net.xml"
    shutil.copy(mini_net, net)
    first = load_map(net)
    cached = list(cache_dir().glob("mini-*.npz"))
    assert len(cached) == 1
    second = load_map(net)
    for name, value in first.arrays().items():
        assert np.array_equal(value, second.arrays()[name]), name
    # editing the network changes its content hash, so the stale cache entry is not used
    net.write_text(net.read_text().replace('speed="11.11"', 'speed="12.00"', 1))
    third = load_map(net)
    assert third.source_sha256 != first.source_sha256
    assert len(list(cache_dir().glob("mini-*.npz"))) == 2


def test_corrupt_cache_entry_is_rebuilt(mini_net: Path, tmp_path: Path) -> None:
    net = tmp_path / "mini.net.xml"
    shutil.copy(mini_net, net)
    load_map(net)
    (entry,) = cache_dir().glob(f"mini-{file_sha256(net)[:32]}-*.npz")
    entry.write_bytes(b"not an npz")
    with pytest.warns(UserWarning, match="unreadable map cache"):
        road_map = load_map(net)
    assert road_map.num_lanes > 0


def test_failed_cache_write_leaves_no_partial_file(
    mini_net: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    net = tmp_path / "other.net.xml"
    shutil.copy(mini_net, net)

    def broken_savez(*args: object, **kwargs: object) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(np, "savez", broken_savez)
    with pytest.warns(UserWarning, match="map cache not written"):
        road_map = load_map(net)
    assert road_map.num_lanes > 0
    assert not [p for p in cache_dir().iterdir() if p.name.startswith((".other", "other"))]


def test_missing_file_and_unknown_town(tmp_path: Path) -> None:
    with pytest.raises(MapError, match=r"map file not found: .*nowhere\.net\.xml"):
        load_map(tmp_path / "nowhere.net.xml")
    with pytest.raises(MapError, match=r"unknown town 'atlantis'; available towns:"):
        resolve_map_path("atlantis")


def test_file_that_is_not_a_network(tmp_path: Path) -> None:
    bogus = tmp_path / "notes.net.xml"
    bogus.write_text("these are my notes, not a road network\n")
    with pytest.raises(MapError, match=r"notes\.net\.xml is not a SUMO network"):
        load_map(bogus)
    broken = tmp_path / "broken.net.xml"
    broken.write_text('<net version="1.20"><edge id="a" from="x" to="y"><lane id="a_0" ')
    with pytest.raises(MapError, match=r"broken\.net\.xml could not be read as a SUMO network"):
        load_map(broken)
    assert not list(cache_dir().glob("notes-*")) and not list(cache_dir().glob("broken-*"))


def test_network_without_driving_lanes(tmp_path: Path) -> None:
    (tmp_path / "p.nod.xml").write_text(
        '<nodes><node id="a" x="0" y="0"/><node id="b" x="100" y="0"/></nodes>'
    )
    (tmp_path / "p.edg.xml").write_text(
        '<edges><edge id="ab" from="a" to="b" numLanes="1" allow="pedestrian"/></edges>'
    )
    net = run_netconvert(
        ["-n", str(tmp_path / "p.nod.xml"), "-e", str(tmp_path / "p.edg.xml")],
        tmp_path / "path.net.xml",
        source="footpath",
    )
    with pytest.raises(MapError, match=r"path\.net\.xml has no driving lanes"):
        load_map(net)


def test_netconvert_failure_names_the_input_and_leaves_no_output(tmp_path: Path) -> None:
    bad = tmp_path / "bad.nod.xml"
    bad.write_text("<nodes><node id='a' x='oops' y='0'/></nodes>")
    out = tmp_path / "out" / "bad.net.xml"
    with pytest.raises(NetconvertError, match=r"netconvert failed on bad\.nod\.xml"):
        run_netconvert(["-n", str(bad)], out, source="bad.nod.xml")
    assert not out.exists()
    assert list(out.parent.iterdir()) == []
