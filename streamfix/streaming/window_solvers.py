"""The window solvers the engine ships: the default (long-gap bridging in front of
``streamfix.core.pipeline.clean_window``) and the ALM adapter, and how the engine reads a
solver's wishes (``wants_history``, ``wants_skeleton``) and caps its iterations."""
from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ..core.points import finite_points, point_norms
from .solver_api import WindowOutput, WindowSolver, WindowSolverError

__all__ = ["alm_window_solver", "default_window_solver", "wants", "with_max_iterations", "with_score_frames"]


def alm_window_solver(
    positions: np.ndarray,
    confidence: np.ndarray,
    bones: np.ndarray,
    bone_lengths: np.ndarray | None,
    rate_hz: float,
    config: Any = None,
    state: Any = None,
    init: np.ndarray | None = None,
) -> WindowOutput:
    """Adapter: :func:`streamfix.core.alm.solve` (Yang et al. Algorithm 1) as a window solver.

    ``config`` is a :class:`~streamfix.core.alm.SolverParams` (None = defaults).
    ``recovered`` = unobserved, or observed but moved by the sparse term E by > 2 cm.
    """
    from ..core.alm import SolverParams, solve

    params = config if config is not None else SolverParams()
    observed = (np.asarray(confidence) > 0) & finite_points(positions)
    res = solve(positions, observed, bones, bone_lengths, params, init=init, state=state)
    err = point_norms(np.nan_to_num(res.sparse_error))
    recovered = ~observed | (err > 0.02)
    return WindowOutput(res.positions, recovered, res.state, int(res.iterations), bool(res.converged))


def default_window_solver() -> WindowSolver:
    """``streamfix.core.pipeline.clean_window`` behind the long-gap bridge
    (:class:`~streamfix.streaming.bridging.BridgingWindowSolver`: joints missing for
    >= 1/3 of a window and blackouts are filled from PCA on the body's clean history or
    the learned prior first).

    Raises :class:`WindowSolverError` when the solver stack cannot be imported (a
    dependency such as PyWavelets missing): every window would fail, and ``clean`` would
    carry the live path's output instead of a cleaning.
    """
    try:
        from ..core.pipeline import clean_window  # type: ignore[attr-defined]  # noqa: F401
    except ImportError as exc:
        raise WindowSolverError(
            f"the window solver cannot be imported ({exc}); the installation is incomplete: "
            "reinstall streamfix with its dependencies (pip install streamfix)") from exc
    from .bridging import BridgingWindowSolver

    return BridgingWindowSolver()


def wants(solver: WindowSolver, flag: str) -> bool:
    """True when the solver declares ``flag`` (``wants_history``: takes ``history=``;
    ``wants_skeleton``: takes ``skeleton=``), itself or one wrapper level (``.solver``)."""
    if getattr(solver, flag, False):
        return True
    inner = getattr(solver, "solver", None)
    return inner is not None and inner is not solver and bool(getattr(inner, flag, False))


def import_solver_modules() -> None:
    """Import the modules the default solver imports lazily inside its windows (the prior's
    initialiser and latent fit, the swap, support, jump and dislocated-limb stages, PCA's
    fill): time that an import would otherwise spend holding the GIL, and the
    interpreter's import lock, in a solver thread the first time a window needs one, while
    the live path waits (``tests/test_window_solvers_preload.py`` checks that a stream's
    windows import nothing after this). Loads no model."""
    from ..core import dislocated, limb_jumps, pca_fill, pca_gapfill, support  # noqa: F401
    from ..prior import init, latent  # noqa: F401
    from . import support as window_support, swaps  # noqa: F401


def _default_config(solver: WindowSolver) -> Any:
    """The ``config`` a window solver (or the base of a wrapping one) uses when given None, or None."""
    solver = getattr(solver, "base_solver", solver)
    try:
        import inspect

        default = inspect.signature(solver).parameters["config"].default
    except (KeyError, TypeError, ValueError):
        return None
    return None if default is inspect.Parameter.empty else default


def with_score_frames(config: Any, n: int | None, solver: WindowSolver) -> Any:
    """A copy of a solver config with ``score_newest_frames`` set to ``n`` where the config
    (given, or the solver's default) has that field (``streamfix.core.pipeline.PipelineConfig``);
    otherwise ``config`` unchanged."""
    base = config if config is not None else _default_config(solver)
    if n is None or not dataclasses.is_dataclass(base):
        return config
    if "score_newest_frames" not in {f.name for f in dataclasses.fields(base)}:
        return config
    return dataclasses.replace(base, score_newest_frames=int(n))


def with_max_iterations(config: Any, n: int | None, solver: WindowSolver) -> Any:
    """A copy of a solver config with its iteration cap set to ``n`` (if it has one)."""
    if n is None:
        return config
    solver = getattr(solver, "base_solver", solver)  # a wrapping solver: its base's config
    if config is None:
        if solver is alm_window_solver:
            from ..core.alm import SolverParams

            return SolverParams(max_iter=n)
        config = _default_config(solver)
        if config is None:
            return None
    if not dataclasses.is_dataclass(config):
        return config
    names = {f.name for f in dataclasses.fields(config)}
    for key in ("max_iterations", "max_iter", "solver_max_iter", "iterations"):
        if key in names:
            return dataclasses.replace(config, **{key: n})
    for key in ("solver", "params", "solver_params", "alm"):
        if key in names:
            inner = getattr(config, key)
            new_inner = with_max_iterations(inner, n, solver) if inner is not None else None
            if new_inner is not inner:
                return dataclasses.replace(config, **{key: new_inner})
    return config
