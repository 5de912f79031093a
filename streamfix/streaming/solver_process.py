"""A window solver that solves in a child process, so the engine's worker thread only waits.

Why
---
A threaded :class:`~streamfix.streaming.engine.StreamEngine` solves its windows on a
worker thread, but the solver's numpy code holds the GIL for most of its run, so the
``live`` path (on the input thread) waits behind it: with a dozen bodies on one core the
live frames' p99 grows many times over (issue 13). Here the solver
runs in a long-lived child process; the worker thread sends the window to it and waits
on a pipe with the GIL released, and the operating system's scheduler, not the GIL's
switch interval, shares the core between the input thread and the solve.

What is guaranteed
------------------
* One child serves one :class:`ProcessWindowSolver` (one engine), one call at a time,
  in the order the calls are made, with the arguments the in-thread solver would get
  (the solver state is returned to the engine and sent back with the next window, as
  in-thread): the output equals the in-thread solver's bit for bit.
* The child builds the real solver itself from a picklable ``factory`` (default
  :func:`~streamfix.streaming.window_solvers.default_window_solver`), and loads the
  kernels and the prior (the parent's ``--prior``) before it says it is ready.
* A child that dies, or does not answer within ``timeout_s``, fails that window with
  :class:`SolverProcessError` (the engine counts a solver error and keeps the frames);
  it is killed if still alive and a fresh child is started at once for the next window.
  Nothing waits forever.
* ``close()`` (called by ``StreamEngine.close``) stops the child.
* At most one child per CPU solves at a time: the engine calls the solver from the shared
  pool's threads, one per CPU (:mod:`streamfix.streaming.solver_pool`; the other windows wait
  their turn in its queue), and the children run at a lower CPU priority
  (:data:`~streamfix.streaming.solver_pool.SOLVER_NICE`, as the pool's threads): on a
  shared core the input thread's live frames go first, the solves take what is left.

How children start
------------------
Never by a plain ``fork`` of the service (it has threads and ZeroMQ sockets): children
come from multiprocessing's *forkserver*, a clean process started once per service that
imports the solver stack and compiles the kernels (:mod:`._solver_preload`), so a
child forks from it already warm and is ready far sooner (it still loads
the prior and builds its solver). :func:`prepare_solver_process` starts the forkserver and
one spare child before the first frame arrives; the first engine takes that spare.
"""
from __future__ import annotations

import multiprocessing
import os
import signal
import threading
from typing import Any, Callable

from ..allocator import keep_freed_memory
from .solver_api import WindowSolver
from .solver_pool import SOLVER_NICE
from .window_solvers import default_window_solver

__all__ = ["ProcessWindowSolver", "SolverProcessError", "prepare_solver_process", "DEFAULT_TIMEOUT_S"]

DEFAULT_TIMEOUT_S = 5.0
"""Seconds a window may take in the child before it is declared stalled (a window
normally takes a small fraction of this; the engine abandons a stalled window after
``max_clean_delay_s`` on its own, this frees the worker thread for the next one)."""
STARTUP_TIMEOUT_S = 60.0
"""Seconds a new child may take to be ready (a cold forkserver imports and compiles)."""
_PRELOAD = "streamfix.streaming._solver_preload"  # what the forkserver imports (solver stack, kernels)


class SolverProcessError(RuntimeError):
    """The window failed in (or with) its child: ``child_lost`` when the child died, stalled
    or could not start (it is replaced), False when the solver itself raised."""

    def __init__(self, message: str, child_lost: bool = True) -> None:
        super().__init__(message)
        self.child_lost = child_lost


def _child_main(conn: Any, factory: Callable[[], WindowSolver], prior_path: str | None) -> None:
    """The child: build the solver, warm up, say ready, then answer calls until told to stop."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the service's to handle: it closes us
    try:
        os.nice(SOLVER_NICE)  # the live path first (see SOLVER_NICE)
    except OSError:
        pass
    keep_freed_memory()  # the windows are solved here (streamfix.allocator)
    try:
        from ..core import kernels
        from ..prior.runtime import load_default_prior, set_default_prior

        solver = factory()
        kernels.warm_up()
        try:
            if prior_path is not None:
                set_default_prior(prior_path)  # loads it
            else:
                load_default_prior()
        except (FileNotFoundError, ValueError, OSError, KeyError):
            pass  # no usable prior: the solver falls back without it, as in the service's own process
    except BaseException as exc:  # noqa: BLE001 - reported to the parent, which raises it
        conn.send(("failed", f"{type(exc).__name__}: {exc}"))
        return
    conn.send(("ready", os.getpid()))
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):  # the parent is gone
            return
        if msg is None:
            return
        args, kwargs = msg
        try:
            reply = ("ok", solver(*args, **kwargs))
        except Exception as exc:  # noqa: BLE001 - the window fails in the parent, the child lives on
            reply = ("error", f"{type(exc).__name__}: {exc}")
        try:
            conn.send(reply)
        except (EOFError, OSError):  # the parent is gone
            return
        except Exception as exc:  # noqa: BLE001 - a result that does not pickle: the window fails
            conn.send(("error", f"the solver's result could not be sent back: {type(exc).__name__}: {exc}"))


def _context() -> Any:
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload([_PRELOAD])  # no effect once the forkserver runs
    return ctx


def _default_prior_path() -> str | None:
    from ..prior import runtime

    return runtime._DEFAULT_PATH  # what --prior chose in this process; the child uses the same


class _Child:
    """One child process and the parent's end of its pipe."""

    def __init__(self, factory: Callable[[], WindowSolver], prior_path: str | None) -> None:
        ctx = _context()
        self.key = (factory, prior_path)
        self.conn, child_conn = ctx.Pipe(duplex=True)
        self.process = ctx.Process(
            target=_child_main, args=(child_conn, factory, prior_path), name="streamfix-solver", daemon=True
        )
        self.process.start()
        child_conn.close()
        self.ready = False

    @property
    def pid(self) -> int | None:
        return self.process.pid

    def wait_ready(self, timeout_s: float) -> None:
        if self.ready:
            return
        reply = self._receive(timeout_s, "to start")
        if reply[0] != "ready":
            raise SolverProcessError(f"window solver process {self.pid} could not start: {reply[1]}")
        self.ready = True

    def _receive(self, timeout_s: float, doing: str) -> tuple:
        try:
            if not self.conn.poll(timeout_s):  # waits with the GIL released
                raise SolverProcessError(
                    f"window solver process {self.pid} did not answer within {timeout_s:g} s {doing}; "
                    "it is stopped and a new one started"
                )
            return self.conn.recv()
        except (EOFError, OSError) as exc:
            raise self._died(doing) from exc

    def _died(self, doing: str) -> SolverProcessError:
        """The error for a child whose pipe broke ``doing`` something (after reaping it for its exit code)."""
        self.process.join(timeout=1.0)
        return SolverProcessError(
            f"window solver process {self.pid} died {doing} (exit code {self.process.exitcode}); a new one is started"
        )

    def solve(self, args: tuple, kwargs: dict, timeout_s: float) -> Any:
        try:
            self.conn.send((args, kwargs))
        except (EOFError, OSError) as exc:
            raise self._died("before the window") from exc
        status, value = self._receive(timeout_s, "solving a window")
        if status != "ok":
            raise SolverProcessError(f"window solver (process {self.pid}) failed: {value}", child_lost=False)
        return value

    def stop(self, timeout_s: float = 2.0) -> None:
        """Ask the child to exit, then terminate / kill it if it does not."""
        if self.process.is_alive():
            try:
                self.conn.send(None)
            except (EOFError, OSError):
                pass
            self.process.join(timeout_s)
        if self.process.is_alive():
            self.process.kill()
            self.process.join(timeout_s)
        self.conn.close()


_spare_lock = threading.Lock()
_spare: _Child | None = None


def prepare_solver_process(factory: Callable[[], WindowSolver] = default_window_solver,
                           timeout_s: float = STARTUP_TIMEOUT_S) -> Callable[[], None]:
    """Before any frame arrives: start the forkserver (which imports and compiles the solver
    stack) and one child for the first engine to take. Returns at once; call what it returns
    to wait until that child is ready (so the caller can warm its own process meanwhile),
    which raises :class:`SolverProcessError` when the child cannot start."""
    global _spare
    child = _take_spare(factory) or _Child(factory, _default_prior_path())
    with _spare_lock:
        old, _spare = _spare, child
    if old is not None:
        old.stop()

    def wait() -> None:
        try:
            child.wait_ready(timeout_s)
        except SolverProcessError:
            child.stop()
            raise

    return wait


def _take_spare(factory: Callable[[], WindowSolver]) -> _Child | None:
    global _spare
    with _spare_lock:
        child = _spare
        if child is None or child.key != (factory, _default_prior_path()) or not child.process.is_alive():
            return None
        _spare = None
        return child


class ProcessWindowSolver:
    """Window solver protocol (:data:`~streamfix.streaming.solver_api.WindowSolver`) over a
    child process that owns the real solver (see the module docstring for the guarantees).

    ``factory``: a picklable callable returning the real solver (a module-level function);
    it is also called once here, to read the solver's ``wants_history`` /
    ``wants_skeleton`` and its base solver's defaults, which the engine reads.
    ``timeout_s``: the most a window may take in the child.
    """

    def __init__(self, factory: Callable[[], WindowSolver] = default_window_solver, *,
                 timeout_s: float = DEFAULT_TIMEOUT_S, startup_timeout_s: float = STARTUP_TIMEOUT_S) -> None:
        self.factory = factory
        self.timeout_s = float(timeout_s)
        self.startup_timeout_s = float(startup_timeout_s)
        probe = factory()
        self.wants_history = bool(getattr(probe, "wants_history", False))
        self.wants_skeleton = bool(getattr(probe, "wants_skeleton", False))
        # with_max_iterations reads the base solver's default config: the same as in-thread
        self.base_solver = getattr(probe, "base_solver", probe)
        self._child: _Child | None = None
        self._closed = False
        self.restarts = 0  # children started after the first (one died or stalled)
        self.start()

    @property
    def pid(self) -> int | None:
        """The current child's process id (None when none runs)."""
        return None if self._child is None else self._child.pid

    def start(self) -> None:
        """Start the child now if none runs (does not wait for it to be ready)."""
        if self._closed:
            raise SolverProcessError("the window solver process was closed")
        if self._child is None:
            self._child = _take_spare(self.factory) or _Child(self.factory, _default_prior_path())

    def wait_ready(self) -> None:
        """Block until the child has built its solver and loaded what it needs."""
        self.start()
        self._child.wait_ready(self.startup_timeout_s)

    def __call__(self, positions, confidence, bones, bone_lengths, rate_hz, **kwargs: Any) -> Any:
        """Solve one window in the child; its result, exactly as the real solver returned it."""
        self.start()
        child = self._child
        try:
            child.wait_ready(self.startup_timeout_s)  # a restarted child may still be loading
            return child.solve((positions, confidence, bones, bone_lengths, rate_hz), kwargs, self.timeout_s)
        except SolverProcessError as exc:
            if exc.child_lost:
                self._restart(child)
            raise

    def _restart(self, child: _Child) -> None:
        """Stop a dead or stalled child and start the next one at once (it loads while we wait)."""
        child.stop(timeout_s=0.5)
        self._child = None
        if not self._closed:
            self.restarts += 1
            self.start()

    def close(self) -> None:
        """Stop the child (idempotent)."""
        self._closed = True
        child, self._child = self._child, None
        if child is not None:
            child.stop()

    def __enter__(self) -> "ProcessWindowSolver":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def __del__(self) -> None:  # an engine dropped without close(): do not leave the child behind
        try:
            self.close()
        except Exception:  # noqa: BLE001 - interpreter shutdown
            pass
