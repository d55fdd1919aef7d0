"""What produced an output folder, and what a ``--resume`` compares before it adds to one.

Shared by the resumable commands (``cmudrive eval``, ``cmudrive data collect``, ``cmudrive train``): the
code version (the package version and, in a git checkout, its commit), content hashes of files and
folders (checkpoints, route files), settings turned into plain JSON, and :func:`settings_diff`, which
names every setting two such records disagree on with its old and new value. Standard library only: the
training code imports it without the simulator, the simulator without torch.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import hashlib
import json
import math
import os
import subprocess
from collections.abc import Iterable, Mapping
from fnmatch import fnmatchcase
from pathlib import Path
from typing import Any

import cmudrive

GIT_TIMEOUT = 5.0  # [s] for each git call of code_version (a hung git must not hold a run up)
SHOWN_CHARS = 120  # longest value shown in a difference before it is cut


class _Absent:
    """A setting one of the two records does not have."""

    def __repr__(self) -> str:
        return "(not set)"


ABSENT: Any = _Absent()


@functools.lru_cache(maxsize=1)
def code_version() -> dict[str, Any]:
    """``{"cmudrive": version, "git_commit": sha or None, "git_dirty": bool or None}``: the commit and
    whether tracked files differ from it when the package is imported from a git checkout (its parent
    folder holds ``.git``), None otherwise (an installed wheel, no git)."""
    root = Path(cmudrive.__file__).resolve().parents[1]
    commit, dirty = None, None
    if (root / ".git").exists():
        commit = _git(root, "rev-parse", "HEAD")
        status = _git(root, "status", "--porcelain", "--untracked-files=no") if commit else None
        dirty = None if status is None else bool(status)
    return {"cmudrive": cmudrive.__version__, "git_commit": commit, "git_dirty": dirty}


def _git(root: Path, *args: str) -> str | None:
    try:
        done = subprocess.run(
            ["git", "-C", str(root), *args],
            capture_output=True,
            text=True,
            timeout=GIT_TIMEOUT,
            check=False,
            env={**os.environ, "GIT_OPTIONAL_LOCKS": "0"},  # status must not write the index
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout.strip() if done.returncode == 0 else None


def describe_code(code: Mapping[str, Any]) -> str:
    """``cmudrive 0.1.0 (git 5248555, uncommitted changes)`` for a :func:`code_version` record."""
    text = f"cmudrive {code.get('cmudrive')}"
    if code.get("git_commit"):
        dirty = ", uncommitted changes" if code.get("git_dirty") else ""
        text += f" (git {str(code['git_commit'])[:12]}{dirty})"
    return text


def tree_sha256(path: str | os.PathLike[str]) -> str:
    """SHA-256 of a file's bytes, or of a folder: every file below it (symbolic links followed) by its
    path relative to the folder and its bytes, in sorted order. Where it lies and the files' times do not
    count: a checkpoint copied elsewhere has the same hash."""
    path = Path(path)
    if path.is_file():
        return _file_sha256(path)
    digest = hashlib.sha256()
    for file in sorted(p for p in path.rglob("*") if p.is_file()):
        digest.update(file.relative_to(path).as_posix().encode("utf-8", "surrogateescape") + b"\0")
        digest.update(_file_sha256(file).encode() + b"\n")
    return digest.hexdigest()


def _file_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def json_sha256(data: Any) -> str:
    """SHA-256 of ``data`` as canonical JSON (sorted keys, no spaces)."""
    text = json.dumps(to_jsonable(data), sort_keys=True, separators=(",", ":"), allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()


def to_jsonable(value: Any) -> Any:
    """Plain JSON data for settings: dataclasses as dicts, tuples as lists, paths and enum members as
    their value, numpy scalars and arrays as numbers and lists, non-finite floats as strings."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: to_jsonable(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, Mapping):
        return {str(k): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple | set | frozenset):
        items = [to_jsonable(v) for v in value]
        return sorted(items, key=repr) if isinstance(value, set | frozenset) else items
    if isinstance(value, enum.Enum):
        return to_jsonable(value.value)
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    if hasattr(value, "tolist"):  # numpy scalars and arrays
        return to_jsonable(value.tolist())
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if value is None or isinstance(value, bool | int | float | str):
        return value
    return repr(value)


def flatten(data: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{"a": {"b": 1}}`` -> ``{"a.b": 1}`` (lists stay values; an empty dict stays a value)."""
    flat: dict[str, Any] = {}
    for key, value in data.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping) and value:
            flat.update(flatten(value, f"{name}."))
        else:
            flat[name] = value
    return flat


def settings_diff(
    old: Mapping[str, Any], new: Mapping[str, Any], ignore: Iterable[str] = ()
) -> list[tuple[str, Any, Any]]:
    """``(setting, old value, new value)`` for every setting (dotted path through nested dicts) whose
    values differ, sorted by name; a setting only one side has gets :data:`ABSENT` on the other.
    ``ignore``: names or ``fnmatch`` patterns of settings that may differ."""
    a, b = flatten(to_jsonable(old)), flatten(to_jsonable(new))
    patterns = tuple(ignore)
    return [
        (key, a.get(key, ABSENT), b.get(key, ABSENT))
        for key in sorted(a.keys() | b.keys())
        if a.get(key, ABSENT) != b.get(key, ABSENT) and not any(fnmatchcase(key, p) for p in patterns)
    ]


def describe_diff(diff: Iterable[tuple[str, Any, Any]], indent: str = "  ") -> str:
    """One line per difference: ``tick_cap: 4000 (then) -> 200 (now)``."""
    return "\n".join(f"{indent}{key}: {_shown(old)} (then) -> {_shown(new)} (now)" for key, old, new in diff)


def _shown(value: Any) -> str:
    text = repr(value) if value is ABSENT else json.dumps(value)
    return text if len(text) <= SHOWN_CHARS else text[: SHOWN_CHARS - 3] + "..."


__all__ = [
    "ABSENT",
    "code_version",
    "describe_code",
    "describe_diff",
    "flatten",
    "json_sha256",
    "settings_diff",
    "to_jsonable",
    "tree_sha256",
]
