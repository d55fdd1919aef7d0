"""Map-layer budgets: loading a committed town from the cache, and nearest-lane + Frenet on 10k points.

    python benchmarks/maps.py [TOWN ...] [--points 10000] [--repeat 5]

References measured in the same run: parsing the same network with sumolib (what the cache saves us),
and a bare scipy cKDTree nearest-neighbour query of the same points (the floor for any spatial query).
Prints one line per town and measurement, then `ratio_*` lines.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import numpy as np
import sumolib
from scipy.spatial import cKDTree

from cmudrive.maps import available_towns, load_map, resolve_map_path


def best_of(fn: Callable[[], object], repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def measure(town: str, points: int, repeat: int) -> tuple[float, float]:
    """Print one line of timings for ``town``; return (load / sumolib parse, query / bare kd-tree)."""
    path = resolve_map_path(town)
    load_map(town)  # make sure the cache is warm
    t_load = best_of(lambda: load_map(town), repeat)
    t_index = best_of(lambda: load_map(town).index, repeat)  # load + build the spatial index
    t_sumolib = best_of(lambda: sumolib.net.readNet(str(path), withInternal=True), 1)
    m = load_map(town)
    index = m.index
    rng = np.random.default_rng(0)
    lanes = rng.choice(np.flatnonzero(m.driving), points)
    s = rng.uniform(0, 1, points) * m.lane_length[lanes]
    xy = index.frenet_to_xy(lanes, s, rng.uniform(-1.5, 1.5, points))
    heading = index.heading_at(lanes, s) + rng.normal(0, 0.1, points)
    t_query = best_of(lambda: index.nearest_lane(xy, heading=heading), repeat)
    t_query_plain = best_of(lambda: index.nearest_lane(xy), repeat)
    t_frenet = best_of(lambda: index.frenet_to_xy(lanes, s), repeat)
    tree = cKDTree(index.sample_xy)
    t_kdtree = best_of(lambda: tree.query(xy, k=1), repeat)
    print(
        f"{town}: {m.num_lanes} lanes, {m.summary()['driving_km']} driving km | "
        f"cache load {t_load * 1e3:.1f} ms, load+index {t_index * 1e3:.1f} ms, "
        f"sumolib parse {t_sumolib * 1e3:.0f} ms | nearest+frenet {points} pts: "
        f"{t_query * 1e3:.1f} ms (heading-filtered), {t_query_plain * 1e3:.1f} ms (plain); "
        f"frenet->xy {t_frenet * 1e3:.1f} ms; bare kd-tree k=1 {t_kdtree * 1e3:.1f} ms"
    )
    return t_index / t_sumolib, t_query / t_kdtree


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("towns", nargs="*", default=None)
    parser.add_argument("--points", type=int, default=10_000)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    towns = args.towns or available_towns()
    load_ratios, query_ratios = [], []
    for town in towns:
        load_ratio, query_ratio = measure(town, args.points, args.repeat)
        load_ratios.append(load_ratio)
        query_ratios.append(query_ratio)
    print(f"ratio_load_vs_sumolib_parse={statistics.mean(load_ratios):.4f}")
    print(f"ratio_query_vs_bare_kdtree={statistics.mean(query_ratios):.2f}")


if __name__ == "__main__":
    main()
