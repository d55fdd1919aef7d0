"""A CAV whose pose leaves its lane must not take SUMO down: with moveToXY(keepRoute=2) SUMO's copy left
the network and libsumo 1.28's sublane model segfaulted in the next step (cmudrive220's
YieldToEmergencyVehicle_3 on Town06: two PID CAVs, no traffic, a crash at t = 10.5 s). The route runs in a
child process, so a segfault fails this test instead of killing the test run."""

from __future__ import annotations

import subprocess
import sys
import textwrap

SCRIPT = textwrap.dedent(
    """
    import dataclasses
    from cmudrive.agents import PidAgent
    from cmudrive.bench import EvalConfig, evaluate_route
    from cmudrive.bench.routes import read_routes
    from cmudrive.maps.cache import assets_dir
    from cmudrive.sim.background import BackgroundConfig

    specs, _ = read_routes(assets_dir().parent / "routes" / "cmudrive220.xml", strict=False)
    spec = next(s for s in specs if s.id == "YieldToEmergencyVehicle_3")
    cavs = tuple(dataclasses.replace(spec.cavs[i], id=k) for k, i in enumerate((1, 2)))
    spec = dataclasses.replace(spec, cavs=cavs, scenarios=())
    empty = BackgroundConfig(vehicles=0, pedestrians=0)
    result = evaluate_route(spec, PidAgent, EvalConfig(tick_cap=300, background=empty))
    print(result.error is None, result.ticks)
    """
)


def test_a_cav_drifting_off_its_lane_at_speed_does_not_crash_sumo() -> None:
    done = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    no_error, ticks = done.stdout.split()[-2:]
    assert no_error == "True"
    assert int(ticks) >= 220  # past the tick (210) where SUMO crashed
