"""The training rows of V2V-VLA: which rows an epoch reads and how they are read.

Whole routes are held out for validation (``val_fraction`` of the route ids, drawn with the seed), never
single samples of a route that also trains (:func:`load_split`); standing rows are thinned
(:func:`keep_rows`) and rows with a communication sentence repeated (:func:`repeat_rows`); each epoch
draws its rows as a permutation (:class:`EpochSampler`) or by situation (:class:`BucketSampler`,
``--bucket-power``). :class:`DrivingDataset` reads rows a batch at a time (one Arrow take), decodes their
stored images then and applies the camera-rotation augmentation (:mod:`cmudrive.model.augment`) and,
for a share of the rows, speed dropout and cooperative-input dropout (:func:`drop_cooperative_inputs`).
"""

from __future__ import annotations

import functools
import io
import math
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from PIL import Image
from torch.utils.data import Dataset, Sampler

from cmudrive.agents.control import expert_stops
from cmudrive.data.schema import EXPERT_DRIVER
from cmudrive.model.augment import YawAugment, rotate_sample
from cmudrive.model.row import STANDING_SPEED, TRAIN_COLUMNS, standing_seconds
from cmudrive.sensors.occupancy import OccupancyConfig, packed_to_rgb

VIEW = "view"  # where a row was seen from, in the CAV's frame (zeros: the CAV's own view)
DRIVER = "driver"  # who drove the CAV into the row's state ("expert", else closed-loop data)
OPTIONAL = (VIEW, DRIVER)  # columns older collections lack: read where every shard has them
GRID = "merged_occupancy"  # the stored grid the augmentation re-draws a rotated row's BEV from


class SplitSettings(Protocol):
    """What :func:`load_split` reads of a ``TrainConfig``."""

    @property
    def data(self) -> str: ...
    @property
    def val_fraction(self) -> float: ...
    @property
    def standing_keep(self) -> float: ...
    @property
    def communication_repeat(self) -> int: ...
    @property
    def seed(self) -> int: ...


def load_split(config: SplitSettings) -> tuple[Any, Any, list[str]]:
    """(train, validation, validation route ids): the shards of ``config.data`` split by route."""
    ds = load_rows(config.data)
    route_of = np.asarray(ds["route_id"])
    val_routes = split_routes(sorted(set(route_of.tolist())), config.val_fraction, config.seed)
    is_val = np.isin(route_of, val_routes)
    train_rows = np.flatnonzero(~is_val & keep_rows(ds, config.standing_keep, config.seed))
    is_val &= expert_rows(ds)  # validation: the expert's own views, comparable across collections
    if config.communication_repeat > 1:
        train_rows = repeat_rows(train_rows, communication_rows(ds)[train_rows], config.communication_repeat)
    return ds.select(train_rows), ds.select(np.flatnonzero(is_val)), val_routes


def load_rows(data: str, extra: Sequence[str] = ()) -> Any:
    """The training columns (and ``extra`` ones) of every row of the shards in ``data`` (a folder, or
    several separated by commas: an expert collection and closed-loop collections on the same routes),
    and the derived input ``standing`` (:func:`cmudrive.model.row.standing_seconds`: from the whole
    sequence of each CAV's rows in its folder, so before any selection). ``view`` and ``driver`` are read
    where a folder's shards have them; where another folder has them and this one not (collections
    before recovery views or closed-loop data), its rows get the CAV's own view and the expert."""
    import datasets
    import pyarrow.parquet as pq

    from cmudrive.data.shards import load_shards, shard_paths

    folders = [f for f in data.split(",") if f]
    if not folders:
        raise FileNotFoundError(f"{data!r}: no dataset folder")
    names = [[set(pq.read_schema(p).names) for p in shard_paths(Path(f))] for f in folders]
    has = [{c for c in OPTIONAL if c not in extra and n and all(c in m for m in n)} for n in names]
    wanted = set().union(*has)
    parts = []
    for folder, present in zip(folders, has, strict=True):
        ds = load_shards(folder, (*TRAIN_COLUMNS, *extra, *(c for c in OPTIONAL if c in present)))
        table = ds.data.table
        column = {name: table.column(name).to_numpy() for name in ("route_id", "cav", "time", "speed")}
        standing = standing_seconds(column["route_id"], column["cav"], column["time"], column["speed"])
        ds = ds.add_column("standing", standing)
        for name in sorted(wanted - present):  # what an older collection lacks: own view, the expert
            value: Any = [0.0, 0.0, 0.0] if name == VIEW else EXPERT_DRIVER
            feature = datasets.List(datasets.Value("float32"), length=3) if name == VIEW else None
            ds = ds.add_column(name, [value] * len(ds), feature=feature)
        parts.append(
            ds.select_columns([*TRAIN_COLUMNS, *extra, *(c for c in OPTIONAL if c in wanted), "standing"])
        )
    return parts[0] if len(parts) == 1 else datasets.concatenate_datasets(parts)


def recovery_rows(ds: Any) -> np.ndarray:
    """(N,) bool: rows seen from a recovery view (``cmudrive.data.recovery``), not from the CAV itself."""
    if VIEW not in ds.column_names:
        return np.zeros(len(ds), bool)
    view = _column(ds, VIEW).combine_chunks().flatten().to_numpy().reshape(len(ds), 3)
    return np.abs(view).sum(axis=1) > 0.0


def _column(ds: Any, name: str) -> Any:
    """The Arrow column ``name`` of the rows of ``ds``, in its order (of a selection too, where
    ``ds.data.table`` would be the whole underlying table)."""
    return ds.select_columns([name]).with_format("arrow")[:].column(name)


def closed_loop_rows(ds: Any) -> np.ndarray:
    """(N,) bool: rows of states another agent drove into, labelled by the expert beside it."""
    if DRIVER not in ds.column_names:
        return np.zeros(len(ds), bool)
    return np.asarray(_column(ds, DRIVER).to_numpy(zero_copy_only=False)) != EXPERT_DRIVER


def expert_rows(ds: Any) -> np.ndarray:
    """(N,) bool: rows the expert drove into, seen from the CAV itself (no recovery view): the rows
    validation reads, comparable across collections."""
    return ~recovery_rows(ds) & ~closed_loop_rows(ds)


STANDING_STAYS = 0.5  # [m] the last speed waypoint (2.5 s ahead) within this of the CAV


def standing_rows(ds: Any) -> np.ndarray:
    """(N,) bool: rows of a CAV that stands and stays standing for the 2.5 s its speed waypoints cover."""
    table = ds.data.table
    speed = table.column("speed").to_numpy()
    waypoints = table.column("speed_waypoints").combine_chunks().flatten().flatten().to_numpy()
    last = waypoints.reshape(len(speed), -1, 2)[:, -1]  # (N, 2) [m]
    return (speed < STANDING_SPEED) & (np.hypot(last[:, 0], last[:, 1]) < STANDING_STAYS)


def keep_rows(ds: Any, standing_keep: float, seed: int) -> np.ndarray:
    """(N,) bool: every row that moves, and a ``standing_keep`` share of the standing ones (drawn with
    ``seed``, the same subset for the whole run and its resumptions)."""
    if standing_keep >= 1.0:
        return np.ones(len(ds), bool)
    standing = standing_rows(ds)
    drawn = np.random.default_rng([seed, 7]).random(len(ds)) < standing_keep
    return ~standing | drawn


BUCKETS = ("starts", "stands", "stops", "turns", "follows", "slows", "cruises")
TURN_OFFSET = 2.5  # [m] a path whose last point (20 m ahead) is this far sideways: "turns"
# the expert's reasons for driving slower than the road allows, grouped: an actor or obstacle ahead,
# the road itself (speed limit, curve, junction cap, lights, signs)
_FOLLOW_REASONS = ("LEADING_VEHICLE", "BICYCLE", "PEDESTRIAN", "OBSTACLE", "YIELD", "FORECAST", "DETOUR_WAIT")
_ROAD_REASONS = ("ROAD", "RED_LIGHT", "YELLOW_LIGHT", "STOP_SIGN")


def sampling_buckets(ds: Any) -> np.ndarray:
    """(N,) index into :data:`BUCKETS` of every row: a standing CAV (below 0.1 m/s) that drives off
    ("starts") or stays ("stands"); a moving one that brakes ("stops": SimLingo's brake rule for the
    expert's target speed); else, driving on, one whose path turns or changes lane ("turns"), one held
    back by an actor or obstacle ("follows"), by the road, a light or a sign ("slows"), or cruising."""
    # the rows of the selection, in its order (ds.data.table would be the whole underlying table)
    table = ds.select_columns(["speed", "target_speed", "reason", "path"]).with_format("arrow")[:]
    speed = table.column("speed").to_numpy()
    stop = expert_stops(speed, table.column("target_speed").to_numpy())
    path = table.column("path").combine_chunks().flatten().flatten().to_numpy().reshape(len(speed), -1, 2)
    reason = np.asarray(table.column("reason").to_pylist(), dtype=object)
    standing = speed < STANDING_SPEED
    bucket = np.select(
        [
            standing & ~stop,
            standing,
            stop,
            np.abs(path[:, -1, 1]) > TURN_OFFSET,
            np.isin(reason, _FOLLOW_REASONS),
            np.isin(reason, _ROAD_REASONS),
        ],
        np.arange(6),
        default=6,
    )
    return bucket.astype(np.int64)


class BucketSampler(Sampler[int]):
    """Each epoch ``len(buckets)`` row indices: bucket b gets ``round(share_b * N)`` of them, share_b
    proportional to count_b ** ``power``, drawn without repetition within a bucket until it is used up
    (then its permutation starts again), all shuffled; a function of (seed, epoch), like
    :class:`EpochSampler`."""

    def __init__(self, buckets: np.ndarray, seed: int, power: float) -> None:
        self.buckets, self.seed, self.power = np.asarray(buckets, np.int64), seed, power
        self.epoch = 0
        self.members = [
            np.flatnonzero(self.buckets == b) for b in range(int(self.buckets.max(initial=-1)) + 1)
        ]
        counts = np.array([len(m) for m in self.members], np.float64)
        weight = np.where(counts > 0, counts**power, 0.0)
        quota = weight / max(weight.sum(), 1e-12) * len(self.buckets)
        self.quota = np.floor(quota).astype(np.int64)
        short = len(self.buckets) - int(self.quota.sum())  # largest remainders get the rest
        self.quota[np.argsort(-(quota - self.quota))[:short]] += 1

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __len__(self) -> int:
        return len(self.buckets)

    def __iter__(self) -> Iterator[int]:
        rng = np.random.default_rng([self.seed, self.epoch, 3])
        picks = [np.resize(rng.permutation(m), q) for m, q in zip(self.members, self.quota, strict=True) if q]
        drawn = np.concatenate(picks) if picks else np.zeros(0, np.int64)
        return iter(drawn[rng.permutation(len(drawn))].tolist())


def communication_rows(ds: Any) -> np.ndarray:
    """(N,) bool: rows labelled with a partner to talk to (``partner_label`` >= 0)."""
    return np.asarray(ds["partner_label"]) >= 0  # through the dataset: a selection's rows, in its order


def repeat_rows(rows: np.ndarray, chosen: np.ndarray, times: int) -> np.ndarray:
    """``rows`` with each of the ``chosen`` ones (bool per row) there ``times`` times, order kept (the
    epoch sampler shuffles)."""
    return np.repeat(rows, np.where(chosen, times, 1))


def split_routes(routes: Sequence[str], val_fraction: float, seed: int) -> list[str]:
    """The held-out route ids: ``ceil(val_fraction * routes)``, drawn with ``seed``; none when there is only
    one route (it must train)."""
    if val_fraction == 0.0 or len(routes) < 2:
        return []
    n = min(len(routes) - 1, math.ceil(val_fraction * len(routes)))
    pick = np.random.default_rng(seed).permutation(len(routes))[:n]
    return sorted(routes[i] for i in pick)


IMAGE_COLUMNS = ("camera", "merged_bev")  # stored encoded (JPEG / palette PNG), decoded here


def decode_image(value: Any) -> Any:
    """A stored image (``datasets.Image`` storage: ``{"bytes", "path"}``) as a PIL RGB image; anything else
    (already decoded, or None) as it is. What ``datasets`` would decode, without its per-row overhead."""
    if not isinstance(value, dict):
        return value
    data = value.get("bytes")
    image = Image.open(io.BytesIO(data) if data is not None else value["path"])
    return image.convert("RGB")


def grid_array(column: Any) -> np.ndarray:
    """(n, H, W) uint8 from an Arrow column of n (H, W) nested-list grids, without Python lists."""
    flat = column.combine_chunks() if hasattr(column, "combine_chunks") else column
    rows = flat.flatten()  # the grids' rows
    cells = rows.flatten().to_numpy(zero_copy_only=False)
    n = len(flat)
    h = len(rows) // max(n, 1)
    return np.asarray(cells, np.uint8).reshape(n, h, -1)


class DrivingDataset(Dataset):
    """Rows of an Arrow-backed ``datasets.Dataset`` as dicts, images decoded when a row is read; training
    rows are rotated (:class:`YawAugment`) and, a ``speed_dropout`` share of them, stripped of their speed
    (``None``: the prompt leaves it out), with generators seeded by (seed, epoch, index), so a row's
    augmentation does not depend on workers, order or resumption.

    Rows are read a batch at a time (``__getitems__``, which the DataLoader calls with a batch's indices):
    one Arrow ``take`` for the batch, the images decoded from their stored bytes with PIL, and the merged
    occupancy grids of the rows to rotate read as one array; ``datasets``' own row formatting (nested
    lists to Python, image decoding) cost ~2 ms per row before, the grid another 2 ms."""

    def __init__(
        self,
        table: Any,
        augment: YawAugment | None = None,
        seed: int = 0,
        speed_dropout: float = 0.0,
        cooperative_dropout: float = 0.0,
    ) -> None:
        # the merged occupancy grid is read (as an array) only for the rows the augmentation rotates
        self.grids = None
        if GRID in table.column_names:
            self.grids = table.select_columns([GRID]).with_format("arrow")
            table = table.remove_columns([GRID])
        self.table = table.with_format("arrow")
        self.augment = augment
        self.seed = seed
        self.speed_dropout = speed_dropout
        self.cooperative_dropout = cooperative_dropout
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __len__(self) -> int:
        return len(self.table)

    def __getitem__(self, index: int) -> dict[str, Any]:
        return self.__getitems__([index])[0]

    def __getitems__(self, indices: Sequence[int]) -> list[dict[str, Any]]:
        indices = [int(i) for i in indices]
        rows = self.table[indices].to_pylist()
        for row in rows:
            for key in IMAGE_COLUMNS:
                if key in row:
                    row[key] = decode_image(row[key])
        if self.augment is not None:
            yaws = [self.augment.draw(np.random.default_rng([self.seed, self.epoch, i])) for i in indices]
            turned = [k for k, dyaw in enumerate(yaws) if dyaw]
            if turned and self.grids is not None:
                grids = grid_array(self.grids[[indices[k] for k in turned]].column(GRID))
                for k, grid in zip(turned, grids, strict=True):
                    rows[k][GRID] = grid
            rows = [rotate_sample(row, dyaw) for row, dyaw in zip(rows, yaws, strict=True)]
        if self.speed_dropout:
            for row, i in zip(rows, indices, strict=True):
                if np.random.default_rng([self.seed, self.epoch, i, 1]).random() < self.speed_dropout:
                    if row.get("target_speed") is not None:  # the stop label of the true speed
                        row["stop"] = bool(
                            expert_stops(np.array([row["speed"]]), np.array([row["target_speed"]]))[0]
                        )
                    row["speed"] = None
        if self.cooperative_dropout:
            for row, i in zip(rows, indices, strict=True):
                if np.random.default_rng([self.seed, self.epoch, i, 2]).random() < self.cooperative_dropout:
                    drop_cooperative_inputs(row)
        return rows


def drop_cooperative_inputs(row: dict[str, Any]) -> None:
    """``row`` (in place) as the cooperative model would see it alone: an empty merged occupancy image, no
    other CAVs, and so no partner to name (the communication label becomes "none")."""
    if row.get("merged_bev") is not None:
        row["merged_bev"] = _empty_bev()
    row["other_cavs"] = []
    row["communication"] = ""
    row["partner_label"] = -1


@functools.cache
def _empty_bev() -> Image.Image:
    """The merged image of no occupancy (the ego box only), drawn once: read-only for its users."""
    return Image.fromarray(packed_to_rgb(np.zeros(OccupancyConfig().shape, np.uint8)))


class EpochSampler(Sampler[int]):
    """A permutation per epoch from (seed, epoch): the same on every process, reproducible on resume."""

    def __init__(self, size: int, seed: int, shuffle: bool = True) -> None:
        self.size, self.seed, self.shuffle = size, seed, shuffle
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __len__(self) -> int:
        return self.size

    def __iter__(self) -> Iterator[int]:
        if not self.shuffle:
            return iter(range(self.size))
        return iter(np.random.default_rng([self.seed, self.epoch]).permutation(self.size).tolist())
