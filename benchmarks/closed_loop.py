"""Closed-loop speed of the V2V-VLA agent: one 16-CAV route of ``cmudrive44``, wall time per tick in the
agent and in the simulator (traffic, scenarios, criteria, camera and occupancy for every CAV), against
real time (20 ticks per second of simulated time).

    python benchmarks/closed_loop.py [--agent v2v-vla|v2v-vla-baseline|expert] [--checkpoint DIR]
                                     [--route InterurbanAdvancedActorFlow_0] [--ticks 400] [--threads 2]
                                     [--language-every 5] [--agent-option camera_jpeg=false]

Runs in this process, as a ``cmudrive eval`` worker does (the same environment: ``--threads`` intra-op
threads, OpenMP threads that spin briefly then sleep). The first ``--skip`` ticks (JIT warm-up, the
first language tick) are left out. Prints the agent's and the simulator's median and mean milliseconds
per tick, the real-time factor (simulated seconds per wall second) and, last, ``ticks_per_s=<value>``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from typing import Any


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--agent", default="v2v-vla")
    parser.add_argument("--checkpoint", default=None, help="default: the committed checkpoint")
    parser.add_argument("--route", default="InterurbanAdvancedActorFlow_0", help="a cmudrive44 route id")
    parser.add_argument("--ticks", type=int, default=400)
    parser.add_argument("--skip", type=int, default=20)
    parser.add_argument("--threads", type=int, default=os.cpu_count() or 1)
    parser.add_argument(
        "--language-every", type=int, default=None, help="V2V-VLA agents: ticks between language ticks"
    )
    parser.add_argument(
        "--agent-option", action="append", default=[], help="KEY=VALUE for the agent's constructor (JSON)"
    )
    args = parser.parse_args()
    from cmudrive.bench.runner import (  # loads no OpenMP runtime yet
        OMP_SPIN_COUNT,
        WORKER_THREAD_VARIABLES,
        limit_numba_threads,
    )

    for name in WORKER_THREAD_VARIABLES:  # as cmudrive.bench.runner's workers
        os.environ[name] = str(args.threads)
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    os.environ.setdefault("GOMP_SPINCOUNT", str(OMP_SPIN_COUNT))
    limit_numba_threads()  # starts numba's OpenMP runtime: after its settings

    from cmudrive.agents.base import agent_factory, load_agent_class
    from cmudrive.bench.evaluator import EvalConfig, RouteHooks, evaluate_route
    from cmudrive.bench.routes import read_routes
    from cmudrive.cli.common import routes_path

    specs = {s.id: s for s in read_routes(routes_path("cmudrive44"))}
    if args.route not in specs:
        sys.exit(f"route {args.route!r} is not in cmudrive44")
    spec = specs[args.route]
    options: dict[str, Any] = {"checkpoint": args.checkpoint} if args.checkpoint else {}
    if args.language_every is not None:
        options["language_every"] = args.language_every
    for item in args.agent_option:
        key, _, value = item.partition("=")
        try:
            options[key] = json.loads(value)
        except json.JSONDecodeError:
            options[key] = value
    factory = agent_factory(load_agent_class(args.agent), options)

    spent = {"agent": [0.0] * (args.ticks + 1), "sim": [0.0] * (args.ticks + 1)}
    state: dict[str, Any] = {"phase": "setup", "since": time.perf_counter(), "tick": 0}

    def phase(name: str) -> None:
        now = time.perf_counter()
        if state["phase"] in spent:
            spent[str(state["phase"])][int(state["tick"])] += now - float(state["since"])
        state["phase"], state["since"] = name, now

    def tick(t: int) -> None:
        phase(str(state["phase"]))  # book the running phase to the tick it belongs to
        state["tick"] = min(t + 1, args.ticks)

    result = evaluate_route(
        spec, factory, EvalConfig(tick_cap=args.ticks), hooks=RouteHooks(tick=tick, phase=phase)
    )
    n = min(result.ticks, args.ticks)
    if n <= args.skip:
        sys.exit(f"the route ended after {result.ticks} ticks, not more than --skip {args.skip}")
    agent = [s * 1e3 for s in spent["agent"][args.skip : n]]
    sim = [s * 1e3 for s in spent["sim"][args.skip : n]]
    total = [a + s for a, s in zip(agent, sim, strict=True)]
    mean = statistics.mean(total)
    print(
        f"{args.agent} on {spec.id} ({len(spec.cavs)} CAVs), ticks {args.skip}-{n}, {args.threads} threads"
        + (f", language every {args.language_every} ticks" if args.language_every else "")
        + "".join(f", {item}" for item in args.agent_option)
    )
    for name, values in (("agent", agent), ("simulator", sim)):
        median, average = statistics.median(values), statistics.mean(values)
        print(f"  {name:<10} median {median:6.1f} ms, mean {average:6.1f} ms per tick")
    print(
        f"  total      mean {mean:6.1f} ms per tick = {50.0 / mean:.2f}x real time (50 ms of simulated time)"
    )
    print(f"ticks_per_s={1e3 / mean:.1f}")


if __name__ == "__main__":
    main()
