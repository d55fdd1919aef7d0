"""Route logs: a compact record of one route's run, its format and its recorder.

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

Typical use::

    recorder = RouteRecorder(spec.id, spec.town, [r.xy for r in cav_routes])
    for ...:                                        # once per tick
        snap = world.tick(controls)
        recorder.record(snap, controls, np.flatnonzero(snap.role == Role.CAV))
        recorder.add_events(recorder.num_ticks - 1, [infraction_event(cav, inf) for cav, inf in new])
    recorder.save("results/logs/route_0.npz")
    log = load_route_log("results/logs/route_0.npz")

The evaluator records through :class:`LogRecorder`, a step callback (``cmudrive.bench.callbacks``).
``cmudrive.bench.route_log`` reads a log back (checking every field); ``cmudrive.viz.replay`` draws it as
a BEV video.
"""

from __future__ import annotations

import json
import os
import re
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from cmudrive.bench.callbacks import RouteCallback, RouteStart, Step
from cmudrive.bench.records import Infraction, RouteResult, record_stem
from cmudrive.sim.dynamics import Controls
from cmudrive.sim.snapshot import Role, Snapshot

FORMAT_NAME = "cmudrive.route_log"
FORMAT_VERSION = 1  # bump on any incompatible change; readers refuse newer versions
DEFAULT_DT = 0.05  # [s] one tick (20 Hz)
CONTROL_NAMES = ("steer", "throttle", "brake")
EVENT_FIELDS = ("cav", "key", "x", "y", "message")  # required in every event
_CAV_ID = re.compile(r"^cav(\d+)$")


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


# ---------------------------------------------------------------------- the evaluator's log
class LogRecorder(RouteCallback):
    """A step callback that writes the route log of every route it watches (``cmudrive eval --record``):
    each tick's world after the step with the controls applied in it, the infractions as events, saved
    as ``<folder>/<record_stem(route id)>.npz`` when the route ends (crashed routes included)."""

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)
        self.recorder: RouteRecorder | None = None

    def on_route_start(self, start: RouteStart) -> None:
        routes = [c.dense_route for c in start.setup.cavs]
        assert all(r is not None for r in routes)  # callbacks get the privileged set-up
        self.recorder = RouteRecorder(start.spec.id, start.spec.town, [r.xy for r in routes if r is not None])

    def on_step(self, step: Step) -> None:
        assert self.recorder is not None
        self.recorder.record(step.after, step.applied, np.flatnonzero(step.after.role == Role.CAV))

    def on_route_end(self, result: RouteResult) -> None:
        if self.recorder is None:  # the route ended before it started (the agent's setup crashed)
            return
        for i, cav in enumerate(result.cavs):
            for events in cav.infractions.values():
                for inf in events:  # log ticks count recorded snapshots: world step 1 is log tick 0
                    self.recorder.add_events(max(inf.tick - 1, 0), [infraction_event(i, inf)])
        self.recorder.save(self.folder / f"{record_stem(result.route_id)}.npz")
