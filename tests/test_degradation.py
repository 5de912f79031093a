"""The engine's overload policy on its own (streaming.degradation): levels rise one at a
time while windows overrun, a stalled worker does not run them up, and they fall back
after enough healthy windows."""
from __future__ import annotations

from streamfix.streaming.config import EngineConfig
from streamfix.streaming.degradation import Degradation


def _cfg(**kw) -> EngineConfig:
    return EngineConfig(rate_hz=30.0, max_iterations=40, recover_after=3, **kw)


def test_levels_rise_with_overruns_and_set_hop_and_iterations():
    cfg = _cfg()
    d = Degradation(cfg)
    assert (d.level, d.hop, d.iterations()) == (0, cfg.hop, 40)
    d.solve_s = 1.0  # s: longer than a body's share of even the largest hop
    done = 0
    seen = []
    for _ in range(4):
        done += 1  # windows keep finishing: the overload is real, not a stall
        went_up = d.check(inflight=1, windows_due=2.0, n_bodies=2, done_total=done)
        seen.append((went_up, d.level, d.hop, d.iterations()))
    assert seen == [
        (True, 1, cfg.hop, 20),
        (True, 2, min(2 * cfg.hop, cfg.hop_limit), 20),
        (True, 3, cfg.hop_limit, 10),
        (False, 3, cfg.hop_limit, 10),  # level 3 is the floor
    ]


def test_a_stalled_worker_raises_one_level_only():
    d = Degradation(_cfg())
    for _ in range(5):  # nothing finishes, nothing new queued: the same stall every time
        d.check(inflight=3, windows_due=1.0, n_bodies=1, done_total=0)
    assert d.level == 1


def test_recovers_one_level_after_recover_after_healthy_windows():
    cfg = _cfg()
    d = Degradation(cfg)
    d.solve_s = 1.0
    d.check(inflight=2, windows_due=1.0, n_bodies=1, done_total=1)
    d.check(inflight=2, windows_due=1.0, n_bodies=1, done_total=2)
    assert d.level == 2
    d.solve_s = 0.0  # fast again
    levels = [d.check(inflight=0, windows_due=1.0, n_bodies=1, done_total=3) or d.level for _ in range(7)]
    assert levels == [2, 2, 1, 1, 1, 0, 0]
    assert (d.hop, d.iterations()) == (cfg.hop, 40)


def test_no_degradation_when_disabled():
    d = Degradation(_cfg(degrade=False))
    d.solve_s = 10.0
    assert not d.check(inflight=50, windows_due=1.0, n_bodies=1, done_total=1)
    assert d.level == 0


def test_a_longer_hop_is_a_larger_budget():
    cfg = _cfg()
    d = Degradation(cfg)
    d.solve_s = 1.5 * cfg.hop / cfg.rate_hz  # one body: over the hop's time, under twice it
    d.check(inflight=1, windows_due=1.0, n_bodies=1, done_total=1)
    d.check(inflight=1, windows_due=1.0, n_bodies=1, done_total=2)
    assert d.level == 2 and d.hop == 2 * cfg.hop
    assert not d.check(inflight=1, windows_due=1.0, n_bodies=1, done_total=3)  # twice the hop: in budget
    assert d.level == 2


def test_solve_time_is_averaged_over_a_hops_windows():
    # with many bodies one slow window among fast ones is no overload (its wall time includes the
    # main thread's turns at the GIL); windows that stay over their share are
    cfg = _cfg()
    n = 30
    budget = cfg.hop / cfg.rate_hz / n
    d = Degradation(cfg)
    for _ in range(3 * n):
        d.observe(0.6 * budget, n)
    d.observe(3.0 * budget, n)  # one window 3x its share
    assert d.solve_s < budget
    assert not d.check(inflight=n, windows_due=float(n), n_bodies=n, done_total=1)
    assert d.level == 0
    for _ in range(2 * n):
        d.observe(1.5 * budget, n)  # sustained: the hop's windows no longer fit in the hop
    assert d.solve_s > budget
    assert d.check(inflight=n, windows_due=float(n), n_bodies=n, done_total=2)
    assert d.level == 1
    # one body: the last window's time, as before
    one = Degradation(cfg)
    one.observe(5.0, 1)
    one.observe(0.01, 1)
    assert one.solve_s == 0.01
