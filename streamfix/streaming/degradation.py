"""The threaded engine's overload policy: how far it degrades when its solver falls behind.

Level 0 = the configured schedule; 1 = half the solver iterations; 2 = also twice the
hop; 3 = quarter iterations and the largest hop (:attr:`EngineConfig.hop_limit`). The
engine asks :meth:`Degradation.check` before it queues a window; a level is recovered
after ``recover_after`` consecutive healthy windows. No I/O, no threads: the engine
passes in what it counts.
"""
from __future__ import annotations

from .config import EngineConfig

__all__ = ["Degradation"]


class Degradation:
    """Degradation level, hop (frames) and iteration cap of one engine."""

    def __init__(self, cfg: EngineConfig) -> None:
        self.cfg = cfg
        self.level = 0
        self.hop = cfg.hop
        self.solve_s = 0.0  # solved windows' compute time (s), averaged over about one hop's windows
        self._healthy = 0
        self._done_at_change = 0
        self._pending_at_change = 0

    def iterations(self) -> int | None:
        """The solver's iteration cap at the current level (None: the solver's own)."""
        base = self.cfg.max_iterations
        if self.level == 0:
            return base
        lvl1 = self.cfg.degraded_iterations or (max(1, base // 2) if base else 10)
        if self.level >= 3:
            return max(1, lvl1 // 2)
        return lvl1

    def observe(self, solve_s: float, n_bodies: int) -> None:
        """Take a solved window's compute time (s, wall) into :attr:`solve_s`, an exponential
        average over about ``n_bodies`` windows: the windows one hop owes.

        Why an average: the check asks whether the worker finishes a hop's windows within the
        hop, which is their mean time against each one's share. A single window is a noisy
        answer with many bodies: a window's wall time includes the main thread's turns at the
        GIL, and single windows over their 1/30 share of the hop took a threaded engine with 30
        bodies at 30 Hz on one core to level 2 while the core still had time to spare;
        averaged, level 1, far less often. With one body it is the last window's time, as before."""
        if n_bodies <= 1:
            self.solve_s = float(solve_s)
        else:
            self.solve_s += (float(solve_s) - self.solve_s) / n_bodies

    def check(self, inflight: int, windows_due: float, n_bodies: int, done_total: int) -> bool:
        """Update the level before a window is queued; True when it went up (an event).

        Overloaded when the worker cannot finish one window per body per hop. Budgets
        scale with the number of tracked bodies ``n_bodies``: ``windows_due`` windows are
        owed every hop, so that many in flight is normal and a body's window may take
        hop / n_bodies on average (:meth:`observe`). (An engine-wide "any window
        in flight" test degraded 12 bodies at 30 Hz to level 3 and skipped windows
        although the solver left most of a core idle.) A level only rises again once windows
        finished or queued since the last change (a stalled worker does not run the level up
        to 3 at once).
        """
        if not self.cfg.degrade:
            return False
        budget_s = self.hop / self.cfg.rate_hz / n_bodies
        if inflight > windows_due or self.solve_s > budget_s:
            self._healthy = 0
            progressed = done_total > self._done_at_change or inflight > self._pending_at_change
            if self.level < 3 and (progressed or self.level == 0):
                self._set_level(self.level + 1, done_total, inflight)
                return True
        elif self.solve_s < 0.5 * budget_s:
            self._healthy += 1
            if self.level > 0 and self._healthy >= self.cfg.recover_after:
                self._set_level(self.level - 1, done_total, inflight)
                self._healthy = 0
        return False

    def _set_level(self, level: int, done_total: int, inflight: int) -> None:
        self.level = level
        self._done_at_change = done_total
        self._pending_at_change = inflight
        limit = self.cfg.hop_limit
        if level >= 3:
            self.hop = limit
        elif level == 2:
            self.hop = min(2 * self.cfg.hop, limit)
        else:
            self.hop = self.cfg.hop
