"""Routes as Ray tasks on a local Ray instance (the executor a cluster would use), same results as local."""

from __future__ import annotations

from pathlib import Path

import pytest

from cmudrive.agents import PidAgent
from cmudrive.bench import EvalConfig, LocalExecutor, RayExecutor, run_evaluation

from .test_evaluator import EMPTY, ring_route

ray = pytest.importorskip("ray", reason="Ray is an optional extra: pip install 'cmudrive[ray]'")


def test_ray_executor_runs_routes_like_the_local_one(tmp_path: Path) -> None:
    routes = [ring_route("a", seed=1), ring_route("b", seed=2)]
    config = EvalConfig(background=EMPTY, tick_cap=200)
    try:
        on_ray = run_evaluation(routes, PidAgent, tmp_path / "ray", RayExecutor(), config)
    finally:
        ray.shutdown()
    local = run_evaluation(routes, PidAgent, tmp_path / "local", LocalExecutor(2), config)
    assert [r["route_id"] for r in on_ray["routes"]] == ["a", "b"]
    for a, b in zip(on_ray["routes"], local["routes"], strict=True):  # routes are deterministic by seed
        assert (a["status"], a["route_completion"], a["driving_score"]) == (
            b["status"],
            b["route_completion"],
            b["driving_score"],
        )
    assert (tmp_path / "ray" / "routes" / "a.json").is_file()
