"""Our compile time is never the agent's: the agent's clock stops while numba compiles or loads a kernel.

The simulator, the sensors and the bundled agents' planners (the expert's forecast, detour and corridor
kernels, the controllers) are numba functions, compiled on first use and cached on disk (``cache=True``).
Which kernel first runs inside an agent's ``run_step`` depends on the agent, and on a cold cache the
expert's first step compiles a dozen of them: about 2 s on an idle 2-core machine, well over the 10 s step
limit on a busy laptop (measured: 10 of 44 main-job routes "Agent crashed" at tick 0 with two CPU-bound
processes beside a fresh clone). Loading them from a warm cache also takes time (LLVM links each one).

Rather than guess every kernel and argument type ahead of the route (a kernel warmed with other dtypes or
array layouts compiles again anyway), the route watches numba's own compiler: numba holds its global
compiler lock, and announces it with the ``numba:compiler_lock`` event, for exactly the span in which it
compiles a kernel, loads one from its cache or saves one to it. While that lock is held anywhere in the
route's process, :class:`CompileClock`

- pauses the agent's wall-clock limit (the ``ITIMER_REAL`` timer behind ``setup_timeout`` and
  ``step_timeout``) and starts it again with the time that was left, so compile time is not charged, and a
  timeout can never interrupt numba half-way through a compile (a half-built library poisoned later
  compiles of the same process: numba's "no compiled object yet for <Library ...>" in CI);
- reports phase ``compile`` to the runner's watchdog, which gives our code its own silence limit and
  blames a worker that dies there on the simulator, not on the agent.

A user's agent that jit-compiles its own numba code is treated the same way: JIT compilation is set-up
work, like loading weights, and its duration says nothing about the agent's per-step speed.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable
from typing import Any

from numba.core import event

COMPILER_LOCK = "numba:compiler_lock"  # numba's event for "the global compiler lock is held"
COMPILE_PHASE = "compile"  # the route phase reported while numba compiles or loads a kernel


class CompileClock(event.Listener):
    """Listener for numba's compiler lock: pause the running ``ITIMER_REAL`` timer and report phase
    :data:`COMPILE_PHASE` through ``enter`` while the lock is held; on release, restart the timer with what
    was left and report the phase that ran before (``current()``). Nested compiles (a kernel that calls
    another) pause once. Use it as a context manager around the route; only the main thread's timer is
    touched (SIGALRM is delivered there)."""

    def __init__(self, enter: Callable[[str], None], current: Callable[[], str]) -> None:
        self._enter, self._current = enter, current
        self._depth = 0
        self._left = 0.0  # [s] of the paused timer, 0 when none was running
        self._resume = "sim"

    def on_start(self, ev: event.Event) -> None:
        self._depth += 1
        if self._depth == 1:
            self._resume = self._current()
            if threading.current_thread() is threading.main_thread():
                self._left = signal.setitimer(signal.ITIMER_REAL, 0.0)[0]
        self._enter(COMPILE_PHASE)  # each nested compile counts as progress for the watchdog

    def on_end(self, ev: event.Event) -> None:
        self._depth -= 1
        if self._depth > 0:
            self._enter(COMPILE_PHASE)
            return
        self._enter(self._resume)
        if self._left > 0.0:
            left, self._left = self._left, 0.0
            signal.setitimer(signal.ITIMER_REAL, left)

    def __enter__(self) -> CompileClock:
        event.register(COMPILER_LOCK, self)
        return self

    def __exit__(self, *exc: Any) -> None:
        event.unregister(COMPILER_LOCK, self)


__all__ = ["COMPILER_LOCK", "COMPILE_PHASE", "CompileClock"]
