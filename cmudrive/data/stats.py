"""What a dataset folder holds (``cmudrive data stats DIR``): samples per scenario type, weather, CAV count
and town, label histograms, waypoint ranges and size on disk. Every shard is first read whole with its
page checksums verified (``shards.verify_shard``: a corrupt shard is an error naming it, never counted
as good samples); the statistics then come from the small columns only."""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from cmudrive.data.shards import shard_paths, verify_shard

COUNTED = ("scenario_type", "weather", "num_cavs", "town", "speed_action", "route_action", "reason")
READ = (*COUNTED, "route_id", "speed", "communication", "partner_label", "partner", "path", "speed_waypoints")


def _points(column: pa.ChunkedArray, k: int) -> np.ndarray:
    """An Array2D column of (k, 2) per row -> (rows, k, 2) float array."""
    flat = pa.concat_arrays([c.storage if isinstance(c, pa.ExtensionArray) else c for c in column.chunks])
    values = flat.flatten().flatten().to_numpy(zero_copy_only=False)
    return values.reshape(-1, k, 2)


def dataset_stats(out: Path | str) -> dict[str, Any]:
    """Counts, histograms, waypoint ranges and bytes of the shards in ``out`` (JSON-ready)."""
    files = shard_paths(Path(out))
    if not files:
        raise FileNotFoundError(f"{out}: no shard (*.parquet)")
    for f in files:
        verify_shard(f)
    views = all("view" in pq.read_schema(f).names for f in files)  # older shards lack the column
    tables = [pq.read_table(f, columns=[*READ, *(["view"] if views else [])]) for f in files]
    table = pa.concat_tables(tables)
    n = table.num_rows
    view = table.column("view").combine_chunks().flatten().to_numpy().reshape(n, 3) if views and n else None
    counts = {c: Counter(table.column(c).to_pylist()) for c in COUNTED}
    comm = np.array([bool(s) for s in table.column("communication").to_pylist()], bool)
    path = _points(table.column("path"), 20) if n else np.zeros((0, 20, 2))
    speed_wp = _points(table.column("speed_waypoints"), 10) if n else np.zeros((0, 10, 2))
    speed = table.column("speed").to_numpy() if n else np.zeros(0)
    size = sum(f.stat().st_size for f in files)
    return {
        "shards": len(files),
        "routes": len(set(table.column("route_id").to_pylist())),
        "samples": n,
        "recovery_views": int((np.abs(view).sum(axis=1) > 0).sum()) if view is not None else 0,
        "bytes": size,
        "bytes_per_sample": size / n if n else 0.0,
        "counts": {c: dict(sorted(v.items(), key=lambda kv: -kv[1])) for c, v in counts.items()},
        "communication_share": float(comm.mean()) if n else 0.0,
        "partner_share": float((table.column("partner").to_numpy() >= 0).mean()) if n else 0.0,
        "ranges": {
            "speed [m/s]": _range(speed),
            "path end x [m]": _range(path[:, -1, 0]),
            "path end y [m]": _range(path[:, -1, 1]),
            "speed waypoint 2.5 s x [m]": _range(speed_wp[:, -1, 0]),
            "speed waypoint 2.5 s y [m]": _range(speed_wp[:, -1, 1]),
        },
    }


def _range(values: np.ndarray) -> dict[str, float]:
    if len(values) == 0:
        return {}
    q = np.percentile(values, [0, 5, 50, 95, 100])
    return {
        "min": float(q[0]),
        "p5": float(q[1]),
        "median": float(q[2]),
        "p95": float(q[3]),
        "max": float(q[4]),
    }
