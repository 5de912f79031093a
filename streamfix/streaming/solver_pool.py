"""One pool of window-solver threads per process, shared by every threaded engine.

``serve`` runs one :class:`~streamfix.streaming.engine.StreamEngine` per input stream. With
a solver thread per engine, five streams on one core meant five CPU-bound threads
time-slicing that core and trading the GIL with the input thread: every window took
several times its own solve time to finish, and the live path waited behind them.
One first-in-first-out queue served by as many threads as the process has CPUs solves
windows in the order they were scheduled (the order their frames fall due), each at
full speed, and leaves the input thread a single contender for the GIL per core
(``benchmarks/bench_service.py`` measures both set-ups; ``results/service.json``).

The threads run :data:`SOLVER_NICE` below the process's CPU priority. On a core shared
with the input thread, a live frame that arrives mid-solve otherwise waits for the solver
to use up its time slice: with one body, most of the live path's p99 through the sockets
(``bench_service``). The solver still gets every cycle the input thread leaves.

A task is a plain callable; the engine passes one that solves a window and does its own
book-keeping, and never raises (:meth:`StreamEngine._solve_queued`); a task that does
raise is logged and the thread goes on. The threads are
daemons: they never keep a process alive, and a process that forks gets a new pool.
"""
from __future__ import annotations

import logging
import os
import queue
import threading
from typing import Callable

__all__ = ["SolverPool", "shared_pool", "pool_size", "SOLVER_NICE", "lower_priority"]

_log = logging.getLogger(__name__)

SOLVER_NICE = 10
"""How much lower (nice increment) window solvers run than the service's input thread:
the pool's threads here and the children of :mod:`~streamfix.streaming.solver_process`.
The live path is the service's input thread; at equal priority a frame waits for a solve
to use up its time slice."""


def lower_priority(increment: int = SOLVER_NICE) -> None:
    """Lower the calling thread's CPU priority by ``increment`` (Linux: niceness is per
    thread); a no-op where the platform has no per-thread priority."""
    try:
        tid = threading.get_native_id()
        current = os.getpriority(os.PRIO_PROCESS, tid)
        os.setpriority(os.PRIO_PROCESS, tid, min(19, current + int(increment)))
    except (AttributeError, OSError):  # no setpriority (Windows), or refused
        pass


def pool_size() -> int:
    """Threads for the shared pool: the CPUs this process may run on (at least 1)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # no affinity API (macOS, Windows)
        return max(1, os.cpu_count() or 1)


class SolverPool:
    """``threads`` daemon threads taking tasks from one FIFO queue."""

    def __init__(self, threads: int) -> None:
        if threads < 1:
            raise ValueError(f"a solver pool needs at least 1 thread, got {threads}")
        self.threads = int(threads)
        self._tasks: queue.SimpleQueue[Callable[[], None]] = queue.SimpleQueue()
        self._bodies = 0  # ordinals handed out by next_body_ordinal
        self._bodies_lock = threading.Lock()
        self._workers = [
            threading.Thread(target=self._work, name=f"streamfix-solver-{i}", daemon=True) for i in range(self.threads)
        ]
        for worker in self._workers:
            worker.start()

    def submit(self, task: Callable[[], None]) -> None:
        """Queue ``task`` behind every task submitted before it."""
        self._tasks.put(task)

    def next_body_ordinal(self) -> int:
        """0, 1, 2, ... over every engine using this pool: the ordinal that spreads a new
        body's windows over the hop (:func:`streamfix.streaming.bodies.hop_phase`), so the
        bodies of all streams, not each stream's alone, fall due on different frames."""
        with self._bodies_lock:
            self._bodies += 1
            return self._bodies - 1

    @property
    def body_ordinals_issued(self) -> int:
        """How many ordinals :meth:`next_body_ordinal` has handed out."""
        return self._bodies

    @property
    def queued(self) -> int:
        """Tasks submitted and not yet taken by a thread (a snapshot: threads take them meanwhile)."""
        return self._tasks.qsize()

    def _work(self) -> None:
        lower_priority()  # the live path first (module doc)
        while True:
            task = self._tasks.get()
            try:
                task()
            except Exception:  # a task must not take a thread of every engine's pool with it
                _log.exception("window solver pool: a task raised")


_POOL: SolverPool | None = None
_POOL_PID: int | None = None
_POOL_LOCK = threading.Lock()


def shared_pool() -> SolverPool:
    """The process's pool (:func:`pool_size` threads), started on first use; a forked
    child (whose parent's threads did not come along) starts its own."""
    global _POOL, _POOL_PID
    with _POOL_LOCK:
        if _POOL is None or _POOL_PID != os.getpid():
            _POOL = SolverPool(pool_size())
            _POOL_PID = os.getpid()
        return _POOL
