"""Imported by the forkserver of :mod:`streamfix.streaming.solver_process` only: the solver
stack's imports and the compiled kernels, done once there, so that every window-solver child
forked from it starts warm. The prior is not loaded here: onnxruntime
starts threads, and a process with threads must not be forked."""
from __future__ import annotations

from ..core import kernels
from .window_solvers import default_window_solver, import_solver_modules

default_window_solver()  # imports what the default solver imports on its first window
import_solver_modules()  # and what it imports later, inside windows
kernels.warm_up()
