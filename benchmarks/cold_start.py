"""Cold and warm start of a route: the time to its first tick with an empty and with a filled compile cache.

    python benchmarks/cold_start.py [--route Accident_0] [--agent expert] [--hogs 2]

Each start is a fresh Python process (as each route's worker is) that runs one route of the main job
(cmudrive44) for ``--ticks`` ticks and reports, from the process's start: imports done, the world and the
agent set up (``setup`` entered), and the first tick done; plus how long numba spent in its compiler (it
compiles, loads or saves kernels there) and how many kernels it compiled. The first start gets an empty
``NUMBA_CACHE_DIR``, the second the cache the first one filled. ``--hogs N`` runs N CPU-bound processes
beside both (the busy laptop of a first run). Since ``cmudrive.bench.compile_clock``, compile time is not on
the agent's step clock; this shows how much of it there is.

The script imports cmudrive from the checkout it lives in (not whichever copy is installed).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_START = """
import time
t0 = time.perf_counter()
import json, sys
from pathlib import Path
from numba.core import event
from cmudrive.agents import load_agent_class
from cmudrive.bench import EvalConfig, evaluate_route
from cmudrive.bench.evaluator import RouteHooks
from cmudrive.bench.routes import read_routes
marks = {"imports": time.perf_counter() - t0}
compiled, locked, since = [], [0.0], [0.0]

class Count(event.Listener):
    def on_start(self, ev):
        compiled.append(1)

    def on_end(self, ev):
        pass

class Lock(event.Listener):
    depth = 0

    def on_start(self, ev):
        self.depth += 1
        if self.depth == 1:
            since[0] = time.perf_counter()

    def on_end(self, ev):
        self.depth -= 1
        if self.depth == 0:
            locked[0] += time.perf_counter() - since[0]

def phase(name):
    if name == "setup" and "setup" not in marks:
        marks["setup"] = time.perf_counter() - t0

def tick(n):
    if n == 1:
        marks["first tick"] = time.perf_counter() - t0

route_file, route_id, agent, ticks = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
spec = next(s for s in read_routes(Path(route_file)) if s.id == route_id)
hooks = RouteHooks(tick=tick, phase=phase)
with event.install_listener("numba:compile", Count()), event.install_listener("numba:compiler_lock", Lock()):
    result = evaluate_route(spec, load_agent_class(agent), EvalConfig(tick_cap=ticks), hooks=hooks)
marks["route"] = time.perf_counter() - t0
out = {"marks": marks, "compiled": len(compiled), "compiler_s": locked[0], "status": result.status}
print(json.dumps(out))
"""


def start(cache: str, args: argparse.Namespace) -> dict:
    routes = ROOT / "cmudrive" / "assets" / "routes" / "cmudrive44.xml"
    env = {**os.environ, "NUMBA_CACHE_DIR": cache, "PYTHONPATH": str(ROOT)}
    cmd = [sys.executable, "-c", _START, str(routes), args.route, args.agent, str(args.ticks)]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True)
    return json.loads(done.stdout.splitlines()[-1])


def main() -> None:
    raw = argparse.RawDescriptionHelpFormatter
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=raw)
    parser.add_argument("--route", default="Accident_0", help="a route id of cmudrive44")
    parser.add_argument("--agent", default="expert")
    parser.add_argument("--ticks", type=int, default=20)
    parser.add_argument("--hogs", type=int, default=0, help="CPU-bound processes running beside")
    args = parser.parse_args()
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.hogs)]
    try:
        with tempfile.TemporaryDirectory() as cache:
            rows = [("cold", start(cache, args)), ("warm", start(cache, args))]
    finally:
        for hog in hogs:
            hog.kill()
    print(f"route {args.route}, agent {args.agent}, {args.ticks} ticks, {args.hogs} CPU hogs beside")
    print("| start | imports s | agent made s | first tick s | route s | numba's compiler s | compiled |")
    print("|---|---|---|---|---|---|---|")
    for name, r in rows:
        m = r["marks"]
        print(
            f"| {name} | {m['imports']:.1f} | {m['setup']:.1f} | {m['first tick']:.1f} | {m['route']:.1f} "
            f"| {r['compiler_s']:.1f} | {r['compiled']} |"
        )


if __name__ == "__main__":
    main()
