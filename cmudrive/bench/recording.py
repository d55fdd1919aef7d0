"""Route logs: a compact record of one route's run; its recorder, and its loader that checks every field.

A log holds every actor's pose per tick, the CAVs' controls, the traffic lights, the CAVs' routes and the
infraction events, in one compressed ``.npz`` of plain arrays (no pickles: loading a log never runs
code, and numpy alone reads it). The layout, with shapes, dtypes and units, is in ``docs/formats.md``.

Actors appear and disappear during a route, so the log has a static **actor table** (one row per actor:
id, kind, role, extent) and per-tick actor rows in CSR form: tick ``k`` is rows
``tick_ptr[k]:tick_ptr[k + 1]``, each pointing into the table. A 4000-tick route with 200 actors is
~11 MB on disk (float32 poses). Recording keeps no Python object per actor per tick: each tick appends
a few small numpy arrays, which ``save`` concatenates.

Ticks of a log are numbered by recording order, ``0 .. num_ticks - 1`` (``RouteLog.step`` keeps the
world's own step number of each); event ticks use the same numbering. The controls of a tick are what
the caller passes with its snapshot: the evaluator passes the controls applied in the world step that
produced the snapshot.

Loading trusts nothing in the file: the declared (uncompressed) sizes of the archive's members and the
shapes in their ``.npy`` headers are checked against ``MAX_LOG_BYTES`` before any array is read (a 5.9 MB
crafted log once asked for 5.59 GiB), and after reading, every field's shape and index, the header's
``dt`` (finite, > 0), finite poses, extents and routes, known actor kinds and roles, ASCII light states and
every event (a JSON object with an integer ``tick`` of the log and a ``cav`` of the route, finite
``x``/``y``) are checked, so that a replay never starts on a log it cannot draw. Each problem is a
``RouteLogError`` naming the file.

Typical use::

    recorder = RouteRecorder(spec.id, spec.town, [r.xy for r in cav_routes])
    for ...:                                        # once per tick
        snap = world.tick(controls)
        recorder.record(snap, controls, np.flatnonzero(snap.role == Role.CAV))
        recorder.add_events(recorder.num_ticks - 1, [infraction_event(cav, inf) for cav, inf in new])
    recorder.save("results/logs/route_0.npz")
    log = load_route_log("results/logs/route_0.npz")

``cmudrive.viz.replay`` draws a log as a BEV video.
"""

from __future__ import annotations

import json
import math
import os
import re
import tempfile
import zipfile
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from cmudrive.bench.records import Infraction
from cmudrive.sim.dynamics import Controls
from cmudrive.sim.snapshot import ActorKind, Role, Snapshot

if TYPE_CHECKING:
    pass

FORMAT_NAME = "cmudrive.route_log"
FORMAT_VERSION = 1  # bump on any incompatible change; readers refuse newer versions
DEFAULT_DT = 0.05  # [s] one tick (20 Hz)
CONTROL_NAMES = ("steer", "throttle", "brake")
EVENT_FIELDS = ("cav", "key", "x", "y", "message")  # required in every event
_CAV_ID = re.compile(r"^cav(\d+)$")
EVENT_SECONDS = 3.0  # [s] an event counts as active (a replay shows its marker) this long from its tick
# [bytes] uncompressed size of a log, all members together: a 4000-tick route with 1000 actors at once is
# ~120 MB (28 bytes per actor row), so this leaves ~9x room; larger declared sizes are refused unread
MAX_LOG_BYTES = 2**30
MAX_DT = 10.0  # [s] a tick longer than this is not a recording of ours


class RouteLogError(ValueError):
    """A route log that cannot be read (missing, corrupt, unsupported version); the message names the file."""


def infraction_event(cav: int, infraction: Infraction) -> dict[str, Any]:
    """The log event of one :class:`Infraction` of CAV ``cav``."""
    return {
        "cav": int(cav),
        "key": infraction.key,
        "x": float(infraction.x),
        "y": float(infraction.y),
        "message": infraction.message,
        "time": float(infraction.time),
        "actor": infraction.actor,
    }


# ---------------------------------------------------------------------- recording
class RouteRecorder:
    """Collects one route's ticks in memory and writes them as a route log."""

    def __init__(
        self, route_id: str, town: str | Path, cav_routes: Sequence[np.ndarray], dt: float = DEFAULT_DT
    ) -> None:
        """``town``: the map name (or .net.xml path) the replay loads; ``cav_routes[i]``: CAV ``i``'s dense
        route, an (n, 2) polyline [m] in the map frame."""
        self.route_id = str(route_id)
        self.town = str(town)
        self.dt = float(dt)
        self.cav_routes: list[np.ndarray] = []
        for i, r in enumerate(cav_routes):
            xy = np.asarray(r, dtype=np.float64)
            if xy.ndim != 2 or xy.shape[1] != 2:
                raise ValueError(
                    f"route {self.route_id}: CAV {i}'s route has shape {xy.shape}, expected (n, 2)"
                )
            self.cav_routes.append(xy)
        self._table: dict[tuple[str, int, int, float, float], int] = {}  # actor -> actor-table row
        self._last: tuple[np.ndarray, ...] | None = None  # last tick's actor columns and table rows
        self._poses: list[np.ndarray] = []  # per tick (n, 4) float32: x, y, yaw, speed
        self._ints: list[np.ndarray] = []  # per tick (n, 2) int32: actor-table row, signals
        self._controls: list[np.ndarray] = []  # per tick (3, C) float32
        self._cav_actor: list[np.ndarray] = []  # per tick (C,) int32
        self._tls: list[np.ndarray] = []  # per tick (sum of light string lengths,) uint8
        self._tls_len: np.ndarray | None = None  # (T_lights,) int32, fixed by the first tick
        self._step: list[int] = []
        self._time: list[float] = []
        self._events: list[str] = []  # JSON, one per event
        self._cav_of_id: dict[str, int] = {}  # "cav3" -> 3

    @property
    def num_cavs(self) -> int:
        return len(self.cav_routes)

    @property
    def num_ticks(self) -> int:
        return len(self._step)

    def record(
        self,
        snap: Snapshot,
        controls: Controls | None,
        cav_rows: np.ndarray,
        *,
        cav_index: np.ndarray | None = None,
    ) -> None:
        """Append one tick: the valid actors of ``snap`` and the ``controls`` of the CAVs at snapshot rows
        ``cav_rows`` (in the same order; ``None``: no controls this tick). Each row's CAV index is read
        from its id (``cav3`` -> 3) unless ``cav_index`` gives them."""
        where = f"route {self.route_id}, tick {self.num_ticks}"
        valid = np.asarray(snap.valid, bool)
        sel: slice | np.ndarray = slice(None) if valid.all() else np.flatnonzero(valid)
        length = snap.length[sel].astype(np.float32)
        width = snap.width[sel].astype(np.float32)
        cols = (
            np.asarray(snap.ids[sel], dtype=str),
            snap.kind[sel].astype(np.int8),
            snap.role[sel].astype(np.int8),
        )
        actor = self._actor_rows(*cols, length, width)
        rows = np.asarray(cav_rows, dtype=np.int64).reshape(-1)
        if np.any((rows < 0) | (rows >= snap.num_actors)) or not np.all(valid[rows]):
            raise ValueError(f"{where}: cav_rows {rows.tolist()} are not all valid rows of the snapshot")
        index = self._cav_indices(snap, rows, cav_index, where)
        cav_actor = np.full(self.num_cavs, -1, np.int32)
        cav_actor[index] = actor[rows if isinstance(sel, slice) else np.searchsorted(sel, rows)]
        ctl = np.full((3, self.num_cavs), np.nan, np.float32)
        if controls is not None:
            for j, name in enumerate(CONTROL_NAMES):
                value = np.asarray(getattr(controls, name), dtype=np.float64).reshape(-1)
                if value.shape != rows.shape:
                    raise ValueError(f"{where}: {name} has {value.size} values for {rows.size} CAV rows")
                ctl[j, index] = value
        tls = self._tls_chars(snap.tls_state, where)
        pose = np.empty((len(actor), 4), np.float32)
        for j, column in enumerate((snap.x, snap.y, snap.yaw, snap.speed)):
            pose[:, j] = column[sel]
        ints = np.empty((len(actor), 2), np.int32)
        ints[:, 0], ints[:, 1] = actor, snap.signals[sel]
        # every check passed: append the tick (a call that raises records nothing of it)
        self._poses.append(pose)
        self._ints.append(ints)
        self._controls.append(ctl)
        self._cav_actor.append(cav_actor)
        self._tls.append(tls)
        self._step.append(int(snap.step))
        self._time.append(float(snap.time))

    def add_events(self, tick: int, events: Sequence[dict[str, Any]]) -> None:
        """Add infraction / collision events of log tick ``tick``; each needs ``cav`` (index), ``key``,
        ``x``, ``y`` [m] and ``message``; other JSON-serialisable fields are kept."""
        if int(tick) < 0:
            raise ValueError(f"route {self.route_id}: event tick {tick} is negative")
        for ev in events:
            missing = [f for f in EVENT_FIELDS if f not in ev]
            if missing:
                raise ValueError(f"route {self.route_id}: event {ev!r} at tick {tick} lacks {missing}")
            item = {**ev, "tick": int(tick), "cav": int(ev["cav"]), "key": str(ev["key"])}
            item.update(x=float(ev["x"]), y=float(ev["y"]), message=str(ev["message"]))
            try:
                self._events.append(json.dumps(item, allow_nan=True))
            except TypeError as exc:
                raise ValueError(
                    f"route {self.route_id}: event {ev!r} is not JSON-serialisable: {exc}"
                ) from None

    def arrays(self) -> dict[str, np.ndarray]:
        """The log's fields (``docs/formats.md``), as written by :meth:`save`."""
        n_ticks, n_cavs = self.num_ticks, self.num_cavs
        counts = np.array([len(p) for p in self._poses], dtype=np.int64)
        tick_ptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        poses = np.concatenate(self._poses) if n_ticks else np.zeros((0, 4), np.float32)
        ints = np.concatenate(self._ints) if n_ticks else np.zeros((0, 2), np.int32)
        controls = np.stack(self._controls) if n_ticks else np.zeros((0, 3, n_cavs), np.float32)
        tls_len = self._tls_len if self._tls_len is not None else np.zeros(0, np.int32)
        tls = np.stack(self._tls) if n_ticks else np.zeros((0, int(tls_len.sum())), np.uint8)
        keys = list(self._table)
        route_len = np.array([len(r) for r in self.cav_routes], dtype=np.int64)
        header = {
            "format": FORMAT_NAME,
            "version": FORMAT_VERSION,
            "route_id": self.route_id,
            "town": self.town,
            "dt": self.dt,
            "num_ticks": n_ticks,
            "num_cavs": n_cavs,
        }
        return {
            "header": np.array(json.dumps(header)),
            "actor_id": np.array([k[0] for k in keys], dtype=str),
            "actor_kind": np.array([k[1] for k in keys], dtype=np.int8),
            "actor_role": np.array([k[2] for k in keys], dtype=np.int8),
            "actor_length": np.array([k[3] for k in keys], dtype=np.float32),
            "actor_width": np.array([k[4] for k in keys], dtype=np.float32),
            "step": np.array(self._step, dtype=np.int64),
            "time": np.array(self._time, dtype=np.float64),
            "tick_ptr": tick_ptr,
            "actor": np.ascontiguousarray(ints[:, 0]),
            "x": np.ascontiguousarray(poses[:, 0]),
            "y": np.ascontiguousarray(poses[:, 1]),
            "yaw": np.ascontiguousarray(poses[:, 2]),
            "speed": np.ascontiguousarray(poses[:, 3]),
            "signals": np.ascontiguousarray(ints[:, 1]),
            "steer": np.ascontiguousarray(controls[:, 0]),
            "throttle": np.ascontiguousarray(controls[:, 1]),
            "brake": np.ascontiguousarray(controls[:, 2]),
            "cav_actor": np.stack(self._cav_actor) if n_ticks else np.zeros((0, n_cavs), np.int32),
            "tls_len": tls_len,
            "tls_state": tls,
            "route_ptr": np.concatenate([[0], np.cumsum(route_len)]).astype(np.int64),
            "route_xy": np.concatenate(self.cav_routes) if n_cavs else np.zeros((0, 2)),
            "events": np.array(self._events, dtype=str),
        }

    def save(self, path: str | Path) -> Path:
        """Write the log to ``path`` (compressed ``.npz``) atomically: a temporary file in the same folder,
        renamed over ``path`` once complete, so a crash never leaves a half-written log."""
        path = Path(path)
        arrays = self.arrays()
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        try:
            with os.fdopen(fd, "wb") as fh:
                np.savez_compressed(fh, **arrays)  # type: ignore[arg-type]
            os.chmod(tmp, 0o644)
            os.replace(tmp, path)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
        return path

    # ------------------------------------------------------------------ helpers
    def _actor_rows(
        self, ids: np.ndarray, kind: np.ndarray, role: np.ndarray, length: np.ndarray, width: np.ndarray
    ) -> np.ndarray:
        """(n,) int32 actor-table row of each actor, adding new actors. An actor is its id with its kind,
        role and extent: an id that comes back with other attributes gets a new row."""
        cols = (ids, kind, role, length, width)
        last = self._last
        if last is not None and all(np.array_equal(a, b) for a, b in zip(cols, last[:5], strict=True)):
            return last[5]  # the same actors as last tick: the common case, no Python loop
        rows = np.empty(len(ids), np.int32)
        keys = zip(ids.tolist(), kind.tolist(), role.tolist(), length.tolist(), width.tolist(), strict=True)
        for j, key in enumerate(keys):
            row = self._table.get(key)
            if row is None:
                row = self._table[key] = len(self._table)
            rows[j] = row
        self._last = (*cols, rows)
        return rows

    def _cav_indices(
        self, snap: Snapshot, rows: np.ndarray, cav_index: np.ndarray | None, where: str
    ) -> np.ndarray:
        if cav_index is not None:
            index = np.asarray(cav_index, dtype=np.int64).reshape(-1)
            if index.shape != rows.shape:
                raise ValueError(f"{where}: {index.size} CAV indices for {rows.size} CAV rows")
        else:
            names = snap.ids[rows].tolist()
            found = [self._cav_of_id.get(n) for n in names]
            if None in found:
                matches = [_CAV_ID.match(str(n)) for n in names]
                if not all(matches):
                    raise ValueError(
                        f"{where}: cav_rows point at {names}; CAV ids look like 'cav0' (or pass cav_index)"
                    )
                parsed = [int(m.group(1)) for m in matches if m]
                self._cav_of_id.update(zip(names, parsed, strict=True))
                found = list(parsed)
            index = np.array(found, dtype=np.int64)
        if np.any((index < 0) | (index >= self.num_cavs)) or len(set(index.tolist())) != len(index):
            raise ValueError(
                f"{where}: CAV indices {index.tolist()} are not distinct CAVs of 0..{self.num_cavs - 1}"
            )
        return index

    def _tls_chars(self, tls_state: np.ndarray, where: str) -> np.ndarray:
        states = [str(s) for s in np.asarray(tls_state).reshape(-1).tolist()]
        lengths = np.array([len(s) for s in states], dtype=np.int32)
        if self._tls_len is None:
            self._tls_len = lengths
        elif not np.array_equal(lengths, self._tls_len):
            raise ValueError(
                f"{where}: traffic-light state lengths {lengths.tolist()} differ from the first tick's "
                f"{self._tls_len.tolist()}"
            )
        try:
            return np.frombuffer("".join(states).encode("ascii"), dtype=np.uint8).copy()
        except UnicodeEncodeError as exc:
            raise ValueError(f"{where}: traffic-light states {states} are not ASCII") from exc


# ---------------------------------------------------------------------- loading
# field -> (numpy kind codes accepted, ndim, dtype it is read as)
_FIELDS: dict[str, tuple[str, int, type | str]] = {
    "header": ("U", 0, str),
    "actor_id": ("U", 1, str),
    "actor_kind": ("iu", 1, np.int8),
    "actor_role": ("iu", 1, np.int8),
    "actor_length": ("f", 1, np.float32),
    "actor_width": ("f", 1, np.float32),
    "step": ("iu", 1, np.int64),
    "time": ("f", 1, np.float64),
    "tick_ptr": ("iu", 1, np.int64),
    "actor": ("iu", 1, np.int64),
    "x": ("f", 1, np.float32),
    "y": ("f", 1, np.float32),
    "yaw": ("f", 1, np.float32),
    "speed": ("f", 1, np.float32),
    "signals": ("iu", 1, np.int32),
    "steer": ("f", 2, np.float32),
    "throttle": ("f", 2, np.float32),
    "brake": ("f", 2, np.float32),
    "cav_actor": ("iu", 2, np.int64),
    "tls_len": ("iu", 1, np.int64),
    "tls_state": ("u", 2, np.uint8),
    "route_ptr": ("iu", 1, np.int64),
    "route_xy": ("f", 2, np.float64),
    "events": ("U", 1, str),
}


@dataclass(frozen=True, eq=False)
class RouteLog:
    """A loaded route log. ``T`` ticks, ``C`` CAVs, ``N`` actors in the table, ``R`` actor rows in all."""

    path: Path
    route_id: str
    town: str  # map name or .net.xml path, as recorded
    dt: float  # [s]
    arrays: dict[str, np.ndarray]  # every field of docs/formats.md, in the dtypes of ``_FIELDS``

    @property
    def num_ticks(self) -> int:
        return int(self.arrays["step"].shape[0])

    @property
    def num_cavs(self) -> int:
        return int(self.arrays["route_ptr"].shape[0]) - 1

    @property
    def step(self) -> np.ndarray:
        """(T,) int64 the world's step number at each log tick."""
        return self.arrays["step"]

    @property
    def time(self) -> np.ndarray:
        """(T,) float64 simulation time [s] of each log tick."""
        return self.arrays["time"]

    @cached_property
    def events(self) -> list[dict[str, Any]]:
        """Every event in recording order: ``tick`` (log tick), ``cav``, ``key``, ``x``, ``y``, ``message``
        and any extra fields recorded with it."""
        return [json.loads(s) for s in self.arrays["events"].tolist()]

    @cached_property
    def cav_routes(self) -> list[np.ndarray]:
        """CAV ``i``'s dense route, (n, 2) float64 [m]."""
        ptr, xy = self.arrays["route_ptr"], self.arrays["route_xy"]
        return [xy[ptr[i] : ptr[i + 1]] for i in range(self.num_cavs)]

    def _tick(self, tick: int) -> int:
        k = int(tick)
        if not -self.num_ticks <= k < self.num_ticks:
            raise IndexError(f"route log {self.path}: tick {tick} out of range (it has {self.num_ticks})")
        return k % self.num_ticks

    def snapshot(self, tick: int) -> Snapshot:
        """The recorded actors of log tick ``tick`` as a :class:`Snapshot` (float32 precision). Fields the
        log does not keep get defaults: ``accel`` 0, ``lane`` -1, ``z`` NaN (any level), ``valid`` True."""
        k = self._tick(tick)
        a = self.arrays
        lo, hi = int(a["tick_ptr"][k]), int(a["tick_ptr"][k + 1])
        idx = a["actor"][lo:hi]
        n = hi - lo
        return Snapshot(
            step=int(a["step"][k]),
            time=float(a["time"][k]),
            ids=a["actor_id"][idx],
            kind=a["actor_kind"][idx],
            role=a["actor_role"][idx],
            x=a["x"][lo:hi].astype(np.float64),
            y=a["y"][lo:hi].astype(np.float64),
            yaw=a["yaw"][lo:hi].astype(np.float64),
            speed=a["speed"][lo:hi].astype(np.float64),
            accel=np.zeros(n),
            length=a["actor_length"][idx].astype(np.float64),
            width=a["actor_width"][idx].astype(np.float64),
            lane=np.full(n, -1, np.int32),
            z=np.full(n, np.nan),
            signals=a["signals"][lo:hi].copy(),
            valid=np.ones(n, bool),
            tls_state=self.tls_state(k),
        )

    def tls_state(self, tick: int) -> np.ndarray:
        """(T_lights,) str signal string of each traffic light at log tick ``tick``."""
        row = self.arrays["tls_state"][self._tick(tick)].tobytes().decode("ascii")
        ends = np.cumsum(self.arrays["tls_len"]).tolist()
        starts = [0, *ends[:-1]][: len(ends)]  # a town without lights (Town06) has none
        return np.array([row[s:e] for s, e in zip(starts, ends, strict=True)], dtype=str)

    def controls(self, tick: int) -> Controls:
        """(C,) controls of every CAV at log tick ``tick``; NaN where the CAV had none (gone)."""
        k = self._tick(tick)
        return Controls(*(self.arrays[name][k].astype(np.float64) for name in CONTROL_NAMES))

    def cav_xy(self, cav: int) -> np.ndarray:
        """(T, 2) float64 position [m] of CAV ``cav`` at every log tick, NaN where it was not in the world."""
        return self.cav_pose(cav)[:, :2]

    def cav_pose(self, cav: int) -> np.ndarray:
        """(T, 4) float64 x [m], y [m], yaw [rad], speed [m/s] of CAV ``cav`` at every log tick (map
        frame), NaN where it was not in the world."""
        a = self.arrays
        out = np.full((self.num_ticks, 4), np.nan)
        tick_of_row = np.repeat(np.arange(self.num_ticks), np.diff(a["tick_ptr"]))
        target = a["cav_actor"][:, cav]
        hit = (a["actor"] == target[tick_of_row]) & (target[tick_of_row] >= 0)
        for j, name in enumerate(("x", "y", "yaw", "speed")):
            out[tick_of_row[hit], j] = a[name][hit]
        return out

    def active_events(self, tick: int, seconds: float = EVENT_SECONDS) -> list[dict[str, Any]]:
        """Events from the ``seconds`` up to and including log tick ``tick``."""
        span = max(1, round(seconds / self.dt))
        return [e for e in self.events if e["tick"] <= tick < e["tick"] + span]


def load_route_log(path: str | Path) -> RouteLog:
    """Read a route log; a missing, corrupt or newer-version file raises :class:`RouteLogError` naming it."""
    path = Path(path)
    if not path.is_file():
        raise RouteLogError(f"route log {path} does not exist")
    try:
        _check_declared_sizes(path)
        loaded = np.load(path, allow_pickle=False)
        if not isinstance(loaded, np.lib.npyio.NpzFile):
            raise RouteLogError(f"route log {path} is a single array, not a route log (.npz)")
        with loaded as data:
            missing = [name for name in ("header", *_FIELDS) if name not in data.files]
            header = _header(path, data["header"]) if "header" in data.files else None
            if header is None or missing:
                raise RouteLogError(f"route log {path} is not a cmudrive route log: it lacks {missing}")
            arrays = {name: _field(path, name, data[name]) for name in _FIELDS}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
        if isinstance(exc, RouteLogError):
            raise
        raise RouteLogError(f"route log {path} is corrupt or unreadable: {exc}") from exc
    _check_consistent(path, arrays)
    _check_values(path, arrays)
    log = RouteLog(
        path=path, route_id=str(header["route_id"]), town=str(header["town"]), dt=header["dt"], arrays=arrays
    )
    _check_events(log)
    return log


def _check_declared_sizes(path: Path) -> None:
    """Refuse a log whose members declare more than ``MAX_LOG_BYTES`` uncompressed, or whose ``.npy``
    headers declare more data than their member holds, before numpy allocates anything."""
    if not zipfile.is_zipfile(path):
        raise RouteLogError(f"route log {path} is not a route log (.npz, a zip archive of arrays)")
    with zipfile.ZipFile(path) as archive:
        infos = archive.infolist()
        total = sum(info.file_size for info in infos)
        if total > MAX_LOG_BYTES:
            raise RouteLogError(
                f"route log {path} declares {total / 2**30:.2f} GiB of data, more than the "
                f"{MAX_LOG_BYTES / 2**30:.0f} GiB a route log may hold"
            )
        for info in infos:
            with archive.open(info) as member:
                version = np.lib.format.read_magic(member)
                read_header = (
                    np.lib.format.read_array_header_1_0
                    if version == (1, 0)
                    else np.lib.format.read_array_header_2_0
                )
                shape, _, dtype = read_header(member, max_header_size=10_000)
            declared = math.prod(shape) * dtype.itemsize
            if declared > info.file_size:
                raise RouteLogError(
                    f"route log {path}: member {info.filename!r} declares {declared} bytes of data "
                    f"({shape} {dtype}) but holds {info.file_size}"
                )


def _header(path: Path, raw: np.ndarray) -> dict[str, Any]:
    try:
        header = json.loads(str(raw.item()))
    except (ValueError, TypeError) as exc:
        raise RouteLogError(f"route log {path}: unreadable header: {exc}") from exc
    if not isinstance(header, dict) or header.get("format") != FORMAT_NAME:
        raise RouteLogError(f"route log {path}: not a {FORMAT_NAME} file (header {header!r})")
    version = header.get("version")
    if not isinstance(version, int) or not 1 <= version <= FORMAT_VERSION:
        raise RouteLogError(
            f"route log {path}: unsupported format version {version!r} "
            f"(this cmudrive reads versions 1 to {FORMAT_VERSION})"
        )
    for key in ("route_id", "town", "dt"):
        if key not in header:
            raise RouteLogError(f"route log {path}: header lacks {key!r}")
    dt = header["dt"]
    if isinstance(dt, bool) or not isinstance(dt, int | float) or not 0.0 < dt <= MAX_DT:
        raise RouteLogError(
            f"route log {path}: header dt must be a number of seconds in (0, {MAX_DT:g}], got {dt!r}"
        )
    if not isinstance(header["route_id"], str) or not isinstance(header["town"], str):
        raise RouteLogError(f"route log {path}: header route_id and town must be strings")
    header["dt"] = float(dt)
    return header


def _field(path: Path, name: str, value: np.ndarray) -> np.ndarray:
    kinds, ndim, dtype = _FIELDS[name]
    if value.dtype.kind not in kinds or value.ndim != ndim:
        raise RouteLogError(f"route log {path}: field {name!r} is {value.dtype} with {value.ndim} dims")
    return value if dtype is str else value.astype(dtype, copy=False)


def _check_consistent(path: Path, a: dict[str, np.ndarray]) -> None:
    """Shapes and indices agree with each other, so that every tick can be rebuilt."""
    n_ticks, n_actors, n_rows = len(a["step"]), len(a["actor_id"]), len(a["actor"])
    n_cavs = len(a["route_ptr"]) - 1
    ptr = a["tick_ptr"]
    problems = []
    if any(len(a[f]) != n_actors for f in ("actor_kind", "actor_role", "actor_length", "actor_width")):
        problems.append("actor table columns differ in length")
    if len(ptr) != n_ticks + 1 or ptr[0] != 0 or ptr[-1] != n_rows or np.any(np.diff(ptr) < 0):
        problems.append(f"tick_ptr does not index {n_rows} rows over {n_ticks} ticks")
    if any(len(a[f]) != n_rows for f in ("x", "y", "yaw", "speed", "signals")):
        problems.append("per-row columns differ in length")
    if n_rows and (a["actor"].min() < 0 or a["actor"].max() >= n_actors):
        problems.append("actor rows point outside the actor table")
    if len(a["time"]) != n_ticks:
        problems.append("time and step differ in length")
    if any(a[f].shape != (n_ticks, n_cavs) for f in (*CONTROL_NAMES, "cav_actor")):
        problems.append(f"controls / cav_actor are not ({n_ticks}, {n_cavs})")
    elif a["cav_actor"].size and (a["cav_actor"].min() < -1 or a["cav_actor"].max() >= n_actors):
        problems.append("cav_actor points outside the actor table")
    if a["tls_state"].shape != (n_ticks, int(a["tls_len"].sum())):
        problems.append("tls_state does not match tls_len")
    rp = a["route_ptr"]
    if n_cavs < 0 or rp[0] != 0 or rp[-1] != len(a["route_xy"]) or np.any(np.diff(rp) < 0):
        problems.append("route_ptr does not index route_xy")
    if a["route_xy"].shape[1:] != (2,):
        problems.append("route_xy is not (P, 2)")
    if problems:
        raise RouteLogError(f"route log {path} is inconsistent: {'; '.join(problems)}")


def _check_values(path: Path, a: dict[str, np.ndarray]) -> None:
    """Values the replay draws are finite and known: poses, extents, routes, kinds, roles, light states."""
    problems = []
    for name in ("x", "y", "yaw", "speed", "actor_length", "actor_width", "route_xy", "time"):
        bad = np.flatnonzero(~np.isfinite(a[name]).reshape(len(a[name]), -1).all(axis=1))
        if len(bad):
            problems.append(f"{name} is not finite in {len(bad)} rows (first: row {int(bad[0])})")
    if np.any(a["actor_length"] <= 0.0) or np.any(a["actor_width"] <= 0.0):
        problems.append("an actor extent is not positive")
    for name, enum in (("actor_kind", ActorKind), ("actor_role", Role)):
        unknown = sorted(set(a[name].tolist()) - {int(v) for v in enum})
        if unknown:
            problems.append(f"{name} holds unknown values {unknown[:5]}")
    if a["tls_state"].size and int(a["tls_state"].max()) >= 128:
        problems.append("tls_state is not ASCII")
    if problems:
        raise RouteLogError(f"route log {path} holds values a replay cannot draw: {'; '.join(problems)}")


def _check_events(log: RouteLog) -> None:
    """Every event is a JSON object with the fields of ``EVENT_FIELDS`` and ``tick``: an integer log tick,
    a CAV of the route, finite x and y, a string key and message."""
    for i, raw in enumerate(log.arrays["events"].tolist()):
        where = f"route log {log.path}: event {i}"
        try:
            event = json.loads(raw)
        except (ValueError, RecursionError):
            raise RouteLogError(f"{where} is not JSON") from None
        if not isinstance(event, dict):
            raise RouteLogError(f"{where} is not an object")
        missing = [k for k in ("tick", *EVENT_FIELDS) if k not in event]
        if missing:
            raise RouteLogError(f"{where} lacks {missing}")
        for name, limit in (("tick", log.num_ticks), ("cav", log.num_cavs)):
            value = event[name]
            if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < limit:
                raise RouteLogError(f"{where}: {name} must be an integer in 0..{limit - 1}, got {value!r}")
        for name in ("x", "y"):
            value = event[name]
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
                raise RouteLogError(f"{where}: {name} must be a finite number, got {value!r}")
        if not isinstance(event["key"], str) or not isinstance(event["message"], str):
            raise RouteLogError(f"{where}: key and message must be strings")
