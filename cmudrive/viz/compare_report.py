"""``cmudrive report RUN [RUN...]``: one HTML page that compares evaluation runs, with the PNG charts and
maps it shows written beside it.

The page opens from disk with no network: inline CSS, images by relative path, and one small inline
script that counts the images that loaded (so a broken picture shows in the page and in a headless
browser's DOM). What it holds:

- how the runs were grouped (:mod:`cmudrive.bench.runs`: seeds of one setup) and each run's agent,
  options, seed and code;
- DS, SR, RC and IS overall and per ability, scenario type, CAV count and weather, as mean ± sample
  standard deviation over each group's runs (:mod:`cmudrive.bench.compare`), in tables and bar charts;
- a map per town with a marker per infraction record (:mod:`cmudrive.viz.infraction_map`), the records in
  a table, and per route with a log (``eval --record``) the command that replays it and a link to the log
  (and to the video, when ``cmudrive replay LOG -o LOG.mp4`` has made one beside it).

With one run the single-run outputs of :func:`cmudrive.bench.report.write_report` (``summary.md``, CSV
tables, three charts) are written too, as before. Text from records and manifests is HTML-escaped.
"""

from __future__ import annotations

import csv
import html
import os
import shlex
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from cmudrive.bench.compare import (
    B2D_SUCCESS,
    BREAKDOWNS,
    METRICS,
    OVERALL,
    Comparison,
    Stat,
    as_rows,
    compare,
)
from cmudrive.bench.records import INFRACTION_KEYS
from cmudrive.bench.report import EMPTY, write_report
from cmudrive.bench.runs import Run, RunGroup, check_route_sets, group_runs, load_run
from cmudrive.viz.compare_figures import NO_SCENARIO, infraction_points, write_charts, write_maps
from cmudrive.viz.infraction_map import KIND_MARKERS, group_colour

PAGE = "index.html"
CSV_FILE = "comparison.csv"
VIDEO_SUFFIXES = (".mp4", ".gif")  # a replay video beside a log: LOG with one of these suffixes
OPEN_TABLE_ROWS = 60  # [-] a longer infraction table starts folded
DIGITS = {"infraction_score": 3}  # decimals per metric (others 2)

CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;margin:24px auto;max-width:1320px;
color:#222;padding:0 16px;line-height:1.4}
h1{font-size:1.6em;margin-bottom:.2em}h2{margin-top:1.6em;border-bottom:1px solid #ddd;padding-bottom:4px}
table{border-collapse:collapse;margin:8px 0 16px;font-size:12px}
th,td{border:1px solid #d6d6d6;padding:3px 6px;text-align:right;white-space:nowrap}
th{background:#f2f4f7}td.l,th.l{text-align:left}
tr:nth-child(even) td{background:#fafbfc}.scroll{overflow-x:auto}
.swatch{display:inline-block;width:11px;height:11px;border-radius:2px;margin-right:5px;vertical-align:-1px}
img{max-width:100%;height:auto;border:1px solid #eee;margin:6px 0}
.note{color:#555;font-size:13px}code{background:#f3f3f3;padding:1px 4px;border-radius:3px;font-size:12px}
.empty{color:#999}
"""

IMAGE_CHECK = """<script>
window.addEventListener("load", function () {
  var imgs = document.images, ok = 0;
  for (var i = 0; i < imgs.length; i++) {
    if (imgs[i].complete && imgs[i].naturalWidth > 0) { ok++; }
    else { imgs[i].setAttribute("data-broken", "1"); }
  }
  var p = document.getElementById("image-check");
  p.textContent = ok + " of " + imgs.length + " images loaded";
  p.setAttribute("data-loaded", String(ok));
  p.setAttribute("data-total", String(imgs.length));
});
</script>"""


def esc(value: object) -> str:
    return html.escape(str(value), quote=True)


@dataclass
class Page:
    """What the page is built from: the comparison, and the pictures drawn for it."""

    comparison: Comparison
    out: Path
    charts: dict[str, Path]  # "overall" and breakdown names -> chart
    maps: list[tuple[str, Path | None, str]]  # per town: its name, the map (None: not drawn), a note


def write_comparison(runs: Sequence[str | Path], out_dir: str | Path) -> list[Path]:
    """Compare the runs (folders of ``cmudrive eval`` or results files) into ``out_dir``: ``index.html``,
    its PNGs, ``comparison.csv``, and with one run the single-run report; returns the paths written.
    Raises ``RunError`` / ``ResultsError`` naming the file for a path that is not a run, runs of different
    route sets or a bad record."""
    if not runs:
        raise ValueError("report: give at least one run")
    loaded = [load_run(p) for p in runs]
    check_route_sets(loaded)
    comparison = compare(group_runs(loaded))
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    if len(loaded) == 1:
        written += write_report(loaded[0].results_file, out)
    charts = write_charts(comparison, out)
    maps = write_maps(comparison, out)
    page = Page(comparison, out, charts, maps)
    csv_path = out / CSV_FILE
    with csv_path.open("w", newline="", encoding="utf-8") as f:
        rows = as_rows(comparison)
        w = csv.DictWriter(f, fieldnames=["breakdown", "category", "group", "metric", "mean", "std", "runs"])
        w.writeheader()
        w.writerows(_csv_safe(r) for r in rows)
    html_path = out / PAGE
    html_path.write_text(render_page(page), encoding="utf-8")
    return [html_path, csv_path, *charts.values(), *(m for _, m, _ in maps if m), *written]


def _csv_safe(row: dict[str, object]) -> dict[str, object]:
    from cmudrive.bench.report import _csv_cell

    return {k: _csv_cell(v) for k, v in row.items()}


# ------------------------------------------------------------------------------------------------------
# page


def _cell(stat: Stat | None, metric: str, runs: int) -> str:
    if stat is None:
        return f'<td class="empty">{EMPTY}</td>'
    if metric == "num_routes":  # a count per run: its mean, the spread says nothing
        text = esc(f"{stat.mean:g}")
    else:
        text = esc(stat.text(0 if metric == "num_crashed" else DIGITS.get(metric, 2)))
    if stat.n < runs:
        text += f' <span class="note">({stat.n} of {runs} runs)</span>'
    return f"<td>{text}</td>"


def _swatch(g: int) -> str:
    return f'<span class="swatch" style="background:{group_colour(g)}"></span>'


def _group_heads(comparison: Comparison) -> list[str]:
    return [
        f'<span title="seeds {esc(_seeds(grp))}">{_swatch(g)}{esc(grp.label)}</span> '
        f'<span class="note">({len(grp.runs)} run{"s" if len(grp.runs) > 1 else ""})</span>'
        for g, grp in enumerate(comparison.groups)
    ]


def _seeds(group: RunGroup) -> str:
    return ", ".join("?" if s is None else str(s) for s in group.seeds)


def _runs_section(comparison: Comparison) -> list[str]:
    rows = []
    for g, group in enumerate(comparison.groups):
        for run in group.runs:
            commit = _code(run)
            setup = str((run.manifest or {}).get("setup_sha256", ""))[:12]
            options = ", ".join(f"{k}={v}" for k, v in sorted((run.setup.get("agent_options") or {}).items()))
            rows.append(
                "<tr>"
                f'<td class="l">{_swatch(g)}{esc(group.label)}</td><td class="l">{esc(run.path)}</td>'
                f'<td class="l">{esc(run.agent)}</td><td class="l">{esc(options or EMPTY)}</td>'
                f"<td>{esc(EMPTY if run.seed is None else run.seed)}</td>"
                f"<td>{len(run.routes)} / {esc(EMPTY if run.num_expected is None else run.num_expected)}</td>"
                f'<td class="l"><code>{esc(setup or EMPTY)}</code></td>'
                f'<td class="l"><code>{esc(commit or EMPTY)}</code></td>'
                "</tr>"
            )
    for group in comparison.groups:
        commits = {_code(run) for run in group.runs}
        if len(commits) > 1:
            rows.append(
                f'<tr><td class="l note" colspan="8">note: the runs of {esc(group.label)} ran different code '
                f"({esc(', '.join(sorted(commits)))}); the setup, not the code, groups runs</td></tr>"
            )
    first = comparison.groups[0].runs[0]
    routes = f"{len(first.routes)} routes" + (
        f" of <code>{esc(first.route_file)}</code>" if first.route_file else ""
    )
    return [
        "<h2>Runs and how they were grouped</h2>",
        '<p class="note">Runs whose <code>run.json</code> setups are equal in everything but the seed '
        "(agent, agent options and files, every evaluation setting) form one group, and a group's numbers "
        "are the mean ± sample standard deviation (n - 1) over its runs; a single run shows its value. A run "
        "without <code>run.json</code> is a group of its own. All runs are on one route set "
        f"({routes}); reports of different route sets are refused.</p>",
        '<div class="scroll"><table id="runs"><tr><th class="l">group</th><th class="l">run</th>'
        '<th class="l">agent</th><th class="l">options</th><th>seed</th><th>routes evaluated / expected</th>'
        '<th class="l">setup</th><th class="l">code</th></tr>',
        *rows,
        "</table></div>",
    ]


def _code(run: Run) -> str:
    """The code a run's last invocation ran: its git commit, cut to 10 digits, and whether it was dirty."""
    entries = (run.manifest or {}).get("runs") or [{}]
    last = entries[-1] if isinstance(entries[-1], dict) else {}
    code = last.get("code") or {}
    return str(code.get("git_commit") or "")[:10] + (" (dirty)" if code.get("git_dirty") else "")


def _overall_section(page: Page) -> list[str]:
    c = page.comparison
    sizes = [len(g.runs) for g in c.groups]
    lines = [
        "<h2>Overall</h2>",
        '<div class="scroll"><table id="overall"><tr><th class="l">metric</th>'
        + "".join(f'<th class="l">{h}</th>' for h in _group_heads(c))
        + "</tr>",
    ]
    for metric, label in OVERALL.items():
        if all(c.overall[g][metric] is None for g in range(len(c.groups))):
            continue  # no run has it (the ability mean of a route set without scenarios)
        cells = "".join(_cell(c.overall[g][metric], metric, sizes[g]) for g in range(len(c.groups)))
        lines.append(f'<tr data-metric="{metric}"><td class="l">{esc(label)}</td>{cells}</tr>')
    lines.append("</table></div>")
    lines.append(
        '<p class="note">DS, SR and RC count missing routes as 0 (over the route file\'s routes, as in '
        "<code>results.json</code>); IS is the mean over the routes evaluated.</p>"
    )
    lines.append(_img(page, "overall", "DS, SR, RC and IS per group"))
    lines += [
        "<h3>Each run</h3>",
        '<div class="scroll"><table id="per-run"><tr><th class="l">group</th><th>seed</th>',
    ]
    lines[-1] += "".join(f"<th>{esc(METRICS[m])}</th>" for m in METRICS) + "</tr>"
    for g, group in enumerate(c.groups):
        for run, values in zip(group.runs, c.per_run_overall[g], strict=True):
            cells = "".join(_cell(_one(values.get(m)), m, 1) for m in METRICS)
            lines.append(
                f'<tr><td class="l">{_swatch(g)}{esc(group.label)}</td>'
                f"<td>{esc(EMPTY if run.seed is None else run.seed)}</td>{cells}</tr>"
            )
    lines.append("</table></div>")
    return lines


def _one(value: float | int | None) -> Stat | None:
    return None if value is None else Stat(float(value), None, 1)


def _img(page: Page, name: str, alt: str) -> str:
    path = page.charts.get(name)
    if path is None:
        return ""
    return f'<img src="{esc(path.name)}" alt="{esc(alt)}">'


def _breakdown_section(page: Page, name: str, title: str) -> list[str]:
    c = page.comparison
    cats = c.categories[name]
    lines = [f"<h2>Per {esc(title)}</h2>"]
    if not cats:
        return [
            *lines,
            f'<p class="note">No route of these runs falls in any {esc(title)} group (left out).</p>',
        ]
    metrics = [*METRICS, *([B2D_SUCCESS] if name == "ability" else []), "num_routes"]
    sizes = [len(g.runs) for g in c.groups]
    head = "".join(f'<th colspan="{len(metrics)}" class="l">{h}</th>' for h in _group_heads(c))
    sub = "".join(f"<th>{esc(_short(m))}</th>" for _ in c.groups for m in metrics)
    lines += [
        _img(page, name, f"DS and SR per {title}"),
        f'<div class="scroll"><table id="by-{esc(name)}">',
        f'<tr><th class="l" rowspan="2">{esc(title)}</th>{head}</tr>',
        f"<tr>{sub}</tr>",
    ]
    for cat in cats:
        cells = ""
        for g, cell in enumerate(c.scores[name][cat]):
            cells += "".join(_cell(cell.get(m) if cell else None, m, sizes[g]) for m in metrics)
        lines.append(
            f'<tr data-category="{esc(cat)}"><td class="l">{esc(cat or NO_SCENARIO)}</td>{cells}</tr>'
        )
    lines.append("</table></div>")
    if name == "ability":
        lines.append(
            '<p class="note">B2D success: Bench2Drive\'s success rule (completion 100, no infraction but '
            "min-speed records; Traffic_Signs: past the first junction without a red light or stop).</p>"
        )
    return lines


def _short(metric: str) -> str:
    return {"num_routes": "routes", B2D_SUCCESS: "B2D success (%)"}.get(metric, METRICS.get(metric, metric))


def _infraction_section(page: Page) -> list[str]:
    lines = ["<h2>Where infractions happened</h2>"]
    lines.append(
        '<p class="note">One marker per infraction record at the CAV\'s centre (map frame); colour: group, '
        'shape: kind. Min-speed records (hollow triangles, "too slow") cost nothing.</p>'
    )
    for town, path, note in page.maps:
        lines.append(f'<h3>{esc(town)}</h3><p class="note">{esc(note)}</p>')
        if path is not None:
            lines.append(f'<img class="map" src="{esc(path.name)}" alt="infractions in {esc(town)}">')
    rows = _infraction_rows(page)
    fold = "" if len(rows) <= OPEN_TABLE_ROWS else " (folded)"
    lines += [
        f"<details{' open' if not fold else ''}><summary>{len(rows)} infraction records{fold}</summary>",
        '<div class="scroll"><table id="infractions"><tr><th class="l">group</th><th>seed</th>'
        '<th class="l">route</th><th class="l">CAV</th><th class="l">kind</th><th>t [s]</th><th>x [m]</th>'
        '<th>y [m]</th><th class="l">message</th></tr>',
        *rows,
        "</table></div></details>",
    ]
    return lines


def _infraction_rows(page: Page) -> list[str]:
    rows = []
    for g, group in enumerate(page.comparison.groups):
        for run in group.runs:
            for r in run.routes:
                for c in r.cavs:
                    for key in INFRACTION_KEYS:
                        for i in c.infractions.get(key, []):
                            rows.append(
                                f'<tr><td class="l">{_swatch(g)}{esc(group.label)}</td>'
                                f"<td>{esc(EMPTY if run.seed is None else run.seed)}</td>"
                                f'<td class="l">{esc(r.route_id)}</td><td class="l">{esc(c.cav_id)}</td>'
                                f'<td class="l">{esc(KIND_MARKERS.get(key, ("", key))[1])}</td>'
                                f"<td>{i.time:.1f}</td><td>{i.x:.1f}</td><td>{i.y:.1f}</td>"
                                f'<td class="l">{esc(i.message)}</td></tr>'
                            )
    return rows


def _replay_section(page: Page) -> list[str]:
    lines = ["<h2>Replays</h2>"]
    rows = []
    for g, group in enumerate(page.comparison.groups):
        for run in group.runs:
            for r in run.routes:
                log = run.log_path(r.route_id)
                if log is None:
                    continue
                count = sum(len(v) for c in r.cavs for v in c.infractions.values())
                video = next(
                    (log.with_suffix(s) for s in VIDEO_SUFFIXES if log.with_suffix(s).is_file()), None
                )
                command = (
                    f"cmudrive replay {shlex.quote(str(log))} -o {shlex.quote(str(log.with_suffix('.mp4')))}"
                )
                watch = f'<a href="{esc(_href(page.out, video))}">{esc(video.name)}</a>' if video else EMPTY
                rows.append(
                    f'<tr><td class="l">{_swatch(g)}{esc(group.label)}</td>'
                    f"<td>{esc(EMPTY if run.seed is None else run.seed)}</td>"
                    f'<td class="l">{esc(r.route_id)}</td><td>{r.driving_score:.2f}</td><td>{count}</td>'
                    f'<td class="l"><a href="{esc(_href(page.out, log))}">{esc(log.name)}</a></td>'
                    f'<td class="l">{watch}</td><td class="l"><code>{esc(command)}</code></td></tr>'
                )
    if not rows:
        return [
            *lines,
            '<p class="note">No route logs: run <code>cmudrive eval ... --record</code> to get a replayable '
            "log per route.</p>",
        ]
    return [
        *lines,
        '<p class="note">Route logs of <code>eval --record</code>. The command renders the route as a BEV '
        "video beside its log, where this page links it once made.</p>",
        '<div class="scroll"><table id="replays"><tr><th class="l">group</th><th>seed</th>'
        '<th class="l">route</th><th>DS</th><th>infraction records</th><th class="l">log</th>'
        '<th class="l">video</th><th class="l">command</th></tr>',
        *rows,
        "</table></div>",
    ]


def _href(out: Path, target: Path) -> str:
    """A link from the page to ``target``: relative, so that the page and the runs move together."""
    return Path(os.path.relpath(target.resolve(), out.resolve())).as_posix()


def render_page(page: Page) -> str:
    c = page.comparison
    nruns = sum(len(g.runs) for g in c.groups)
    body = [
        "<h1>cmudrive report</h1>",
        f'<p class="note">{nruns} run{"s" if nruns > 1 else ""} in {len(c.groups)} group'
        f"{'s' if len(c.groups) > 1 else ''}. Categories no run has are left out; "
        f"{EMPTY} marks a category a group's runs do not have.</p>",
        *_runs_section(c),
        *_overall_section(page),
    ]
    for b in BREAKDOWNS:
        body += _breakdown_section(page, b.name, b.title)
    body += [*_infraction_section(page), *_replay_section(page)]
    body.append('<p id="image-check" class="note">images: not checked (scripts off)</p>')
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        "<title>cmudrive report</title>"
        f"<style>{CSS}</style></head><body>\n" + "\n".join(body) + f"\n{IMAGE_CHECK}\n</body></html>\n"
    )


__all__ = ["PAGE", "Page", "Run", "infraction_points", "render_page", "write_charts", "write_comparison"]
