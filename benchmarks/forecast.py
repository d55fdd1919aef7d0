"""Time per call of the expert's hazard forecast: 16 CAVs among 200 actors (150 vehicles, 50 pedestrians).

    python benchmarks/forecast.py [--cavs 16] [--actors 200] [--calls 2000]

Actors are scattered at random over squares of several sizes (``--sides``), heading anywhere, vehicles at
0-14 m/s with yaw rates up to 0.3 rad/s, pedestrians at 0-1.8 m/s; each CAV has a 60 m curved path. The
smaller the square, the more actors lie within 50 m of each CAV and pass the bounding-circle check. Timed:
``Forecaster.update`` + ``Forecaster.forecast`` with a new snapshot each call (as in the closed loop),
median and 90th percentile over ``--calls`` calls after a warm-up (numba compiles on the first call).

The script imports cmudrive from the checkout it lives in (not whichever copy is installed).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's cmudrive

from cmudrive.agents.expert.forecast import Forecaster
from cmudrive.sim.snapshot import ActorKind, Role, Snapshot

DT = 0.05  # [s] tick


def random_world(
    rng: np.random.Generator, cavs: int, actors: int, side: float
) -> tuple[Snapshot, np.ndarray]:
    """A snapshot of ``actors`` rows (the first ``cavs`` are CAVs, a quarter are pedestrians) spread over a
    ``side`` x ``side`` m square, and each CAV's path (cavs, 60, 2)."""
    walkers = actors // 4
    kind = np.full(actors, ActorKind.CAR, np.int8)
    kind[actors - walkers :] = ActorKind.PEDESTRIAN
    role = np.full(actors, Role.BACKGROUND, np.int8)
    role[:cavs] = Role.CAV
    ped = kind == ActorKind.PEDESTRIAN
    snap = Snapshot.from_rows(
        0,
        0.0,
        np.array([], str),
        ids=np.array([f"cav{i}" if i < cavs else f"v{i}" for i in range(actors)]),
        kind=kind,
        role=role,
        x=rng.uniform(0.0, side, actors),
        y=rng.uniform(0.0, side, actors),
        yaw=rng.uniform(-np.pi, np.pi, actors),
        speed=np.where(ped, rng.uniform(0.0, 1.8, actors), rng.uniform(0.0, 14.0, actors)),
        length=np.where(ped, 0.5, 4.5),
        width=np.where(ped, 0.5, 1.9),
    )
    s = np.arange(60.0)
    curvature = rng.uniform(-0.05, 0.05, cavs)  # [1/m]
    heading = snap.yaw[:cavs, None] + curvature[:, None] * s[None]
    paths = np.empty((cavs, 60, 2))
    paths[:, :, 0] = snap.x[:cavs, None] + np.cumsum(np.cos(heading), axis=1) - np.cos(heading[:, :1])
    paths[:, :, 1] = snap.y[:cavs, None] + np.cumsum(np.sin(heading), axis=1) - np.sin(heading[:, :1])
    return snap, paths


def advance(snap: Snapshot, rng: np.random.Generator) -> Snapshot:
    """The next tick: every actor turned a little (so that yaw rates are nonzero); positions are kept, so
    that the density of the scene (and the work per call) stays what it was."""
    yaw = snap.yaw + rng.uniform(-0.3, 0.3, snap.num_actors) * DT
    return Snapshot(**{**snap.__dict__, "step": snap.step + 1, "time": snap.time + DT, "yaw": yaw})


def bench(cavs: int, actors: int, side: float, calls: int, seed: int) -> tuple[float, float, float]:
    """Median and 90th percentile time per call [ms], and the mean number of conflicts per CAV."""
    rng = np.random.default_rng(seed)
    snap, paths = random_world(rng, cavs, actors, side)
    rows = np.arange(cavs)
    speed = snap.speed[:cavs].copy()
    target = np.full(cavs, 10.0)
    forecaster = Forecaster()
    for _ in range(20):  # warm-up (compilation or the on-disk cache)
        snap = advance(snap, rng)
        forecaster.forecast(snap, rows, paths, speed, target)
    times, conflicts = np.empty(calls), 0
    for c in range(calls):
        snap = advance(snap, rng)
        start = time.perf_counter()
        fc = forecaster.forecast(snap, rows, paths, speed, target)
        times[c] = time.perf_counter() - start
        conflicts += int(fc.conflict.sum())
    return 1e3 * float(np.median(times)), 1e3 * float(np.percentile(times, 90)), conflicts / calls / cavs


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--cavs", type=int, default=16)
    parser.add_argument("--actors", type=int, default=200)
    parser.add_argument("--calls", type=int, default=2000)
    parser.add_argument("--sides", type=float, nargs="+", default=[400.0, 200.0, 100.0, 60.0])
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    print(f"{args.cavs} CAVs, {args.actors} actors, {args.calls} calls (update + forecast)")
    for side in args.sides:
        median, p90, conflicts = bench(args.cavs, args.actors, side, args.calls, args.seed)
        print(
            f"square {side:5.0f} m: median {median:.3f} ms, p90 {p90:.3f} ms, {conflicts:.1f} conflicts/CAV"
        )


if __name__ == "__main__":
    main()
