"""Long runs with dense traffic: does SUMO's traffic lock up with teleports off?

    python benchmarks/gridlock.py [--minutes 30] [--towns downtown Town03 ...] [--out gridlock.md]

Per town: 4 CAVs on the lane-following autopilot, each on one long route through random far points (so
it drives the whole run), and background activity holding ~100 vehicles and ~40 pedestrians within
200 m of them, for ``--minutes`` of simulated time. Every 0.5 s each background vehicle that stands
(< 0.1 m/s) adds 0.5 s to its current standstill, and to its standstill *away from the CAVs* when it is
at least 60 m from every CAV (a second clock, reset when it moves or comes near a CAV). Reported per
town: vehicles seen, the share whose longest standstill exceeded 120 s (anywhere, and away from the
CAVs: SUMO's own jams, which the background activity clears), the longest standstill, how many the
background activity removed as stuck (standing > 60 s at least 60 m from every CAV), and the CAVs'
longest standstill (a CAV that stands makes the traffic behind it stand: the autopilot is no expert).
Standstills at red lights are counted too (a full cycle is 90 s). Wall time is printed so the run can be
sized; the table goes to ``--out`` as markdown.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from rich.progress import track

from cmudrive.agents.autopilot import LaneFollowingAutopilot
from cmudrive.maps import LanePos, RoadMap, Route, RouteError, RoutePlanner, available_towns, load_map
from cmudrive.sim.background import BackgroundConfig
from cmudrive.sim.populated import background_stats, populated_world
from cmudrive.sim.snapshot import ActorKind, Role
from cmudrive.sim.world import WorldConfig

SAMPLE = 10  # [ticks] standstills are sampled every 0.5 s
AWAY = 60.0  # [m] from every CAV: the background activity's out-of-sight distance
STAND_SPEED = 0.1  # [m/s]
LONG_STAND = 120.0  # [s]
CRUISE = 12.0  # [m/s] route length needed per second of the run, with margin


def long_route(road_map: RoadMap, length: float, rng: np.random.Generator) -> Route:
    """One route through random driving lanes, at least ``length`` metres long."""
    planner = RoutePlanner(road_map)
    lanes = np.flatnonzero(road_map.driving & ~road_map.lane_internal & (road_map.lane_length > 20.0))
    stops = [LanePos(int(lane), 5.0) for lane in rng.choice(lanes, 1)]
    legs: list[float] = []
    failures = 0
    while sum(legs) < length:
        nxt = LanePos(int(rng.choice(lanes)), 10.0)
        try:
            legs.append(planner.plan_through([stops[-1], nxt]).length)
        except RouteError:
            failures += 1
            if failures % 20 == 0:  # a stop no route leaves (a dead end): step back from it
                if len(stops) > 1:
                    stops.pop()
                    legs.pop()
                else:
                    stops = [LanePos(int(rng.choice(lanes)), 5.0)]
            continue
        stops.append(nxt)
    return planner.plan_through(stops)


def run_town(town: str, minutes: float, seed: int) -> dict[str, float]:
    road_map = load_map(town)
    rng = np.random.default_rng(seed)
    ticks = int(minutes * 60 / 0.05)
    routes = [long_route(road_map, CRUISE * minutes * 60, rng) for _ in range(4)]
    config = BackgroundConfig(vehicles=100, pedestrians=40, radius=200.0)
    standing: dict[str, float] = {}
    longest: dict[str, float] = {}
    standing_away: dict[str, float] = {}
    longest_away: dict[str, float] = {}
    cav_longest = np.zeros(4)
    cav_standing = np.zeros(4)
    started = time.perf_counter()
    with populated_world(WorldConfig(town=town, seed=seed), road_map, routes, config) as world:
        pilot = LaneFollowingAutopilot(road_map, routes)
        snap = world.snapshot()
        for tick in track(range(ticks), description=town, transient=True):
            rows, index = snap.cav_rows()
            snap = world.tick(pilot.controls(snap, rows, index))
            if tick % SAMPLE:
                continue
            bg = (snap.role == Role.BACKGROUND) & (snap.kind != ActorKind.PEDESTRIAN) & snap.valid
            rows, index = snap.cav_rows()
            gap = np.hypot(snap.x[bg, None] - snap.x[None, rows], snap.y[bg, None] - snap.y[None, rows])
            away = gap.min(axis=1, initial=np.inf) >= AWAY
            step = SAMPLE * 0.05
            for actor_id, speed, far in zip(
                snap.ids[bg].tolist(), snap.speed[bg].tolist(), away.tolist(), strict=True
            ):
                still = abs(speed) < STAND_SPEED
                now = standing.get(actor_id, 0.0) + step if still else 0.0
                standing[actor_id] = now
                longest[actor_id] = max(longest.get(actor_id, 0.0), now)
                now_away = standing_away.get(actor_id, 0.0) + step if still and far else 0.0
                standing_away[actor_id] = now_away
                longest_away[actor_id] = max(longest_away.get(actor_id, 0.0), now_away)
            still = np.abs(snap.speed[rows]) < STAND_SPEED
            cav_standing[index] = np.where(still, cav_standing[index] + SAMPLE * 0.05, 0.0)
            cav_longest = np.maximum(cav_longest, cav_standing)
        stats = background_stats(world)
    values = np.array(list(longest.values()) or [0.0])
    values_away = np.array(list(longest_away.values()) or [0.0])
    return {
        "vehicles": float(len(longest)),
        "share_long": 100.0 * float(np.mean(values > LONG_STAND)),
        "share_long_away": 100.0 * float(np.mean(values_away > LONG_STAND)),
        "longest": float(values.max()),
        "removed_stuck": float(stats.get("removed_stuck", 0)),
        "cav_longest": float(cav_longest.max()),
        "wall": time.perf_counter() - started,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=30.0)
    parser.add_argument("--towns", nargs="*", default=available_towns())
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    header = (
        f"| town | vehicles seen | standing > {LONG_STAND:.0f} s | ... of it away from CAVs | "
        "longest standstill [s] | removed as stuck | CAVs' longest standstill [s] | wall [s] |\n"
        "|---|---|---|---|---|---|---|---|"
    )
    lines = [header]
    print(header, flush=True)
    for town in args.towns:
        r = run_town(town, args.minutes, args.seed)
        line = (
            f"| {town} | {r['vehicles']:.0f} | {r['share_long']:.1f} % | {r['share_long_away']:.1f} % | "
            f"{r['longest']:.0f} | "
            f"{r['removed_stuck']:.0f} | {r['cav_longest']:.0f} | {r['wall']:.0f} |"
        )
        lines.append(line)
        print(line, flush=True)
        if args.out is not None:
            args.out.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
