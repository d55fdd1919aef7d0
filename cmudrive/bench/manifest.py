"""``OUT/run.json``: what produced an output folder of ``cmudrive eval`` or ``cmudrive data collect``, and
the check a ``--resume`` makes before it adds records to one (``docs/formats.md``, "Run manifest").

A run's **setup** is everything that decides what a route's record says: the agent (its class), its
options and the content of the files it loads (a checkpoint folder's SHA-256, not its path), the
evaluation seed, every ``EvalConfig`` setting (tick cap, time limits, background traffic, criteria,
sensors with the V2V link and the detection noise, scenarios), the worker memory limit, and for
collection the sampling. ``--resume`` with another setup is refused with a :class:`SetupMismatchError`
that names each setting that differs, its value then and now; so is a resume whose kept records were run
on another definition of their route (route ids are the same, waypoints or seed are not). What cannot
change a record may differ: the number of workers, the executor, ``--record``, the route file (a resume
may add routes; the routes it keeps are checked one by one), and the code version, which is recorded in
the manifest and in every record and only warned about (:class:`ResumeWarning`): a user who pulls a fix
and resumes re-runs the crashed routes with it, and must not be made to re-run the finished ones. A
folder written before manifests existed is resumed with a warning and gets one from then on.
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from cmudrive.agents.base import BUNDLED_AGENTS, load_agent_class
from cmudrive.bench.evaluator import EvalConfig
from cmudrive.bench.records import RouteResult, write_json_atomic
from cmudrive.provenance import (
    code_version,
    describe_code,
    describe_diff,
    json_sha256,
    settings_diff,
    to_jsonable,
    tree_sha256,
)

MANIFEST = "run.json"
FORMAT = "cmudrive.run"
VERSION = 1
INFORMATION = ("agent_files.*.path",)  # where a file lay: its content is compared, not its path
NOT_SETUP = ("record_dir", "agent_options")  # EvalConfig fields kept out of "config" (options: own key)
SHOWN_ROUTES = 10  # route ids named in a message at most


class SetupMismatchError(ValueError):
    """A resume whose setup differs from the one that wrote the folder (the message names each setting)."""


class ResumeWarning(UserWarning):
    """A resume the folder cannot vouch for: other code, or records from before manifests existed."""


def run_setup(
    kind: str,
    agent: str,
    config: EvalConfig,
    seed: int = 0,
    max_memory: float | None = None,
    job: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """The setup of a run (module docstring) as plain JSON. ``kind``: ``eval`` or ``collect``; ``agent``:
    ``package.module:Class`` or a bundled name; ``job``: what a collection adds (its sampling)."""
    files = load_agent_class(agent).input_files(config.agent_options)
    options = {k: v for k, v in config.agent_options.items() if k not in files}
    settings = to_jsonable(config)
    return {
        "kind": kind,
        "agent": BUNDLED_AGENTS.get(agent, agent),
        "agent_options": to_jsonable(options),
        "agent_files": {k: {"sha256": tree_sha256(p), "path": str(p)} for k, p in sorted(files.items())},
        "seed": seed,
        "max_memory": max_memory,
        "config": {k: v for k, v in settings.items() if k not in NOT_SETUP},
        "job": to_jsonable(job) if job is not None else None,
    }


def setup_sha256(setup: Mapping[str, Any]) -> str:
    """Hash of a setup, the informational parts (file paths) left out."""
    files = {k: v["sha256"] for k, v in setup.get("agent_files", {}).items()}
    return json_sha256({**setup, "agent_files": files})


def read_manifest(out: Path, name: str = MANIFEST) -> dict[str, Any] | None:
    """``OUT/run.json`` (``name``), or None when there is none; a SetupMismatchError when it cannot be
    read."""
    path = Path(out) / name
    if not path.exists():
        return None
    try:
        manifest = json.loads(path.read_text())
        if manifest.get("format") != FORMAT or not isinstance(manifest.get("setup"), dict):
            raise ValueError(f"not a {FORMAT} manifest")
        if manifest.get("version") != VERSION:
            raise ValueError(f"manifest version {manifest.get('version')}, this cmudrive reads {VERSION}")
    except (OSError, ValueError, AttributeError) as exc:
        raise SetupMismatchError(
            f"{path} cannot be read ({exc}), so the setup of the records in {out} is unknown: repair it, or "
            "remove it to resume without the check"
        ) from exc
    return manifest


@dataclass(frozen=True)
class Run:
    """A run that passed the checks: what its records are stamped with."""

    setup_sha256: str
    code: dict[str, Any]

    def stamp(self, route_sha256: str) -> dict[str, Any]:
        """``RouteResult.provenance`` of a record of this run, for the route with that hash."""
        return {"setup_sha256": self.setup_sha256, "route_sha256": route_sha256, "code": self.code}


def start_run(
    out: Path,
    setup: Mapping[str, Any],
    route_hashes: Mapping[str, str],
    resume: bool,
    kept: Mapping[str, RouteResult],
    found: int = 0,
    settings: Mapping[str, Any] | None = None,
    routes_file: Path | None = None,
    name: str = MANIFEST,
) -> Run:
    """Check a resume, then write ``OUT/run.json`` with this run added (a new run: a new manifest).

    ``route_hashes``: route id -> ``route_sha256`` of every route of this run; ``kept``: the records a
    resume keeps (the others run again); ``found``: records or shards in the folder (a folder that holds
    some but no manifest was written before manifests existed); ``settings``: what may differ between
    resumes (workers, executor), recorded per run; ``routes_file``: recorded with its hash; ``name``: the
    manifest's file name in ``out``."""
    out = Path(out)
    digest = setup_sha256(setup)
    code = code_version()
    manifest = read_manifest(out, name) if resume else None
    entry: dict[str, Any] = {
        "started": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "resume": resume,
        "code": code,
        "routes": _routes_entry(route_hashes, routes_file),
        "settings": to_jsonable(dict(settings or {})),
    }
    if manifest is not None:
        _check_setup(out / name, manifest["setup"], setup)
    _check_records(out / name, kept, digest, route_hashes)
    codes = [(r.provenance or {}).get("code") for r in kept.values()]
    others = sorted({describe_code(c) for c in codes if c is not None and c != code})
    if others:
        warnings.warn(
            f"{out}: records kept by this resume were written by {' and '.join(others)}, this run is "
            f"{describe_code(code)}; each record names its code version",
            ResumeWarning,
            stacklevel=3,
        )
    if manifest is None and resume and found:
        warnings.warn(
            f"{out} holds {found} records from before runs recorded their setup (no {name}): nothing "
            "shows that they were made with this agent and these settings; from now on this run's setup "
            "is recorded and checked",
            ResumeWarning,
            stacklevel=3,
        )
        entry["unrecorded_records"] = found
    if manifest is None:
        manifest = {
            "format": FORMAT,
            "version": VERSION,
            "setup": dict(setup),
            "setup_sha256": digest,
            "runs": [],
        }
    manifest.setdefault("runs", []).append(entry)
    write_json_atomic(out / name, manifest)
    return Run(digest, code)


def _routes_entry(route_hashes: Mapping[str, str], routes_file: Path | None) -> dict[str, Any]:
    entry: dict[str, Any] = {"count": len(route_hashes), "sha256": json_sha256(sorted(route_hashes.items()))}
    if routes_file is not None:
        entry |= {"file": str(routes_file), "file_sha256": tree_sha256(routes_file)}
    return entry


def _check_setup(path: Path, old: Mapping[str, Any], new: Mapping[str, Any]) -> None:
    diff = settings_diff(old, new, ignore=INFORMATION)
    if diff:
        raise SetupMismatchError(
            f"{path.parent} was written with another setup, and --resume continues a run only with the same "
            f"one. Differences ({path} has the full setup):\n{describe_diff(diff)}\n"
            "Resume with the settings of then, or write to another output folder."
        )


def _check_records(
    path: Path, kept: Mapping[str, RouteResult], digest: str, route_hashes: Mapping[str, str]
) -> None:
    """Refuse kept records that another setup or another definition of their route produced (records
    without provenance, from before manifests existed, cannot be checked)."""
    setup, route = [], []
    for rid, record in kept.items():
        stamp = record.provenance or {}
        if stamp.get("setup_sha256") not in (None, digest):
            setup.append(rid)
        elif stamp.get("route_sha256") not in (None, route_hashes.get(rid)):
            route.append(rid)
    if setup:
        raise SetupMismatchError(
            f"{path.parent}: the records of {_ids(setup)} were made with another setup than this run's "
            f"(and than {path.name} says): write to another output folder"
        )
    if route:
        raise SetupMismatchError(
            f"{path.parent}: the records of {_ids(route)} were run on another definition of the route "
            "(same id, other waypoints, town, weather, seed or scenarios) than this route file's: resume "
            "with the route file of then, or write to another output folder"
        )


def _ids(ids: Sequence[str]) -> str:
    shown = ", ".join(repr(i) for i in sorted(ids)[:SHOWN_ROUTES])
    more = len(ids) - SHOWN_ROUTES
    return f"routes {shown}" + (f" and {more} more" if more > 0 else "")


__all__ = [
    "MANIFEST",
    "ResumeWarning",
    "Run",
    "SetupMismatchError",
    "read_manifest",
    "run_setup",
    "setup_sha256",
    "start_run",
]
