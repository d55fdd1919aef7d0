"""Reading a route log (``cmudrive.bench.recording`` writes it) back: :class:`RouteLog` and
:func:`load_route_log`.

Loading trusts nothing in the file: the declared (uncompressed) sizes of the archive's members and the
shapes in their ``.npy`` headers are checked against ``MAX_LOG_BYTES`` before any array is read (a 5.9 MB
crafted log once asked for 5.59 GiB), and after reading, every field's shape and index, the header's
``dt`` (finite, > 0), finite poses, extents and routes, known actor kinds and roles, ASCII light states and
every event (a JSON object with an integer ``tick`` of the log and a ``cav`` of the route, finite
``x``/``y``) are checked, so that a replay never starts on a log it cannot draw. Each problem is a
``RouteLogError`` naming the file.
"""

from __future__ import annotations

import json
import math
import zipfile
import zlib
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from cmudrive.bench.recording import CONTROL_NAMES, EVENT_FIELDS, FORMAT_NAME, FORMAT_VERSION
from cmudrive.sim.dynamics import Controls
from cmudrive.sim.snapshot import ActorKind, Role, Snapshot

EVENT_SECONDS = 3.0  # [s] an event counts as active (a replay shows its marker) this long from its tick
# [bytes] uncompressed size of a log, all members together: a 4000-tick route with 1000 actors at once is
# ~120 MB (28 bytes per actor row), so this leaves ~9x room; larger declared sizes are refused unread
MAX_LOG_BYTES = 2**30
MAX_DT = 10.0  # [s] a tick longer than this is not a recording of ours


class RouteLogError(ValueError):
    """A route log that cannot be read (missing, corrupt, unsupported version); the message names the file."""


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
