"""World-tick budget: our full tick vs bare libsumo stepping the same network with the same traffic.

    python benchmarks/engine.py [--town downtown] [--ticks 2000] [--quick]
    python benchmarks/engine.py --grid [--ticks 300]      # ticks/s against CAV count and density

1. Our world: 16 CAVs on the lane-following autopilot, background activity holding ~100 vehicles and
   ~50 pedestrians around them. Timed: ``World.tick`` only (CAV dynamics, push into SUMO, SUMO step,
   background activity, snapshot, collisions); the autopilot's controls are computed outside the timer.
2. Bare SUMO: a fresh libsumo simulation of the same network, seed and options, holding the same
   vehicles (the CAVs as ordinary SUMO cars on their routes) and pedestrians as the world had when timing
   began, stepped with ``simulationStep`` only.

``--replay`` adds a third run: our world again, fed the controls recorded in the first (the same
trajectory, bit for bit) with no agent between ticks. The autopilot's work between ticks (~0.4 ms,
~1.7 MB of temporaries) slows SUMO's next step (CPU caches); this run shows our tick without it.

The last line is ``ratio_vs_sumo=<our ticks per second / bare SUMO steps per second>`` (goal >= 0.5).
Peak memory is the process's maximum resident set size. The per-phase line splits our tick: "cavs"
(validate, integrate, push), "sumo_step" (SUMO's step inside our loop), "background", "snapshot",
"collisions". Note that SUMO's own step is ~1 ms slower inside any Python loop that does real work
between steps than in a bare stepping loop (CPU caches), which this ratio charges to us.

``--grid``: our ticks per second (same tick, same timer) for 2, 4, 8 and 16 CAVs against 0, 50, 100 and
200 background vehicles (with half as many background pedestrians), one world per cell, all in one run
(median of ``--repeats`` rounds); printed as a markdown table for docs/simulator.md.

The script imports cmudrive from the checkout it lives in (not whichever copy is installed).
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's cmudrive

from cmudrive.agents.autopilot import LaneFollowingAutopilot
from cmudrive.maps import load_map, resolve_map_path
from cmudrive.sim.background import BackgroundConfig
from cmudrive.sim.dynamics import Controls
from cmudrive.sim.populated import populated_world
from cmudrive.sim.sumo import start_sumo
from cmudrive.sim.world import WorldConfig
from cmudrive.viz.demo import demo_routes

WARMUP_TICKS = 40
GRID_CAVS = (2, 4, 8, 16)
GRID_VEHICLES = (0, 50, 100, 200)  # background vehicles; background pedestrians: half as many


def traffic_of_world() -> tuple[list[tuple[str, str, tuple[str, ...], str, float]], list[tuple]]:
    """Every SUMO vehicle (id, type, remaining route, lane index, pos) and person (id, edges, pos, arrival)
    now; the bare run inserts vehicles at the maximum safe speed there. An actor inside a junction
    (SUMO cannot insert there) starts at the beginning of its next edge instead, so that the bare run
    holds as many actors as ours."""
    import libsumo

    vehicles = []
    for vid in libsumo.vehicle.getIDList():
        route = libsumo.vehicle.getRoute(vid)[libsumo.vehicle.getRouteIndex(vid) :]
        lane = libsumo.vehicle.getLaneID(vid)
        if lane.startswith(":"):  # on the junction after route[0]
            if len(route) > 1:
                vehicles.append((vid, libsumo.vehicle.getTypeID(vid), tuple(route[1:]), "best", 0.0))
            continue
        vehicles.append(
            (
                vid,
                libsumo.vehicle.getTypeID(vid),
                tuple(route),
                lane.rsplit("_", 1)[1],
                libsumo.vehicle.getLanePosition(vid),
            )
        )
    persons = []
    for pid in libsumo.person.getIDList():
        edge = libsumo.person.getRoadID(pid)
        pos = libsumo.person.getLanePosition(pid)
        if edge.startswith(":"):  # on a crossing or walking area: from the start of the next edge
            edge, pos = libsumo.person.getNextEdge(pid), 0.0
        stage = libsumo.person.getStage(pid)
        edges = [e for e in stage.edges if not e.startswith(":")]
        start = edges.index(edge) if edge in edges else 0
        persons.append((pid, tuple(edges[start:]), pos, stage.arrivalPos))
    return vehicles, persons


def run_world(
    town: str,
    ticks: int,
    cavs: int,
    seed: int,
    vehicles: int = 100,
    pedestrians: int = 50,
    quiet: bool = False,
    controls_log: list[Controls] | None = None,
    replay: bool = False,
) -> tuple[float, int, int, tuple]:
    """Time ``ticks`` world ticks after the warm-up. The autopilot's controls are appended to
    ``controls_log``; with ``replay``, the controls come from ``controls_log`` instead (same seed, same
    controls: the same trajectory, bit for bit) and no agent runs between ticks."""
    road_map = load_map(town)
    routes = demo_routes(road_map, cavs, np.random.default_rng(seed))
    config = BackgroundConfig(
        vehicles=vehicles, pedestrians=pedestrians, radius=250.0, pedestrian_radius=150.0
    )
    with populated_world(WorldConfig(town=town, seed=seed), road_map, routes, config) as world:
        pilot = LaneFollowingAutopilot(road_map, routes)
        snap = world.snapshot()
        elapsed = 0.0
        for k in range(WARMUP_TICKS + ticks):
            if k == WARMUP_TICKS:
                world.timing = dict.fromkeys(world.timing, 0.0)
            if replay and controls_log is not None:
                controls = controls_log[k]
            else:
                rows, index = snap.cav_rows()
                controls = pilot.controls(snap, rows, index)
                if controls_log is not None:
                    controls_log.append(controls)
            if k == WARMUP_TICKS:
                traffic = traffic_of_world() if not (quiet or replay) else ([], [])
                actors_at_start = len(snap.ids)
            t0 = time.perf_counter()
            snap = world.tick(controls)
            if k >= WARMUP_TICKS:
                elapsed += time.perf_counter() - t0
        phases = ", ".join(f"{k} {v / ticks * 1e3:.2f}" for k, v in world.timing.items() if k != "ticks")
        if not quiet:
            print(f"ours{' replayed' if replay else ''} per phase [ms/tick]: {phases}")
        return elapsed, actors_at_start, len(snap.ids), traffic


def run_bare(town: str, ticks: int, seed: int, traffic: tuple) -> tuple[float, int, int]:
    import libsumo

    vehicles, persons = traffic
    session = start_sumo(resolve_map_path(town), seed)
    try:
        for vid, vtype, route, lane, pos in vehicles:
            libsumo.route.add(f"r:{vid}", list(route))
            libsumo.vehicle.add(
                vid,
                f"r:{vid}",
                typeID=vtype,
                depart="now",
                departLane=lane,
                departPos=str(pos),
                departSpeed="max",
            )
        for pid, edges, pos, arrival in persons:
            libsumo.person.add(pid, edges[0], pos, depart=-3, typeID="pedestrian")
            libsumo.person.appendWalkingStage(pid, list(edges), arrival)
        libsumo.simulationStep()
        at_start = libsumo.vehicle.getIDCount() + libsumo.person.getIDCount()
        t0 = time.perf_counter()
        for _ in range(ticks):
            libsumo.simulationStep()
        elapsed = time.perf_counter() - t0
        at_end = libsumo.vehicle.getIDCount() + libsumo.person.getIDCount()
    finally:
        session.close()
    return elapsed, at_start, at_end


def run_grid(town: str, ticks: int, seed: int, repeats: int) -> None:
    """Our ticks/s for every CAV count x background density, as a markdown table: the median of
    ``repeats`` rounds over all cells (rounds, not cells, repeated, so that a busy spell on a shared
    machine spreads over the table instead of landing on one cell)."""
    rates: dict[tuple[int, int], list[float]] = {}
    actors: dict[tuple[int, int], int] = {}
    for _ in range(repeats):
        for cavs in GRID_CAVS:
            for vehicles in GRID_VEHICLES:
                elapsed, start, end, _ = run_world(
                    town, ticks, cavs, seed, vehicles, vehicles // 2, quiet=True
                )
                rates.setdefault((cavs, vehicles), []).append(ticks / elapsed)
                actors[cavs, vehicles] = (start + end) // 2
    for (cavs, vehicles), values in rates.items():
        spread = ", ".join(f"{v:.0f}" for v in sorted(values))
        print(f"  {cavs} CAVs, {vehicles} vehicles: {spread} ticks/s", file=sys.stderr)
    print(
        f"town {town}, {ticks} ticks of 0.05 s per cell after {WARMUP_TICKS} warm-up ticks, seed {seed}, "
        f"median of {repeats} rounds"
    )
    print(
        "ticks/s (actors in the world, all kinds) by CAV count and background vehicles (+ half as many "
        "pedestrians):\n"
    )
    print("| CAVs | " + " | ".join(f"{v} vehicles" for v in GRID_VEHICLES) + " |")
    print("|---:|" + "---:|" * len(GRID_VEHICLES))
    for cavs in GRID_CAVS:
        cells = [f"{np.median(rates[cavs, v]):.0f} ({actors[cavs, v]})" for v in GRID_VEHICLES]
        print(f"| {cavs} | " + " | ".join(cells) + " |")


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--town", default="downtown")
    parser.add_argument("--ticks", type=int, default=2000)
    parser.add_argument("--cavs", type=int, default=16)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--quick", action="store_true", help="400 ticks (well under a minute)")
    parser.add_argument("--grid", action="store_true", help="ticks/s table: CAV count x background density")
    parser.add_argument(
        "--replay",
        action="store_true",
        help="also time our tick replaying the recorded controls, with no agent work between ticks",
    )
    parser.add_argument("--repeats", type=int, default=3, help="--grid: rounds over all cells (median)")
    args = parser.parse_args()
    if args.grid:
        ticks = args.ticks if args.ticks != parser.get_default("ticks") else 300
        run_grid(args.town, ticks, args.seed, args.repeats)
        return
    ticks = 400 if args.quick else args.ticks
    log: list[Controls] = []
    ours, ours_start, ours_end, traffic = run_world(args.town, ticks, args.cavs, args.seed, controls_log=log)
    replayed = 0.0
    if args.replay:
        replayed = run_world(args.town, ticks, args.cavs, args.seed, controls_log=log, replay=True)[0]
    bare, bare_start, bare_end = run_bare(args.town, ticks, args.seed, traffic)
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    ours_rate, bare_rate = ticks / ours, ticks / bare
    print(f"town {args.town}, {ticks} ticks of 0.05 s, {args.cavs} CAVs")
    print(
        f"ours: {ours_start} -> {ours_end} actors, {ours / ticks * 1e3:.2f} ms/tick, {ours_rate:.0f} ticks/s "
        f"({ours_rate * 0.05:.1f}x real time)"
    )
    print(
        f"bare SUMO: {bare_start} -> {bare_end} actors, {bare / ticks * 1e3:.2f} ms/step, "
        f"{bare_rate:.0f} steps/s"
    )
    print(f"peak memory {peak_mb:.0f} MB")
    if args.replay:
        print(
            f"ours replaying the same controls without the autopilot: {replayed / ticks * 1e3:.2f} ms/tick, "
            f"ratio {bare / replayed:.3f}"
        )
    print(f"ratio_vs_sumo={ours_rate / bare_rate:.3f}")


if __name__ == "__main__":
    main()
