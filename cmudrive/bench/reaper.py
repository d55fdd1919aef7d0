"""Route workers die with their run, and take every process they started with them (Linux).

A worker (``runner._worker``) calls :func:`hold_descendants` at its start, which

1. makes it a session and process-group leader (``os.setsid``): the agent's children share its group,
   a terminal's Ctrl-C reaches the parent only, which stops the workers itself, and a worker that prints
   is never stopped for writing to a terminal it does not own;
2. makes it a *child subreaper* (``prctl(PR_SET_CHILD_SUBREAPER)``): a descendant whose own parent
   exits (a daemon that double-forked, a child that called ``setsid`` and left the group) is re-parented
   to the worker rather than to init, so every process the route started stays below the worker in the
   process tree for as long as the worker lives;
3. starts a **guard**: this file run as a script, a small separate Python process that polls the worker's
   parent. When that is no longer the run's process (``cmudrive eval`` was SIGKILLed, or the OOM killer
   took it), the guard stops the worker, kills the worker's descendants and the worker, and exits. A
   thread in the worker could not be relied on for this (an agent hung in native code may hold the GIL);
   ``PR_SET_PDEATHSIG`` on the worker would kill the worker at once, but leave its descendants to init,
   out of reach. The guard dies with the worker (its own ``PR_SET_PDEATHSIG``).

When a route ends, the worker kills whatever is left below it before it exits. When the parent kills a
worker (hung, or the run stops) it kills the worker's whole tree with :func:`kill_tree`, then the
worker's process group. multiprocessing's resource tracker, which the parent starts (the queue's
semaphore) and whose pipe every worker and every forked descendant holds, exits once they are all gone.

Left out: a descendant that left the worker's process group *and* outlived a worker that died on its
own (``os._exit``, a segfault): with its subreaper gone it belongs to init, and nothing names it as the
route's any more. Orphans the worker adopted and that exit during the route stay zombies until the route
ends (reaping them would take exit statuses the agent's own ``subprocess`` calls wait for). Elsewhere than
Linux (no ``/proc``, no ``prctl``) only the process group is killed.

This module imports the standard library only: the guard starts without the simulator's imports.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import subprocess
import sys
import time
from collections.abc import Collection

PR_SET_PDEATHSIG = 1  # prctl options (linux/prctl.h)
PR_SET_CHILD_SUBREAPER = 36
GUARD_POLL = 0.1  # [s] between two looks of the guard at the worker's parent
KILL_TIME = 5.0  # [s] at most spent freezing a tree that keeps forking (then what was found is killed)
PROC = "/proc"
_guard: subprocess.Popen[bytes] | None = None  # this worker's guard (kept: a dropped Popen warns)


def prctl(option: int, value: int) -> bool:
    """``prctl(option, value)``; False where there is no prctl or it fails."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(option, value, 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def hold_descendants(parent: int) -> bool:
    """In a worker: lead a process group, adopt orphaned descendants, start the guard that cleans up
    when ``parent`` dies (module docstring). True when the worker leads its own process group."""
    global _guard
    try:
        os.setsid()
    except OSError:  # a group leader already
        pass
    own_group = os.getpgrp() == os.getpid()
    prctl(PR_SET_CHILD_SUBREAPER, 1)
    if os.path.isdir(PROC):
        try:  # no stdin or stdout; no descriptor of the worker (the queue, the resource tracker's pipe)
            cmd = [sys.executable, "-I", "-S", os.path.abspath(__file__), str(os.getpid()), str(parent)]
            _guard = subprocess.Popen(
                cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, close_fds=True
            )
        except OSError:
            prctl(PR_SET_PDEATHSIG, signal.SIGKILL)  # without a guard, the worker at least dies with the run
    return own_group


def _stat(pid: int | str) -> tuple[str, int] | None:
    """(state letter, parent pid) of a process from /proc, None when it is gone."""
    try:
        with open(f"{PROC}/{pid}/stat", "rb") as fh:
            fields = fh.read().rsplit(b")", 1)[1].split()  # after "pid (command name)"
        return fields[0].decode(), int(fields[1])
    except (OSError, IndexError, ValueError):
        return None


def parent_of(pid: int) -> int | None:
    stat = _stat(pid)
    return None if stat is None or stat[0] in "ZX" else stat[1]


def descendants(root: int) -> list[int]:
    """Living (not zombie) processes below ``root`` in the process tree, parents before children; empty
    without /proc."""
    try:
        pids = [p for p in os.listdir(PROC) if p.isdigit()]
    except OSError:
        return []
    children: dict[int, list[int]] = {}
    for pid in pids:
        stat = _stat(pid)
        if stat is not None and stat[0] not in "ZX":
            children.setdefault(stat[1], []).append(int(pid))
    found, todo = [], [root]
    while todo:
        kids = children.get(todo.pop(), [])
        found += kids
        todo += kids
    return found


def _signal(pid: int, sig: int) -> None:
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.kill(pid, sig)


def kill_tree(root: int, include_root: bool = True, skip: Collection[int] = ()) -> None:
    """SIGKILL every descendant of ``root`` (not those in ``skip``) and, with ``include_root``, ``root``.
    Everything is stopped first (SIGSTOP: a stopped process forks no more and does not exit, so its pid
    stays its own), scanning again until no new process turns up, then killed."""
    if include_root:
        _signal(root, signal.SIGSTOP)
    frozen: list[int] = []
    deadline = time.monotonic() + KILL_TIME
    while time.monotonic() < deadline:
        new = [p for p in descendants(root) if p not in skip and p not in frozen]
        if not new:
            break
        for pid in new:
            _signal(pid, signal.SIGSTOP)
        frozen += new
    for pid in frozen:
        _signal(pid, signal.SIGKILL)
    if include_root:
        _signal(root, signal.SIGKILL)


def kill_group(pgid: int) -> None:
    """SIGKILL the process group ``pgid`` (never this process's own)."""
    if pgid <= 1 or pgid == os.getpgrp():
        return
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(pgid, signal.SIGKILL)


def guard(worker: int, parent: int) -> None:
    """The guard's loop: while ``worker`` is the child of ``parent``, wait; when the parent is gone, kill
    the worker and everything below it. Ends with the worker (PR_SET_PDEATHSIG) in any case."""
    prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() != worker:  # the worker is gone already
        return
    while parent_of(worker) == parent:
        time.sleep(GUARD_POLL)
    if parent_of(worker) is not None:
        kill_tree(worker, skip={os.getpid()})


if __name__ == "__main__":
    guard(int(sys.argv[1]), int(sys.argv[2]))
