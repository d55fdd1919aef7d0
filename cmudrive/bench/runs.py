"""Evaluation runs as the comparison report reads them: a run's records, what produced it, and which runs
are seeds of one setup.

A **run** is an output folder of ``cmudrive eval`` (``RUN/results.json``, ``RUN/run.json``, optionally
``RUN/logs/*.npz``) or a results file. What produced it comes from the manifest (``run.json``, or the copy
``results.json`` keeps under ``"run"``; ``docs/formats.md``, "Run manifest"): the agent, its options and
files, the evaluation seed and every ``EvalConfig`` setting.

Runs are **grouped** when everything in their manifest's setup but the seed is equal (agent, options, the
content of the agent's files, memory limit, every evaluation setting): such runs are seeds of one
experiment and the report shows their mean and standard deviation. A run without a manifest (written
before manifests existed) is a group of its own, since nothing shows what produced it.

All runs of one report must be on **one route set**: the same route ids with the same route definitions
(the manifest's route hash, else the records' own). DS and SR over other routes measure something else,
so a mix is refused (:class:`RunError` naming both results files) rather than averaged or put side by side.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cmudrive.bench.records import RouteResult, record_stem
from cmudrive.bench.report import ResultsError, _read_json, _records, load_results
from cmudrive.provenance import json_sha256, settings_diff

RESULTS = "results.json"
MANIFEST = "run.json"
BUNDLED = {
    "cmudrive.agents.expert:ExpertAgent": "expert",
    "cmudrive.agents.autopilot:AutopilotAgent": "autopilot",
    "cmudrive.agents.pid:PidAgent": "pid",
    "cmudrive.model.agent:V2VVLAAgent": "v2v-vla",
    "cmudrive.model.agent:V2VVLABaselineAgent": "v2v-vla-baseline",
    "cmudrive.leaderboard.adapter:LeaderboardAgent": "leaderboard",
}  # class path -> the short name `cmudrive eval --agent` takes (agents.base.BUNDLED_AGENTS, reversed)


class RunError(ResultsError):
    """Runs that cannot be compared, or a path that is not a run; the message names the file."""


@dataclass
class Run:
    """One evaluation run: its records and what produced it."""

    path: Path  # the run folder (or the results file when given a file)
    results_file: Path  # the file the records were read from
    routes: list[RouteResult]
    manifest: dict[str, Any] | None  # run.json, None for runs written before manifests
    num_expected: int | None  # routes of the route file (summary.num_expected), None when unknown

    @property
    def setup(self) -> dict[str, Any]:
        return dict(self.manifest["setup"]) if self.manifest else {}

    @property
    def agent(self) -> str:
        """The agent's short name (``expert``) or class path; ``?`` without a manifest."""
        spec = str(self.setup.get("agent", "?"))
        return BUNDLED.get(spec, spec)

    @property
    def seed(self) -> int | None:
        seed = self.setup.get("seed")
        return seed if isinstance(seed, int) else None

    @property
    def route_set(self) -> str:
        """What identifies the routes: the manifest's hash over (id, route hash), else the records' ids and
        route hashes."""
        runs = self.manifest.get("runs") if self.manifest else None
        if isinstance(runs, list) and runs and isinstance(runs[-1], dict):
            routes = runs[-1].get("routes")
            if isinstance(routes, dict) and isinstance(routes.get("sha256"), str):
                return str(routes["sha256"])
        return json_sha256(
            sorted((r.route_id, (r.provenance or {}).get("route_sha256")) for r in self.routes)
        )

    @property
    def route_file(self) -> str | None:
        runs = self.manifest.get("runs") if self.manifest else None
        if isinstance(runs, list) and runs and isinstance(runs[-1], dict):
            routes = runs[-1].get("routes")
            if isinstance(routes, dict) and isinstance(routes.get("file"), str):
                return str(routes["file"])
        return None

    @property
    def group_key(self) -> str:
        """Equal for runs whose setups differ at most in the seed."""
        if not self.manifest:
            return f"no manifest: {self.results_file}"
        return json_sha256({k: v for k, v in self.setup.items() if k != "seed"})

    def log_path(self, route_id: str) -> Path | None:
        """The route log ``eval --record`` wrote for ``route_id``, None when there is none."""
        path = self.path / "logs" / f"{record_stem(route_id)}.npz"
        return path if self.path.is_dir() and path.is_file() else None


@dataclass
class RunGroup:
    """Runs of one setup (seeds), in the order given."""

    label: str  # what the report calls it: agent, options, and what tells it from a same-agent group
    runs: list[Run] = field(default_factory=list)

    @property
    def seeds(self) -> list[int | None]:
        return [r.seed for r in self.runs]


def load_run(path: str | Path) -> Run:
    """A run from its folder (``results.json`` and ``run.json`` there; a folder whose ``results.json`` is
    missing but whose ``routes/`` holds records, as a run stopped early leaves it, reads those) or from a
    results file. Raises :class:`RunError` naming the path when it is not one, :class:`ResultsError` for a
    bad record."""
    path = Path(path)
    folder = path if path.is_dir() else path.parent
    data: Any = None
    if path.is_dir() and not (path / RESULTS).is_file():
        if not any((path / "routes").glob("*.json")):
            raise RunError(
                f"{path}: not a run folder (no {RESULTS}, no routes/*.json; cmudrive eval --out writes them)"
            )
        results_file, routes = path / "routes", load_results(path / "routes")
    elif path.is_dir() or path.is_file():
        results_file = path / RESULTS if path.is_dir() else path
        data = _read_json(results_file)
        if not isinstance(data, (dict, list)) or (isinstance(data, dict) and "routes" not in data):
            raise RunError(f"{results_file}: not a results file of cmudrive eval (no 'routes' list)")
        routes = _records(results_file, data)
    else:
        raise RunError(f"{path}: no such run folder or results file")
    manifest = data.get("run") if isinstance(data, dict) else None
    manifest_file = folder / MANIFEST
    if not isinstance(manifest, dict) and manifest_file.is_file():
        manifest = _read_json(manifest_file)
    if manifest is not None and not (isinstance(manifest, dict) and isinstance(manifest.get("setup"), dict)):
        where = manifest_file if manifest_file.is_file() else results_file
        raise RunError(f"{where}: a run manifest without a 'setup' object")
    summary = data.get("summary") if isinstance(data, dict) else None
    expected = summary.get("num_expected") if isinstance(summary, dict) else None
    num_expected = expected if isinstance(expected, int) else None
    return Run(folder, results_file, routes, manifest, num_expected)


def check_route_sets(runs: Sequence[Run]) -> None:
    """Refuse runs of different route sets, or one run given twice (``RunError`` naming the files)."""
    seen: dict[Path, Run] = {}
    for run in runs:
        key = run.results_file.resolve()
        if key in seen:
            raise RunError(f"{run.results_file}: the same run is given twice")
        seen[key] = run
    first = runs[0]
    for run in runs[1:]:
        if run.route_set != first.route_set:
            raise RunError(
                f"{run.results_file} and {first.results_file} are runs of different route sets "
                f"({_describe_routes(run)} against {_describe_routes(first)}): a comparison needs the "
                "same routes; report them separately"
            )


def _describe_routes(run: Run) -> str:
    file = run.route_file
    return f"{len(run.routes)} routes" + (f" of {file}" if file else "")


def group_runs(runs: Sequence[Run]) -> list[RunGroup]:
    """Runs grouped by setup (all but the seed), groups in order of their first run. Labels: the agent and
    its options; where two groups share that, the settings that differ from the first such group's."""
    by_key: dict[str, RunGroup] = {}
    for run in runs:
        by_key.setdefault(run.group_key, RunGroup(label="")).runs.append(run)
    groups = list(by_key.values())
    base = [_base_label(g.runs[0]) for g in groups]
    for i, g in enumerate(groups):
        label = base[i]
        twins = [j for j in range(len(groups)) if base[j] == label]
        if len(twins) > 1 and twins[0] != i:
            label += " [" + _difference(groups[twins[0]].runs[0], g.runs[0]) + "]"
        g.label = label
    return groups


def _base_label(run: Run) -> str:
    if not run.manifest:
        return f"{run.path.name} (no run.json)"
    options = run.setup.get("agent_options") or {}
    shown = ", ".join(f"{k}={v}" for k, v in sorted(options.items()))
    return run.agent + (f" ({shown})" if shown else "")


def _difference(first: Run, other: Run) -> str:
    """The settings ``other``'s setup has other values of than ``first``'s, seed and paths left out."""
    diff = settings_diff(first.setup, other.setup, ignore=("seed", "agent_files.*.path"))
    if not diff:
        return other.path.name
    shown = [f"{key}={value}" for key, _, value in diff[:3]]
    return ", ".join(shown) + (f", +{len(diff) - 3} more" if len(diff) > 3 else "")
