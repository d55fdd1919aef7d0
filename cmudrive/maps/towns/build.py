"""Build a town: layout spec -> road graph -> plain XML -> netconvert (twice, see ``plain``) -> net.xml.

netconvert stamps the build time and the (temporary) input paths into the comment at the top of the
network; we replace that comment with a fixed one naming the town, the seed and the netconvert version,
so the same seed and netconvert version give a byte-identical file.
"""

from __future__ import annotations

import re
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from cmudrive.maps.cache import assets_dir as assets_dir  # re-exported by cmudrive.maps.towns
from cmudrive.maps.errors import MapError
from cmudrive.maps.netconvert import run_netconvert, write_with_fixed_header
from cmudrive.maps.towns.catalog import TOWNS, TownSpec
from cmudrive.maps.towns.plain import read_connections, write_plain

# netconvert options shared by all towns (inputs and output are added per build).
NETCONVERT_OPTIONS: tuple[str, ...] = (
    "--xml-validation", "never",
    "--no-warnings",
    "--output.street-names",
    "--tls.default-type", "static",
    "--crossings.guess",  # at junctions of roads with sidewalks
    "--walkingareas",  # join sidewalks around every corner, crossings or not
    "--no-turnarounds.except-deadend",
    "--junctions.corner-detail", "5",
    "--junctions.internal-link-detail", "10",  # points per turning lane inside a junction
    "--junctions.limit-turn-speed", "5.5",  # [m/s^2] lateral acceleration on turns
)  # fmt: skip


def town_spec(name: str) -> TownSpec:
    """The spec of a town by name; MapError naming the valid towns otherwise."""
    try:
        return TOWNS[name]
    except KeyError:
        raise MapError(f"unknown town {name!r}; valid towns: {', '.join(TOWNS)}") from None


def netconvert_version(net_file: Path) -> str | None:
    """The ``Eclipse SUMO netconvert <version>`` string recorded in a network's header, if any."""
    with open(net_file, encoding="utf-8") as fh:
        head = fh.read(4096)
    m = re.search(r"(Eclipse SUMO netconvert \S+)", head)
    return m.group(1) if m else None


def build_town(name: str, out_dir: Path, seed: int | None = None) -> Path:
    """Generate town ``name`` with ``seed`` (default: the town's own) into ``out_dir/<name>.net.xml``."""
    spec = town_spec(name)
    seed = spec.seed if seed is None else int(seed)
    graph = spec.layout.build(np.random.default_rng(seed))
    graph.check(name)
    output = Path(out_dir) / f"{name}.net.xml"
    source = f"town {name!r}"
    with tempfile.TemporaryDirectory(prefix=f"cmudrive-town-{name}-") as tmp:
        # pass 1 with parking lanes closed: netconvert's lane-to-lane connections, none on parking lanes
        probe = write_plain(graph, Path(tmp) / "probe", name, close_parking=True)
        probe_net = Path(tmp) / "probe.net.xml"
        run_netconvert([*probe.netconvert_args(), *NETCONVERT_OPTIONS], probe_net, source=source)
        # pass 2: the same connections, given explicitly, with parking lanes open to their class
        final = write_plain(replace(graph, links=read_connections(probe_net)), Path(tmp) / "final", name)
        built = run_netconvert(
            [*final.netconvert_args(), *NETCONVERT_OPTIONS], Path(tmp) / "final.net.xml", source=source
        )
        write_with_fixed_header(
            built,
            output,
            lambda tool: (
                f"cmudrive procedural town {spec.name!r}, seed {seed}: {spec.description}\n"
                f"     built from plain XML by {tool} with cmudrive.maps.towns.build.NETCONVERT_OPTIONS\n"
                f"     rebuild: python -m cmudrive.maps.towns {spec.name}"
            ),
            source,
        )
    return output
