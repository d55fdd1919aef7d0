"""Dataset shards on disk: one Parquet file per route, written through a temporary name and renamed when
complete, so that a file named ``<stem>.parquet`` is always a whole route and ``--resume`` can trust it.

Layout of a dataset folder::

    DIR/<stem>.parquet        the samples of one route (``stem``: ``records.record_stem(route_id)``)
    DIR/.routes/<stem>.json   that route's evaluation record (status, scores, error); crashed routes too
    DIR/.<stem>.parquet.tmp   a shard being written (removed or renamed when its route ends)

``datasets.load_dataset("parquet", data_dir=DIR)`` and ``load_dataset(DIR)`` read the shards and skip the
hidden ``.`` entries.

Integrity: every data page is written with its CRC-32 (Parquet page checksums), and
:func:`verify_shard` reads every column of every row group with the checksums verified and compares the
row count with the footer's, so that a flipped bit anywhere is a ``ShardError`` naming the shard. Shards
written before checksums can only be checked by decoding (a flip inside a compressed page is usually
caught, one in plain values is not). ``cmudrive data stats`` and ``cmudrive train`` (``load_shards``)
verify every shard before they count or train on it.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from cmudrive.bench.records import record_stem

if TYPE_CHECKING:
    import datasets

SHARD_SUFFIX = ".parquet"
RECORDS_DIR = ".routes"  # hidden: datasets skips it (it does not skip "_" names)
MANIFEST = ".run.json"  # what collected the folder (bench/manifest.py); hidden, as datasets reads the rest
ROW_GROUP = 256  # [rows] per Parquet row group (a flush of the writer)
COMPRESSION = "zstd"  # Parquet codec: the occupancy arrays are mostly zeros
COMPRESSION_LEVEL = 3  # zstd level (measured: level 1 is no faster here and 6 % larger)
# dictionary encoding pays on the repeated strings only; on the occupancy arrays it costs ~40 % of the
# write time for ~10 % of their size
DICTIONARY_COLUMNS = (
    "route_id",
    "scenario_type",
    "weather",
    "town",
    "reason",
    "object_kind",
    "communication",
)


class ShardError(ValueError):
    """A shard that cannot be read whole (corrupt page, checksum mismatch, wrong row count); the message
    names the file."""


def verify_shard(path: Path) -> int:
    """Read every column of every row group of ``path`` with the page checksums verified (one row group
    in memory at a time) and return its row count; ``ShardError`` naming the file when a page is corrupt
    or the rows read differ from the footer's count."""
    try:
        shard = pq.ParquetFile(path, page_checksum_verification=True)
        expected = shard.metadata.num_rows
        rows = 0
        for group in range(shard.num_row_groups):
            table = shard.read_row_group(group)
            table.validate(full=True)  # offsets, dictionary indices and UTF-8 inside the decoded arrays
            rows += table.num_rows
    except (OSError, pa.ArrowException) as exc:
        raise ShardError(f"{path}: corrupt shard ({exc}); delete it and collect its route again") from None
    if rows != expected:
        raise ShardError(f"{path}: corrupt shard: {rows} rows read, the footer says {expected}")
    return rows


def shard_path(out: Path, route_id: str) -> Path:
    return out / f"{record_stem(route_id)}{SHARD_SUFFIX}"


def shard_complete(path: Path) -> bool:
    """The shard exists and its Parquet footer reads (a half-written file never has this name)."""
    try:
        pq.read_metadata(path)
    except (OSError, pa.ArrowException):
        return False
    return True


def shard_rows(path: Path) -> int:
    return int(pq.read_metadata(path).num_rows)


def shard_paths(out: Path) -> list[Path]:
    return sorted(p for p in Path(out).glob(f"*{SHARD_SUFFIX}") if not p.name.startswith((".", "_")))


class ShardWriter:
    """Writes one route's rows to ``DIR/.<stem>.parquet.tmp`` in row groups as they come, and renames the
    file to ``DIR/<stem>.parquet`` in :meth:`close`; :meth:`abort` removes it."""

    def __init__(self, out: Path, route_id: str, schema: pa.Schema) -> None:
        """``schema``: the Arrow schema of :func:`cmudrive.data.schema.features`."""
        self.path = shard_path(out, route_id)
        self.tmp = self.path.with_name(f".{self.path.name}.tmp")
        self.schema = schema
        self._writer: pq.ParquetWriter | None = None
        self.rows = 0

    def write(self, rows: dict[str, list[Any]]) -> None:
        """Append a batch: a list per column (images as ``{"bytes", "path"}`` dicts, arrays as numpy)."""
        if not rows or not next(iter(rows.values())):
            return
        table = to_table(rows, self.schema)
        self._open().write_table(table, row_group_size=ROW_GROUP)
        self.rows += table.num_rows

    def _open(self) -> pq.ParquetWriter:
        if self._writer is None:
            self.tmp.parent.mkdir(parents=True, exist_ok=True)
            self._writer = pq.ParquetWriter(
                self.tmp,
                self.schema,
                compression=COMPRESSION,
                compression_level=COMPRESSION_LEVEL,
                use_dictionary=list(DICTIONARY_COLUMNS),
                write_page_checksum=True,  # CRC-32 per page: verify_shard finds any flipped bit
            )
        return self._writer

    def close(self) -> Path:
        """Finish the file (an empty shard with the schema when no row came) and give it its name."""
        self._open().close()
        self._writer = None
        os.replace(self.tmp, self.path)
        return self.path

    def abort(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        self.tmp.unlink(missing_ok=True)


def to_table(rows: dict[str, list[Any]], schema: pa.Schema) -> pa.Table:
    """Rows as lists per column -> an Arrow table of ``schema`` (``features().arrow_schema``), built column by
    column from numpy: images are ``{"bytes", "path"}`` dicts, fixed-size list-of-list columns take (h, w)
    arrays; the rest goes through ``pa.array``. Holds what ``datasets.Dataset.from_dict`` would, several
    times faster (a test checks that)."""
    arrays = []
    for f in schema:
        values = rows[f.name]
        t = f.type
        if pa.types.is_struct(t) and [t.field(i).name for i in range(t.num_fields)] == ["bytes", "path"]:
            data = pa.array([v["bytes"] for v in values], pa.binary())
            nulls = pa.nulls(len(values), pa.string())
            arrays.append(pa.StructArray.from_arrays([data, nulls], fields=list(t)))
        elif pa.types.is_fixed_size_list(t) and pa.types.is_fixed_size_list(t.value_type):
            h, w = t.list_size, t.value_type.list_size
            dtype = t.value_type.value_type.to_pandas_dtype()
            grid = np.asarray(values, dtype=dtype).reshape(-1) if values else np.zeros(0, dtype)
            inner = pa.FixedSizeListArray.from_arrays(pa.array(grid), w)
            arrays.append(pa.FixedSizeListArray.from_arrays(inner, h))
        else:
            arrays.append(pa.array(values, t))
    return pa.Table.from_arrays(arrays, schema=schema)


def load_shards(out: Path | str, columns: Iterable[str] | None = None) -> datasets.Dataset:
    """All shards of a folder as one ``datasets.Dataset`` (the ``train`` split of the parquet loader),
    each verified first (:func:`verify_shard`: datasets' reader neither checks page checksums nor names
    the file it failed on)."""
    import datasets

    paths = shard_paths(Path(out))
    if not paths:
        raise FileNotFoundError(f"{out}: no {SHARD_SUFFIX} shard")
    for path in paths:
        verify_shard(path)
        if columns is not None:
            missing = [c for c in columns if c not in pq.read_schema(path).names]
            if missing:
                raise ShardError(
                    f"{path}: no column {', '.join(missing)}: the shard was written by an older cmudrive; "
                    "collect the data again (cmudrive data collect)"
                )
    files = [str(p) for p in paths]
    if columns is None:
        return datasets.load_dataset("parquet", data_files=files, split="train")
    # only these columns reach datasets' Arrow cache (uncompressed: the two occupancy grids alone are
    # 48 KiB a row, 11 GiB for the training collection)
    ds = datasets.load_dataset("parquet", data_files=files, split="train", columns=list(columns))
    return ds.select_columns(list(columns))  # in the order asked for
