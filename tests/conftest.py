"""Shared fixtures: a tiny hand-made network (tests/fixtures/mini) built once per session with netconvert."""

from __future__ import annotations

from pathlib import Path

import pytest

from cmudrive.maps import RoadMap, read_sumo_net
from cmudrive.maps.netconvert import run_netconvert

FIXTURES = Path(__file__).parent / "fixtures"


def build_mini(out: Path) -> Path:
    src = FIXTURES / "mini"
    args = [
        "--node-files",
        str(src / "mini.nod.xml"),
        "--edge-files",
        str(src / "mini.edg.xml"),
        "--crossings.guess",
        "--no-turnarounds.except-deadend",
        "--offset.disable-normalization",
    ]
    return run_netconvert(args, out, source="tests/fixtures/mini")


@pytest.fixture(scope="session")
def mini_net(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Path of the mini network: junction C (traffic light) at (200, 0), priority-stop T-junction N at
    (200, 200), two-lane road W-C, two-way one-lane road C-E, and a disconnected one-way island I1-I2."""
    return build_mini(tmp_path_factory.mktemp("mini") / "mini.net.xml")


@pytest.fixture(scope="session")
def mini(mini_net: Path) -> RoadMap:
    return read_sumo_net(mini_net)


@pytest.fixture(autouse=True)
def _isolated_cache(tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> None:
    """Tests never write into the user's map cache."""
    monkeypatch.setenv("CMUDRIVE_CACHE", str(tmp_path_factory.getbasetemp() / "cache"))
