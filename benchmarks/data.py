"""Dataset collection throughput: the expert on the first training routes, 2 workers, shards to a temp dir.

    python benchmarks/data.py [--routes 10] [--tick-cap 600] [--workers 2] [--keep DIR]

Collects the first ``--routes`` routes of the committed ``training`` set (the first 10 have 6.6 CAVs on
average, the whole set 6.56), each cut at ``--tick-cap`` ticks, with the local executor (a fresh worker
process per route, as ``cmudrive data collect`` runs), and reports samples written per second of wall
time from the first worker's start to the last shard's rename: route set-up (map, SUMO, scenery, camera
meshes) and writing are inside it. Also prints bytes per sample on disk. The last line is
``samples_per_s=<value>``.

The machine is often shared: the script also prints the CPU seconds the workers used (their user + system
time, from ``getrusage(RUSAGE_CHILDREN)``) and what that gives per CPU second, times the worker count (the
throughput of the same work on idle cores), and the load average before and after.

The script imports cmudrive from the checkout it lives in (not whichever copy is installed).
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's cmudrive

import pyarrow.parquet as pq

from cmudrive.bench.evaluator import EvalConfig
from cmudrive.bench.records import RouteResult
from cmudrive.bench.routes import read_routes
from cmudrive.bench.runner import LocalExecutor
from cmudrive.data import collect, shard_paths

TRAINING = Path(__file__).resolve().parents[1] / "cmudrive" / "assets" / "routes" / "training.xml"


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--routes", type=int, default=10, help="the first N training routes")
    parser.add_argument("--tick-cap", type=int, default=600, help="ticks per route at most (20 per second)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--keep", type=Path, default=None, help="collect here and keep the shards")
    args = parser.parse_args()

    specs = read_routes(TRAINING)[: args.routes]
    out = args.keep or Path(tempfile.mkdtemp(prefix="cmudrive_data_bench_"))
    cavs = sum(len(s.cavs) for s in specs)
    print(
        f"{len(specs)} routes ({cavs} CAVs, {cavs / len(specs):.2f} per route), tick cap {args.tick_cap}, "
        f"{args.workers} workers -> {out}"
    )

    def on_result(result: RouteResult, written: bool) -> None:
        state = "shard" if written else f"NO SHARD ({result.status})"
        print(
            f"  {result.route_id}: {result.num_cavs} CAVs, {result.ticks} ticks, "
            f"{result.wall_time:.1f} s, {state}"
        )

    load0 = os.getloadavg()
    cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    try:
        summary = collect(
            specs,
            out,
            LocalExecutor(args.workers),
            EvalConfig(tick_cap=args.tick_cap),
            resume=args.keep is not None,
            on_result=on_result,
        )
        wall = time.perf_counter() - t0
        cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (cpu1.ru_utime - cpu0.ru_utime) + (cpu1.ru_stime - cpu0.ru_stime)
        files = shard_paths(out)
        samples = sum(pq.read_metadata(f).num_rows for f in files)
        size = sum(f.stat().st_size for f in files)
    finally:
        if args.keep is None:
            shutil.rmtree(out, ignore_errors=True)
    if summary.failed:
        print(f"failed routes: {summary.failed}")
    print(
        f"{samples} samples in {wall:.1f} s; {size / 2**20:.1f} MiB, "
        f"{size / max(samples, 1):.0f} bytes/sample"
    )
    print(
        f"workers' CPU time {cpu:.1f} s: {samples / max(cpu, 1e-9):.1f} samples per CPU second, "
        f"x {args.workers} workers = {args.workers * samples / max(cpu, 1e-9):.1f} samples/s on idle cores; "
        f"load average {load0[0]:.1f} before, {os.getloadavg()[0]:.1f} after (1 min)"
    )
    print(f"samples_per_s={samples / wall:.1f}")


if __name__ == "__main__":
    main()
