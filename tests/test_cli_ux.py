"""The command line as a leaderboard user meets it: route sets and subsets by name, agent classes from the
current folder with clear errors, output that reads in a terminal and in a log, and help texts."""

from __future__ import annotations

import io
import json
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
import typer
from rich.console import Console
from typer.testing import CliRunner

from cmudrive.bench.route_sets import ROUTE_SET_PURPOSES, route_set_names
from cmudrive.bench.routes import read_routes, write_routes
from cmudrive.cli import app, common, results

REPO = Path(__file__).resolve().parents[1]
SMOKE = REPO / "cmudrive" / "assets" / "routes" / "smoke.xml"


def flat(text: str) -> str:
    """Help text without rich's box characters and line breaks."""
    return re.sub(r"[\s│╭╮╰╯─]+", " ", text)


# ---- subsets ---------------------------------------------------------------------------------------


def test_eval_subset_checks_only_the_picked_routes(tmp_path: Path) -> None:
    """An invalid route outside the subset does not refuse the run; index 1 is the second route of the file
    even though the first one cannot be read."""
    specs = read_routes(SMOKE)
    write_routes(specs[:2], tmp_path / "r.xml")
    text = (tmp_path / "r.xml").read_text().replace('weather="ClearNoon"', 'weather="Sunny"', 1)
    (tmp_path / "r.xml").write_text(text)
    _, picked = common.read_specs(str(tmp_path / "r.xml"), None, refuse_invalid=True, subset="1")
    assert [s.id for s in picked] == ["smoke_01"]
    with pytest.raises(typer.Exit):
        common.read_specs(str(tmp_path / "r.xml"), None, refuse_invalid=True, subset="0-1")
    _, picked = common.read_specs("smoke", None, limit=1, subset="2-3")
    assert [s.id for s in picked] == ["smoke_02"]


@pytest.mark.parametrize("command", [["eval"], ["data", "collect"]])
def test_cli_subset_errors_name_the_route(command: list[str], tmp_path: Path) -> None:
    args = [*command, "--routes", "smoke", "--routes-subset", "smoke_0,smoke_03", "--out", str(tmp_path)]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 1
    assert "no route 'smoke_0'" in result.output and "did you mean 'smoke_03'" in result.output


# ---- route sets ----------------------------------------------------------------------------------


def test_cli_set_typo_lists_the_sets(tmp_path: Path) -> None:
    result = CliRunner().invoke(app, ["eval", "--routes", "cmudrive4", "--out", str(tmp_path)])
    assert result.exit_code == 1
    assert "did you mean 'cmudrive44'" in result.output and "training" in result.output


def test_routes_list_shows_every_committed_set_with_its_purpose() -> None:
    assert set(route_set_names()) == set(ROUTE_SET_PURPOSES)  # a new set needs a purpose line
    result = CliRunner().invoke(app, ["routes", "list"])
    assert result.exit_code == 0, result.output
    rows = {line.split("│")[1].strip(): line for line in result.output.splitlines() if line.count("│") > 3}
    assert set(route_set_names()) <= set(rows)
    assert " 220 " in rows["cmudrive220"] and " 4 " in rows["smoke"] and " 132 " in rows["training"]
    assert "data collection" in rows["training"]


# ---- output ----------------------------------------------------------------------------------------


def merged_with_a_long_reason() -> dict[str, object]:
    cavs = [
        {"cav_id": f"cav{i}", "status": "Failed - Agent got blocked", "infractions": {"red_light": [{}]}}
        for i in range(8)
    ]
    route = {
        "route_id": "BlockedIntersection_2",
        "scenario_type": "BlockedIntersection",
        "town": "Town03",
        "weather": "HardRainNoon",
        "num_cavs": 8,
        "status": "Failed - Agent got blocked",
        "route_completion": 12.5,
        "infraction_score": 0.7,
        "driving_score": 8.75,
        "success": False,
        "cavs": cavs,
    }
    scores = {"driving_score": 8.75, "success_rate": 0.0}
    summary = {"driving_score": 8.75, "success_rate": 0.0, "num_routes": 1, "by_scenario_type": {}}
    summary["by_scenario_type"] = {"BlockedIntersection": scores}
    return {"routes": [route], "summary": summary}


def test_results_in_a_log_are_plain_lines_with_the_whole_reason(capsys: pytest.CaptureFixture[str]) -> None:
    results.print_results(merged_with_a_long_reason())
    out = capsys.readouterr().out
    line = next(x for x in out.splitlines() if x.startswith("route BlockedIntersection_2 "))
    fields = "Town03, HardRainNoon, 8 CAVs, Failed - Agent got blocked, RC 12.5, IS 0.700, DS 8.8"
    assert f"(BlockedIntersection): {fields}" in line
    assert line.endswith("; ".join(f"cav{i}: got blocked, red_light" for i in range(8)))
    assert "…" not in out and "┃" not in out


def test_progress_in_a_terminal_shows_eta_and_simulated_time_ratio(monkeypatch: pytest.MonkeyPatch) -> None:
    buffer = io.StringIO()
    monkeypatch.setattr(common, "console", Console(file=buffer, force_terminal=True, width=160))
    with common.route_progress(Path("x.xml"), 2, 100) as (on_progress, done):
        on_progress("r0", 20)
        done("r0", 60)
    out = buffer.getvalue()
    assert "ETA" in out and "simulated s per wall s" in out and "1/2" in out


# ---- help texts ------------------------------------------------------------------------------------


def test_routes_generate_help_lists_its_options() -> None:
    result = CliRunner().invoke(app, ["routes", "generate", "--help"], env={"COLUMNS": "200"})
    assert result.exit_code == 0
    for option in ("--output", "--benchmark", "--seed", "--length", "--id-prefix", "--cavs", "--weather"):
        assert option in result.output


def test_routes_generate_writes_a_file(tmp_path: Path) -> None:
    out = tmp_path / "g.xml"
    result = CliRunner().invoke(app, ["routes", "generate", "-o", str(out), "-s", "1", "-c", "2", "downtown"])
    assert result.exit_code == 0, result.output
    assert [len(s.cavs) for s in read_routes(out)] == [2]
    result = CliRunner().invoke(app, ["routes", "generate", "-o", str(out), "-b", "nope"])
    assert result.exit_code == 1 and "unknown route set 'nope'" in result.output


def test_train_help_shows_percent_signs_once() -> None:
    result = CliRunner().invoke(app, ["train", "--help"], env={"COLUMNS": "200"})
    assert result.exit_code == 0
    text = flat(result.output)
    assert "47 % of the collection" in text and "1.2 % of the collection" in text and "%%" not in text


# ---- the README's agent section, as written -----------------------------------------------------------

# what pip's console script runs (its folder, not the current one, is first on the path)
LAUNCHER = "import sys\nfrom cmudrive.cli import app\nif __name__ == '__main__':\n    sys.exit(app())\n"
TEST_ARGS = ["--tick-cap", "20", "--workers", "1"]  # keep each run to seconds


def readme_agent_section() -> tuple[dict[str, str], list[str]]:
    """The files (python blocks opening with ``# path``) and the literal ``cmudrive eval`` commands (no
    ``...``) of the README's "Evaluate your own agent" section."""
    text = (REPO / "README.md").read_text()
    section = text.split("### Evaluate your own agent", 1)[1].split("\n## ", 1)[0].split("\n### ", 1)[0]
    files = {}
    for block in re.findall(r"```python\n(.*?)```", section, flags=re.S):
        first = block.splitlines()[0]
        if first.startswith("# ") and first.endswith(".py"):
            files[first[2:].strip()] = block
    commands = [
        line.strip()
        for line in section.splitlines()
        if line.startswith("    cmudrive eval") and "..." not in line
    ]
    return files, commands


@pytest.mark.slow
def test_the_readme_agent_section_works_as_written(tmp_path: Path) -> None:
    """Copy-pasted into an empty folder, the README's agent file and commands run (through a launcher like
    the ``cmudrive`` console script: the current folder is not on its path by itself). Each command gets a
    tiny tick cap, and the first route only where it names no subset. The output, not a terminal, is the
    log form: plain progress lines with ETA and simulated-time ratio, no bars."""
    files, commands = readme_agent_section()
    assert "my_pkg/my_agent.py" in files and len(commands) >= 2
    work = tmp_path / "work"
    for name, content in files.items():
        (work / name).parent.mkdir(parents=True, exist_ok=True)
        (work / name).write_text(content)
    launcher = tmp_path / "bin" / "cmudrive"
    launcher.parent.mkdir()
    launcher.write_text(LAUNCHER)
    env = {**__import__("os").environ, "PYTHONPATH": str(REPO)}
    for command in commands:
        args = shlex.split(command, comments=True)[1:]
        args += TEST_ARGS + ([] if "--routes-subset" in args else ["--routes-subset", "0"])
        proc = subprocess.run(
            [sys.executable, str(launcher), *args],
            cwd=work,
            env=env,
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert proc.returncode == 0, f"{command}\n{proc.stdout}\n{proc.stderr}"
        out_dir = work / args[args.index("--out") + 1]
        routes = json.loads((out_dir / "results.json").read_text())["routes"]
        assert len(routes) == 1 and "crashed" not in routes[0]["status"], routes[0]
        assert "ETA" in proc.stdout and "simulated s per wall s" in proc.stdout
        assert "━" not in proc.stdout + proc.stderr and not re.search(r"\b0/1\b", proc.stdout)
        assert f"route {routes[0]['route_id']}: " in proc.stdout
