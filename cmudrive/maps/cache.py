"""Load a map (and its static scenery) by town name or path, converting it once and caching the arrays.

The cache key is the SHA-256 of the network file plus a hash of the code that builds the arrays
(``model.py``, ``loader.py``, ``index.py``), so an edited network or a changed map model never reads
stale arrays. Cache files are ``.npz`` (no pickles) written to a temporary
name and renamed into place, so an interrupted conversion leaves nothing half-written. The cache folder is
``$CMUDRIVE_CACHE/maps`` (default ``~/.cache/cmudrive/maps``); if it cannot be written the map is still
returned, just not cached.

Static scenery (:func:`load_scenery`) is cached the same way, keyed by the network's hash, the seed and a
hash of the scenery code (``scenery.py``, ``scenery_build.py`` and the map builder's modules).
"""

from __future__ import annotations

import functools
import hashlib
import os
import tempfile
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from cmudrive.maps.errors import MapError
from cmudrive.maps.loader import file_sha256, read_sumo_net
from cmudrive.maps.model import RoadMap
from cmudrive.maps.scenery import StaticScenery

_BUILDER_MODULES = ("model.py", "loader.py", "index.py")  # the code whose output is cached
_SCENERY_MODULES = (*_BUILDER_MODULES, "scenery.py", "scenery_build.py")
NET_SUFFIX = ".net.xml"


def assets_dir() -> Path:
    """Folder of the committed town networks (package data)."""
    return Path(__file__).resolve().parent.parent / "assets" / "maps"


def available_towns() -> list[str]:
    """Names of the committed towns, sorted."""
    return sorted(p.name[: -len(NET_SUFFIX)] for p in assets_dir().glob(f"*{NET_SUFFIX}"))


def cache_dir() -> Path:
    root = os.environ.get("CMUDRIVE_CACHE") or os.path.join(os.path.expanduser("~"), ".cache", "cmudrive")
    return Path(root) / "maps"


def resolve_map_path(town_or_path: str | Path, search: Sequence[str | Path] = ()) -> Path:
    """A path to a ``.net.xml`` file, or a town name (``"Town03"``): ``<name>.net.xml`` in the first
    folder of ``search`` that has it (a route file's own folder, ``--town-dir``), else a committed town."""
    candidate = Path(town_or_path)
    if candidate.suffix in (".xml", ".gz") or candidate.exists() or os.sep in str(town_or_path):
        if not candidate.is_file():
            raise MapError(f"map file not found: {candidate}")
        return candidate
    for folder in [*map(Path, search), assets_dir()]:
        path = folder / f"{town_or_path}{NET_SUFFIX}"
        if path.is_file():
            return path
    towns = ", ".join(available_towns()) or "(none built)"
    where = f" (searched {', '.join(str(s) for s in search)} and the committed towns)" if search else ""
    raise MapError(f"unknown town {str(town_or_path)!r}{where}; available towns: {towns}")


def load_map(town_or_path: str | Path, use_cache: bool = True, search: Sequence[str | Path] = ()) -> RoadMap:
    """Load a town or network file as a :class:`RoadMap`, from the cache when possible (``search``: see
    :func:`resolve_map_path`)."""
    path = resolve_map_path(town_or_path, search)
    name = path.name[: -len(NET_SUFFIX)] if path.name.endswith(NET_SUFFIX) else path.stem
    if not use_cache:
        return read_sumo_net(path, name=name)
    key = f"{file_sha256(path)[:32]}-{_builder_version()}"
    cached = cache_dir() / f"{name}-{key}.npz"
    if cached.is_file():
        try:
            with np.load(cached, allow_pickle=False) as data:
                return RoadMap.from_arrays({k: data[k] for k in data.files})
        except Exception as exc:  # a corrupt cache entry is rebuilt, never trusted
            warnings.warn(f"ignoring unreadable map cache {cached}: {exc}", stacklevel=2)
    road_map = read_sumo_net(path, name=name)
    _save(road_map.arrays(), cached)
    return road_map


def load_scenery(
    town_or_path: str | Path | RoadMap,
    seed: int = 0,
    use_cache: bool = True,
    search: Sequence[str | Path] = (),
) -> StaticScenery:
    """The static scenery of a town, a network file or a loaded :class:`RoadMap` (built by
    :func:`cmudrive.maps.scenery_build.build_scenery` once per map and seed, then read from the cache)."""
    road_map = town_or_path if isinstance(town_or_path, RoadMap) else load_map(town_or_path, search=search)
    if not use_cache:
        return _build_scenery(road_map, seed)
    key = f"{road_map.source_sha256[:32]}-s{seed}-{_builder_version(_SCENERY_MODULES)}"
    cached = cache_dir() / "scenery" / f"{road_map.name}-{key}.npz"  # apart from the map entries
    if cached.is_file():
        try:
            with np.load(cached, allow_pickle=False) as data:
                return StaticScenery.from_arrays({k: data[k] for k in data.files})
        except Exception as exc:  # a corrupt cache entry is rebuilt, never trusted
            warnings.warn(f"ignoring unreadable scenery cache {cached}: {exc}", stacklevel=2)
    scenery = _build_scenery(road_map, seed)
    _save(scenery.arrays(), cached)
    return scenery


def _build_scenery(road_map: RoadMap, seed: int) -> StaticScenery:
    from cmudrive.maps.scenery_build import build_scenery  # shapely is imported only to build

    return build_scenery(road_map, seed)


@functools.cache
def _builder_version(modules: tuple[str, ...] = _BUILDER_MODULES) -> str:
    digest = hashlib.sha256()
    for module in modules:
        digest.update((Path(__file__).parent / module).read_bytes())
    return digest.hexdigest()[:12]


def _save(arrays: dict[str, np.ndarray], target: Path) -> None:
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{target.stem}.", suffix=".npz", dir=target.parent)
        try:
            with os.fdopen(fd, "wb") as fh:
                np.savez(fh, **arrays)  # type: ignore[arg-type]
            os.replace(tmp, target)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
    except OSError as exc:
        warnings.warn(f"map cache not written ({target}): {exc}", stacklevel=3)
