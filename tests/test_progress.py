"""The run progress record behind the ETA and simulated-time ratio of ``cmudrive eval`` / ``data collect``."""

from __future__ import annotations

import pytest

from cmudrive.bench.progress import RunProgress, clock


def test_run_progress_eta_and_simulated_time_ratio() -> None:
    p = RunProgress(total=4, start=100.0, dt=0.05)
    p.tick("a", 200)
    assert p.eta(110.0) is None and p.ratio(110.0) == pytest.approx(1.0)  # 10 s simulated in 10 s
    p.finish("a", 400)
    p.tick("b", 100)
    assert p.eta(120.0) == pytest.approx(60.0)  # 20 s for 1 route, 3 to go
    assert p.ratio(120.0) == pytest.approx(25.0 / 20.0)
    assert p.describe(120.0) == "1/4 routes, 0:20 elapsed, ETA 1:00, 1.25 simulated s per wall s"
    assert clock(3725.0) == "1:02:05"
