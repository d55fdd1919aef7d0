"""Committed route sets by name, and subsets of a route file (``--routes-subset``).

Naming a route file on the command line (``--routes``, ``routes check/stats/show``):

1. the name of a committed set (``cmudrive/assets/routes/<name>.xml``: :data:`ROUTE_SET_PURPOSES`) is that
   set, even when a file or folder of the same name is in the current folder (write ``./smoke`` for it);
2. anything else is a path: a folder is refused, saying so; a bare word that is neither a set nor a file
   is an unknown set name, and the error suggests the closest names (``difflib``).

A subset picks routes of a file as the CARLA leaderboard's ``--routes-subset`` does, extended to our string
ids (:func:`select_subset`): comma-separated items, each

* an exact route id (``Accident_0``; an id always wins over the readings below),
* a 0-based index in the file's order (``3``), or
* an inclusive range of indices (``0-5``: the first six routes),

and the routes run in file order, each once. An unknown id, or an index past the end, is an error that
names it (with the closest ids, or the file's number of routes).
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Sequence
from pathlib import Path

ROUTE_SET_DIR = Path(__file__).resolve().parents[1] / "assets" / "routes"

# what each committed set is for (``cmudrive routes list``)
ROUTE_SET_PURPOSES: dict[str, str] = {
    "cmudrive220": "the benchmark (paper Table 1): 44 scenario types x 5 routes, each weather 44 times",
    "cmudrive44": "the mini split: one route of cmudrive220 per scenario type, for quick runs",
    "smoke": "scenario-free routes on downtown, suburb and interurban: does the loop run at all",
    "training": "data collection (cmudrive data collect): other places than the benchmark's",
}
SUGGESTIONS = 3  # [-] close names offered for a typo
_INDEX = re.compile(r"\d+")
_RANGE = re.compile(r"(\d+)-(\d+)")


class RouteSelectionError(ValueError):
    """A route set name, route file path or route subset that does not name routes."""


def route_set_names() -> list[str]:
    """The committed route sets, sorted."""
    return sorted(p.stem for p in ROUTE_SET_DIR.glob("*.xml"))


def _close(word: str, names: Sequence[str]) -> str:
    close = difflib.get_close_matches(word, names, n=SUGGESTIONS, cutoff=0.5)
    return f"did you mean {' or '.join(repr(c) for c in close)}? " if close else ""


def resolve_routes(name_or_path: str) -> Path:
    """The route file that ``name_or_path`` names (module docstring): a committed set by name, else a
    path; RouteSelectionError for a folder or an unknown bare name."""
    sets = route_set_names()
    if name_or_path in sets:
        return ROUTE_SET_DIR / f"{name_or_path}.xml"
    path = Path(name_or_path)
    if path.is_dir():
        raise RouteSelectionError(
            f"{name_or_path}: is a folder, not a route file (committed route sets: {', '.join(sets)})"
        )
    bare = not path.suffix and len(path.parts) == 1 and not name_or_path.startswith(".")
    if bare and not path.exists():
        raise RouteSelectionError(
            f"no route set or route file {name_or_path!r}: {_close(name_or_path, sets)}"
            f"(committed route sets: {', '.join(sets)}; `cmudrive routes list` says what each is for)"
        )
    return path


def select_subset(ids: Sequence[str], subset: str, source: str = "the route file") -> list[str]:
    """The ids of ``ids`` (a file's routes in file order) that ``subset`` picks (module docstring), in
    file order; RouteSelectionError naming the item that picks nothing, and ``source``."""
    index = {route_id: i for i, route_id in enumerate(ids)}
    picked: set[int] = set()
    items = [item.strip() for item in subset.split(",")]
    if not any(items):
        raise RouteSelectionError(f"--routes-subset {subset!r}: no route id, index or range in it")
    for item in items:
        if not item:
            continue
        if item in index:
            picked.add(index[item])
            continue
        span = _RANGE.fullmatch(item)
        if _INDEX.fullmatch(item):
            first = last = int(item)
        elif span:
            first, last = int(span[1]), int(span[2])
            if first > last:
                raise RouteSelectionError(
                    f"--routes-subset: range {item!r} runs backwards (write {last}-{first})"
                )
        else:
            raise RouteSelectionError(
                f"--routes-subset: {source} has no route {item!r}; {_close(item, list(ids))}"
                "(items are route ids, 0-based indices such as 3, or index ranges such as 0-5)"
            )
        if last >= len(ids):
            raise RouteSelectionError(
                f"--routes-subset: index {last} is past the end of {source}, which holds {len(ids)} routes "
                f"(indices 0-{len(ids) - 1})"
            )
        picked.update(range(first, last + 1))
    return [ids[i] for i in sorted(picked)]


__all__ = [
    "ROUTE_SET_DIR",
    "ROUTE_SET_PURPOSES",
    "RouteSelectionError",
    "resolve_routes",
    "route_set_names",
    "select_subset",
]
