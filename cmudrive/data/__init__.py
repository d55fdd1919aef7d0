"""The driving dataset: expert rollouts on training routes as Hugging Face ``datasets`` Parquet shards, one
per route, with waypoint, control and language labels (``docs/data.md``).

    from cmudrive.data import collect, load_shards
    import datasets
    ds = datasets.load_dataset("parquet", data_dir="data/train", split="train")
"""

from cmudrive.data.collect import BenchmarkRouteError, CollectSummary, ShardJob, check_not_benchmark, collect
from cmudrive.data.collector import SAMPLE_EVERY, RouteInfo, RowCollector
from cmudrive.data.labels import (
    PATH_POINTS,
    PATH_SPACING,
    SPEED_POINTS,
    SPEED_STEP_TICKS,
    plan_labels,
    waypoint_labels,
)
from cmudrive.data.language import Language, LanguageInputs, describe
from cmudrive.data.recovery import RecoveryViews
from cmudrive.data.schema import COLUMNS, features, pack_occupancy, unpack_occupancy
from cmudrive.data.shards import (
    ShardError,
    ShardWriter,
    load_shards,
    shard_complete,
    shard_path,
    shard_paths,
    verify_shard,
)

__all__ = [
    "COLUMNS",
    "PATH_POINTS",
    "PATH_SPACING",
    "SAMPLE_EVERY",
    "SPEED_POINTS",
    "SPEED_STEP_TICKS",
    "BenchmarkRouteError",
    "CollectSummary",
    "Language",
    "LanguageInputs",
    "RecoveryViews",
    "RouteInfo",
    "RowCollector",
    "ShardError",
    "ShardJob",
    "ShardWriter",
    "check_not_benchmark",
    "collect",
    "describe",
    "features",
    "load_shards",
    "pack_occupancy",
    "plan_labels",
    "shard_complete",
    "shard_path",
    "shard_paths",
    "unpack_occupancy",
    "verify_shard",
    "waypoint_labels",
]
