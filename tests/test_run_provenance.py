"""What produced an output folder (OUT/run.json, each record's provenance), and --resume refusing another
setup: the agent, its options and checkpoint content, the tick cap, the seed, the V2V link and noise, the
definition of a kept route. Other code only warns; a folder from before manifests resumes with a warning."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import pytest
from typer.testing import CliRunner

from cmudrive.agents import PidAgent
from cmudrive.bench import EvalConfig, LocalExecutor, run_evaluation
from cmudrive.bench import manifest as manifest_module
from cmudrive.bench.manifest import MANIFEST, ResumeWarning, SetupMismatchError, run_setup
from cmudrive.bench.routes import route_sha256, write_routes
from cmudrive.cli import app
from cmudrive.model.agent import DEFAULT_CHECKPOINT
from cmudrive.provenance import ABSENT, code_version, describe_diff, settings_diff, tree_sha256
from cmudrive.sim.background import BackgroundConfig

from .test_evaluator import ring_route

QUICK = EvalConfig(background=BackgroundConfig(vehicles=0, pedestrians=0), tick_cap=3)


class ReadsCheckpoint(PidAgent):
    """The PID agent, made with a checkpoint folder it does not read (its content is what counts)."""

    def __init__(self, checkpoint: str) -> None:
        super().__init__()
        self.checkpoint = checkpoint


AGENT = f"{__name__}:ReadsCheckpoint"


@pytest.fixture(scope="module")
def finished(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder with one finished route of ReadsCheckpoint (checkpoint ``ck/``), tick cap 3."""
    root = tmp_path_factory.mktemp("finished")
    (root / "ck").mkdir()
    (root / "ck" / "weights.bin").write_bytes(b"weights one")
    config = replace(QUICK, agent_options={"checkpoint": str(root / "ck")})
    run_evaluation([ring_route()], AGENT, root / "out", LocalExecutor(1), config)
    return root


def _copy(finished: Path, tmp_path: Path) -> tuple[Path, EvalConfig]:
    """A copy of the finished folder and its checkpoint, and the config that made it (new checkpoint path)."""
    shutil.copytree(finished, tmp_path, dirs_exist_ok=True)
    return tmp_path / "out", replace(QUICK, agent_options={"checkpoint": str(tmp_path / "ck")})


def test_records_and_results_name_what_produced_them(finished: Path) -> None:
    out = finished / "out"
    manifest = json.loads((out / MANIFEST).read_text())
    setup = manifest["setup"]
    assert setup["kind"] == "eval" and setup["agent"] == AGENT and setup["seed"] == 0
    assert setup["config"]["tick_cap"] == 3 and setup["config"]["sensors"]["link"]["drop_rate"] == 0.0
    assert setup["agent_files"]["checkpoint"]["sha256"] == tree_sha256(finished / "ck")
    assert "checkpoint" not in setup["agent_options"]  # compared by content, not by path
    (run,) = manifest["runs"]
    assert run["code"] == code_version() and run["code"]["cmudrive"] == "0.1.0"
    assert run["routes"]["count"] == 1 and run["settings"] == {"executor": "LocalExecutor", "workers": 1}
    record = json.loads((out / "routes" / "ring.json").read_text())
    assert record["provenance"] == {
        "setup_sha256": manifest["setup_sha256"],
        "route_sha256": route_sha256(ring_route()),
        "code": code_version(),
    }
    results = json.loads((out / "results.json").read_text())
    assert results["run"] == manifest and results["routes"][0]["provenance"] == record["provenance"]


def test_checkpoint_content_not_its_path_decides_a_resume(finished: Path, tmp_path: Path) -> None:
    out, config = _copy(finished, tmp_path)  # the same checkpoint content at another path: accepted
    merged = run_evaluation([ring_route()], AGENT, out, LocalExecutor(1), config, resume=True)
    assert [r["route_id"] for r in merged["routes"]] == ["ring"]
    runs = json.loads((out / MANIFEST).read_text())["runs"]
    assert len(runs) == 2 and runs[1]["resume"]
    (tmp_path / "ck" / "weights.bin").write_bytes(b"weights two")
    with pytest.raises(SetupMismatchError, match=r"agent_files\.checkpoint\.sha256: \"[0-9a-f]+\" \(then\)"):
        run_evaluation([ring_route()], AGENT, out, LocalExecutor(1), config, resume=True)
    assert len(json.loads((out / MANIFEST).read_text())["runs"]) == 2  # a refused resume records nothing


def test_a_kept_route_redefined_under_its_id_is_refused(finished: Path, tmp_path: Path) -> None:
    out, config = _copy(finished, tmp_path)
    with pytest.raises(SetupMismatchError, match="routes 'ring' were run on another definition"):
        run_evaluation([ring_route(seed=5)], AGENT, out, LocalExecutor(1), config, resume=True)


def test_other_code_only_warns_and_is_recorded(
    finished: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A fix pulled between a run and its resume: the finished routes are kept, with a warning naming both
    code versions; the manifest lists both."""
    out, config = _copy(finished, tmp_path)
    other = {"cmudrive": "9.9.9", "git_commit": "0123456789abcdef", "git_dirty": False}
    monkeypatch.setattr(manifest_module, "code_version", lambda: other)
    said = r"written by cmudrive 0\.1\.0.*this run is cmudrive 9\.9\.9 \(git 0123456789ab\)"
    with pytest.warns(ResumeWarning, match=said):
        run_evaluation([ring_route()], AGENT, out, LocalExecutor(1), config, resume=True)
    runs = json.loads((out / MANIFEST).read_text())["runs"]
    assert [r["code"]["cmudrive"] for r in runs] == ["0.1.0", "9.9.9"]


def test_a_folder_from_before_manifests_is_resumed_with_a_warning(finished: Path, tmp_path: Path) -> None:
    out, config = _copy(finished, tmp_path)
    (out / MANIFEST).unlink()
    with pytest.warns(ResumeWarning, match="1 records from before runs recorded their setup"):
        run_evaluation([ring_route()], AGENT, out, LocalExecutor(1), config, resume=True)
    (run,) = json.loads((out / MANIFEST).read_text())["runs"]
    assert run["unrecorded_records"] == 1


def test_an_unreadable_manifest_is_refused(finished: Path, tmp_path: Path) -> None:
    out, config = _copy(finished, tmp_path)
    (out / MANIFEST).write_text("{not json")
    with pytest.raises(SetupMismatchError, match="cannot be read"):
        run_evaluation([ring_route()], AGENT, out, LocalExecutor(1), config, resume=True)


def test_cli_resume_with_another_setup_names_each_difference(tmp_path: Path) -> None:
    write_routes([ring_route()], tmp_path / "one.xml")
    base = ["eval", "--routes", str(tmp_path / "one.xml"), "--out", str(tmp_path / "out"), "--workers", "1"]
    runner = CliRunner()
    result = runner.invoke(app, [*base, "--agent", "pid", "--tick-cap", "3"])
    assert result.exit_code == 0, result.output
    record = tmp_path / "out" / "routes" / "ring.json"
    before = record.read_bytes()
    other = ["--agent", "expert", "--tick-cap", "4", "--seed", "2", "--v2v-drop", "0.25", "--resume"]
    result = runner.invoke(app, [*base, *other, "--detection-noise", "0.1", "0.5"])
    assert result.exit_code == 1
    for line in (
        'agent: "cmudrive.agents.pid:PidAgent" (then) -> "cmudrive.agents.expert:ExpertAgent" (now)',
        "config.tick_cap: 3 (then) -> 4 (now)",
        "seed: 0 (then) -> 2 (now)",
        "config.sensors.link.drop_rate: 0.0 (then) -> 0.25 (now)",
        "config.sensors.noise.miss_at_range: 0.0 (then) -> 0.1 (now)",
        "config.sensors.noise.sigma_at_range: 0.0 (then) -> 0.5 (now)",
    ):
        assert line in result.output, result.output
    assert "step_timeout" not in result.output and record.read_bytes() == before
    # the same setup with other workers: nothing left to run, the folder is continued
    result = runner.invoke(app, [*base, "--agent", "pid", "--tick-cap", "3", "--resume", "--workers", "2"])
    assert result.exit_code == 0, result.output
    assert record.read_bytes() == before
    assert len(json.loads((tmp_path / "out" / MANIFEST).read_text())["runs"]) == 2


def test_v2v_vla_without_checkpoint_records_the_committed_one() -> None:
    setup = run_setup("eval", "v2v-vla", EvalConfig())
    assert setup["agent"] == "cmudrive.model.agent:V2VVLAAgent"
    assert setup["agent_files"]["checkpoint"] == {
        "sha256": tree_sha256(DEFAULT_CHECKPOINT),
        "path": str(DEFAULT_CHECKPOINT.resolve()),
    }


def test_settings_diff_names_nested_settings_with_both_values() -> None:
    old = {"a": {"b": 1, "c": [1, 2]}, "gone": True, "files": {"x": {"sha256": "1", "path": "/p"}}}
    new = {"a": {"b": 2, "c": [1, 2]}, "added": None, "files": {"x": {"sha256": "1", "path": "/q"}}}
    diff = settings_diff(old, new, ignore=["files.*.path"])
    assert diff == [("a.b", 1, 2), ("added", ABSENT, None), ("gone", True, ABSENT)]
    assert describe_diff(diff).splitlines() == [
        "  a.b: 1 (then) -> 2 (now)",
        "  added: (not set) (then) -> null (now)",
        "  gone: true (then) -> (not set) (now)",
    ]


def test_content_hashes_ignore_where_things_lie(tmp_path: Path) -> None:
    for name in ("a", "b"):
        (tmp_path / name / "sub").mkdir(parents=True)
        (tmp_path / name / "sub" / "w.bin").write_bytes(b"\x00\x01")
    assert tree_sha256(tmp_path / "a") == tree_sha256(tmp_path / "b")
    (tmp_path / "b" / "sub" / "w.bin").rename(tmp_path / "b" / "w.bin")  # same bytes, other file name
    assert tree_sha256(tmp_path / "a") != tree_sha256(tmp_path / "b")
    route = ring_route()
    moved = replace(route, town_dirs=("/somewhere",))
    assert route_sha256(moved) == route_sha256(route) != route_sha256(ring_route(seed=1))
