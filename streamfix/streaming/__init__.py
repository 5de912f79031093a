"""Streaming layer: per-body ring buffers, windowed solving with overlap-add, the live fast path. No socket code.

* :mod:`.ring` -- per-body ring buffer of the last W frames (O(1) push, window views).
* :mod:`.live` -- the causal ``live`` path (Theil-Sen outlier gate, One Euro, bone projection).
* :mod:`.engine` -- :class:`StreamEngine` / :class:`ThreadedStreamEngine`: frames in,
  ``live`` and ``clean`` frames out (hop, lookahead, overlap-add, drops, bodies, degradation);
  the coordinator of :mod:`.config` (its settings), :mod:`.bodies` (per-body and per-stream
  state), :mod:`.blending` (hand-over weights), :mod:`.histogram` (latency metrics),
  :mod:`.solver_api` (what a window solver takes and returns) and :mod:`.window_solvers`
  (the solvers it ships).
* :mod:`.offline` -- :func:`clean_motion`: a whole motion through the same engine.
* :mod:`.solver_process` -- :class:`~.solver_process.ProcessWindowSolver`: any window solver
  run in a child process, so the engine's worker thread waits without the GIL and the live
  path is not held up by the solve (``serve --solver-process``); same output.
* :mod:`.bridging` -- the default window solver: joints missing for >= 1/3 of a window
  and blackouts are filled (PCA on the body's clean history, the prior's D(z*) for
  Kinect v2) before ``clean_window``, and flagged recovered.
"""
from .engine import EngineConfig, StreamEngine, ThreadedStreamEngine
from .live import LiveConfig
from .offline import clean_motion

__all__ = ["EngineConfig", "StreamEngine", "ThreadedStreamEngine", "LiveConfig", "clean_motion"]
