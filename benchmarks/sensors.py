"""Sensor budgets: the 16 front cameras of a tick in one batched call, and visibility + occupancy + V2V
merge for the same 16 CAVs.

    python benchmarks/sensors.py [--town downtown] [--ticks 100] [--pictures docs/img] [--grid PNG]

Scene: a real world on a committed town, 16 CAVs on the lane-following autopilot among background
traffic (~100 vehicles, ~50 pedestrians around them), run for a warm-up, then ``--ticks`` snapshots
recorded. Timed: ``FrontCamera.render`` of all 16 CAVs per snapshot (actor meshes, rasterising,
weather pass), after one JIT warm-up call; the first call's time (numba compile, or cache load) is
printed separately. ``--pictures`` also renders one camera view per weather preset at a junction into
that folder (``camera_<Weather>.png`` and the strip ``camera_weathers.png``); ``--grid`` saves all CAVs'
cameras of one tick. Both use the town's static scenery (buildings, poles, guardrails).

Perception is timed per snapshot as an agent declaring merged occupancy gets it: visibility of every
actor and scenery object from each camera, each CAV's own occupancy, then partner selection, warp and
merge (``perception: visibility ... occupancy ... v2v ... total`` ms, median per tick; budget 5 ms).

The last line is ``ms_per_tick_16cams=<median ms per tick>``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from cmudrive.agents.autopilot import LaneFollowingAutopilot
from cmudrive.maps import LaneKind, RoadMap, StopKind, load_map, load_scenery
from cmudrive.maps.scenery import StaticScenery
from cmudrive.sensors import PerceptionFrame, SimulatedOccupancy, compute_visibility
from cmudrive.sensors.camera import CameraConfig, FrontCamera
from cmudrive.sim.background import BackgroundConfig
from cmudrive.sim.populated import populated_world
from cmudrive.sim.snapshot import ActorKind, Role, Snapshot
from cmudrive.sim.weather import WEATHERS, get_weather
from cmudrive.sim.world import WorldConfig
from cmudrive.v2v import V2VNetwork
from cmudrive.viz.demo import demo_routes

WARMUP_TICKS = 200  # [ticks] of 0.05 s before recording: traffic spreads out, CAVs get moving


def record_snapshots(road_map: RoadMap, ticks: int, cavs: int, seed: int) -> list[Snapshot]:
    """Snapshots of a world with ``cavs`` CAVs on autopilot among background traffic."""
    routes = demo_routes(road_map, cavs, np.random.default_rng(seed))
    config = BackgroundConfig(vehicles=100, pedestrians=50, radius=250.0, pedestrian_radius=150.0)
    snaps = []
    with populated_world(WorldConfig(town=road_map.name, seed=seed), road_map, routes, config) as world:
        pilot = LaneFollowingAutopilot(road_map, routes)
        snap = world.snapshot()
        for k in range(WARMUP_TICKS + ticks):
            rows, index = snap.cav_rows()
            snap = world.tick(pilot.controls(snap, rows, index))
            if k >= WARMUP_TICKS:
                snaps.append(snap)
    return snaps


def time_cameras(camera: FrontCamera, snaps: list[Snapshot], weather: str) -> tuple[float, float, int]:
    """First-call time [s] and median time per tick [ms] of rendering every CAV's camera; CAV count."""
    w = get_weather(weather)
    rows = snaps[0].cav_rows()[0]
    t0 = time.perf_counter()
    camera.render(snaps[0], rows, w)
    first = time.perf_counter() - t0
    times = []
    for snap in snaps:
        rows = snap.cav_rows()[0]
        t0 = time.perf_counter()
        camera.render(snap, rows, w)
        times.append(time.perf_counter() - t0)
    return first, float(np.median(times)) * 1e3, len(rows)


def time_perception(snaps: list[Snapshot], weather: str, scenery: StaticScenery) -> dict[str, float]:
    """Median ms per tick of visibility, own occupancy and V2V (partners, warp, merge) for all CAVs."""
    visibility_range = get_weather(weather).visibility
    occupancy, network = SimulatedOccupancy(), V2VNetwork()
    parts: dict[str, list[float]] = {"visibility": [], "occupancy": [], "v2v": []}
    for tick, snap in enumerate([snaps[0], *snaps]):  # the first round compiles (or loads) the kernels
        rows, index = snap.cav_rows()
        t0 = time.perf_counter()
        vis = compute_visibility(snap, rows, visibility_range, scenery)
        t1 = time.perf_counter()
        own = occupancy(PerceptionFrame(snap, rows, vis, scenery))
        t2 = time.perf_counter()
        network.exchange(tick, index, np.stack([snap.x[rows], snap.y[rows], snap.yaw[rows]], axis=1), own)
        t3 = time.perf_counter()
        if tick:
            for key, dt in zip(parts, (t1 - t0, t2 - t1, t3 - t2), strict=True):
                parts[key].append(dt)
    out = {k: float(np.median(v)) * 1e3 for k, v in parts.items()}
    out["total"] = float(np.median(np.sum([parts[k] for k in parts], axis=0))) * 1e3
    return out


def junction_view(road_map: RoadMap, snap: Snapshot) -> tuple[Snapshot, int]:
    """The snapshot with a pedestrian on a crossing ahead of the CAV nearest (8-25 m) before a
    traffic-light stop line, and that CAV's row."""
    rows = snap.cav_rows()[0]
    best, best_row, best_k = np.inf, int(rows[0]), -1
    lines = np.flatnonzero(road_map.stop_kind == StopKind.TRAFFIC_LIGHT)
    mid = road_map.stop_xy[lines].mean(axis=1)
    along = road_map.stop_xy[lines, 1] - road_map.stop_xy[lines, 0]  # right end to left end
    travel = np.stack([along[:, 1], -along[:, 0]], axis=1) / np.linalg.norm(along, axis=1, keepdims=True)
    for r in rows.tolist():
        d = mid - np.array([snap.x[r], snap.y[r]])
        ahead = d @ np.array([np.cos(snap.yaw[r]), np.sin(snap.yaw[r])])
        lateral = np.abs(d @ np.array([-np.sin(snap.yaw[r]), np.cos(snap.yaw[r])]))
        aligned = travel @ np.array([np.cos(snap.yaw[r]), np.sin(snap.yaw[r])]) > 0.9
        score = np.where((ahead > 8) & (ahead < 25) & (lateral < 4) & aligned, ahead, np.inf)
        if score.min() < best:
            best, best_row, best_k = float(score.min()), r, int(lines[np.argmin(score)])
    if best_k < 0:
        return snap, best_row
    junction = road_map.stop_junction[best_k]
    crossings = np.flatnonzero(
        (road_map.lane_kind == LaneKind.CROSSING) & (road_map.lane_junction == junction)
    )
    ego = np.array([snap.x[best_row], snap.y[best_row]])
    fwd = np.array([np.cos(snap.yaw[best_row]), np.sin(snap.yaw[best_row])])
    hits = []  # (distance ahead, point, heading) where the CAV's forward line meets a crossing
    for c in crossings.tolist():
        a, b = road_map.polyline(c)[[0, -1]]
        mat = np.array([fwd, a - b]).T
        if abs(np.linalg.det(mat)) < 1e-6:
            continue
        t, s = np.linalg.solve(mat, a - ego)
        if t > best and 0.0 <= s <= 1.0:
            hits.append(
                (t, ego + (t - 0.0) * fwd + 1.5 * np.array([fwd[1], -fwd[0]]), np.arctan2(*(b - a)[::-1]))
            )
    if not hits:
        return snap, best_row
    _, xy, heading = min(hits, key=lambda h: h[0])
    return _with_pedestrian(snap, xy, float(heading)), best_row


def _with_pedestrian(snap: Snapshot, xy: np.ndarray, yaw: float) -> Snapshot:
    extra = {
        "ids": "ped_demo",
        "kind": ActorKind.PEDESTRIAN,
        "role": Role.SCENARIO,
        "x": xy[0],
        "y": xy[1],
        "yaw": yaw,
        "speed": 1.2,
        "accel": 0.0,
        "length": 0.5,
        "width": 0.6,
        "lane": -1,
        "signals": 0,
        "valid": True,
    }
    cols = {k: np.append(getattr(snap, k), np.asarray(v, getattr(snap, k).dtype)) for k, v in extra.items()}
    return Snapshot(step=snap.step, time=snap.time, tls_state=snap.tls_state, **cols)


def save_pictures(camera: FrontCamera, snap: Snapshot, out: Path, scale: int = 3) -> list[Path]:
    """One view per weather preset at a junction, and a vertical strip of all of them."""
    from PIL import Image

    out.mkdir(parents=True, exist_ok=True)
    view, row = junction_view(camera.road_map, snap)
    images = []
    paths = []
    for name, weather in WEATHERS.items():
        img = Image.fromarray(camera.render(view, np.array([row]), weather)[0])
        img = img.resize((img.width * scale, img.height * scale), Image.Resampling.NEAREST)
        paths.append(out / f"camera_{name}.png")
        img.save(paths[-1])
        images.append(img)
    strip = Image.new("RGB", (images[0].width, sum(i.height for i in images)))
    for k, img in enumerate(images):
        strip.paste(img, (0, k * images[0].height))
    paths.append(out / "camera_weathers.png")
    strip.save(paths[-1])
    return paths


def save_grid(camera: FrontCamera, snap: Snapshot, path: Path, scale: int = 2) -> Path:
    """Every CAV's camera of one tick (ClearNoon), four to a row."""
    from PIL import Image

    images = camera.render(snap, snap.cav_rows()[0], get_weather("ClearNoon"))
    n, h, w, _ = images.shape
    cols = min(n, 4)
    grid = np.zeros((-(-n // cols) * h, cols * w, 3), np.uint8)
    for k, img in enumerate(images):
        grid[(k // cols) * h : (k // cols + 1) * h, (k % cols) * w : (k % cols + 1) * w] = img
    out = Image.fromarray(grid)
    path.parent.mkdir(parents=True, exist_ok=True)
    out.resize((out.width * scale, out.height * scale), Image.Resampling.NEAREST).save(path)
    return path


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--town", default="downtown")
    parser.add_argument("--ticks", type=int, default=100)
    parser.add_argument("--cavs", type=int, default=16)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--weather", default="ClearNoon")
    parser.add_argument("--pictures", type=Path, default=None, help="folder for the weather pictures")
    parser.add_argument("--grid", type=Path, default=None, help="PNG of all CAVs' cameras of one tick")
    args = parser.parse_args()
    road_map = load_map(args.town)
    t0 = time.perf_counter()
    snaps = record_snapshots(road_map, args.ticks, args.cavs, args.seed)
    print(
        f"town {args.town}: {len(snaps)} snapshots, {snaps[-1].num_actors} actors, "
        f"{time.perf_counter() - t0:.1f} s to simulate"
    )
    t0 = time.perf_counter()
    scenery = load_scenery(road_map)
    camera = FrontCamera(CameraConfig(), road_map, scenery)
    print(
        f"camera: {camera.num_static_triangles} static triangles ({len(scenery)} scenery objects), "
        f"built in {time.perf_counter() - t0:.2f} s"
    )
    if args.pictures is not None:
        for p in save_pictures(camera, snaps[0], args.pictures):
            print(f"wrote {p}")
    if args.grid is not None:
        print(f"wrote {save_grid(camera, snaps[0], args.grid)}")
    perception = time_perception(snaps, args.weather, scenery)
    print("perception, median ms/tick: " + ", ".join(f"{k} {v:.2f}" for k, v in perception.items()))
    first, ms, n = time_cameras(camera, snaps, args.weather)
    c = camera.config
    print(f"first call (JIT compile or cache load): {first:.2f} s")
    print(f"{n} cameras {c.width}x{c.height}, {args.weather}: median {ms:.2f} ms/tick, {len(snaps)} ticks")
    print(f"ms_per_tick_16cams={ms:.2f}")


if __name__ == "__main__":
    main()
