"""The causal ``live`` fast path: outlier gate, low-pass filter, bone-length projection.

Per body and per frame, all vectorised across joints (no solver):

0. **Depth along the ray** (on a path built with ``camera_space``, ``repair_depth``): a
   raw sample whose bone is stretched because the sensor read the depth behind it (far
   along its camera ray from the last output) is moved back along the ray to its bone's
   length (:func:`streamfix.core.ray_depth.repair_ray_depth`, with the last output as the
   reference), flagged recovered; a few array operations when nothing is stretched. Until the
   engine hands over the body's lengths, the path judges by the median of its raw frames'
   bone lengths (:func:`streamfix.core.ray_depth.provisional_lengths`), gross throws only.
1. **Outlier gate** (per coordinate), default ``gate='theil_sen'``: the reference is
   the Theil-Sen line through the last ``gate_frames`` (7) *raw* samples of the
   coordinate (slope = median of pairwise slopes, breakdown point 29 %), evaluated at
   the newest sample; a sample whose distance to it exceeds
   ``tau = max(gate_min_m, gate_k * s)`` (``s`` a time-smoothed 1.4826 MAD of the
   line's residuals) is replaced by the line's value. This rejects isolated spikes such
   as the uniform +-25 cm corruption of Yang et al.'s protocol, which a low-pass filter
   alone only spreads out, while following real motion (the line tracks velocity) and
   real sensor noise (``s`` adapts). Replaced values are never fed back, so the gate
   cannot drift or lock out. A line cannot follow a fast real movement (a foot at
   toe-off at 30 Hz leaves it by decimetres), so a gated joint whose raw sample keeps its
   bones' lengths, where the line's value breaks them, gets its raw sample back
   (``rigid_release``, :meth:`LivePath._release_rigid`): a spike breaks the bones, real
   motion does not. ``gate='predict'`` is the older variant (constant-velocity
   prediction from the gated history, with re-acquisition after ``reacquire``
   rejections); measured worse on real Kinect data (it raised jitter) and kept for
   comparison. ``gate='none'`` disables the gate.
2. **Low-pass**: the One Euro filter (Casiez et al. 2012) or the Kinect SDK Holt filter
   from :mod:`streamfix.core.filters`, on the gated samples. The One Euro filter smooths as
   much as the window solver finds sensor noise (:meth:`LivePath.set_noise_share`): fully
   on a depth sensor, not at all on exact motion capture, where it would only lag.
3. **Bone-length projection** (non-iterative): walking the skeleton tree from its roots,
   one depth level at a time (vectorised within a level), a child is placed at
   ``l_b * u`` from its parent, ``u`` the filtered bone direction and ``l_b`` the robust
   bone length the engine estimates from the clean history. Bones without a length
   estimate are left alone. By default (``propagate=False``) the parent is taken
   unprojected, so a joint moves only along its own bone and an error never spreads
   down the chain, and only joints the gate replaced or the sensor lost move: a depth
   sensor's bones vary by centimetres, and its tracked joints put on the robust lengths
   ended further from optical motion capture (``project_tracked=True`` moves them too).
   ``propagate=True`` is forward kinematics (exact lengths, lower bone CV on Kinect, but
   a wrong parent drags its subtree: on CMU 131_01 with 20 % corruption the live jitter
   cut is markedly smaller).

``tests/test_streaming_ring_live.py`` holds the live output's jitter against the input's on
CMU 131_01 with entries corrupted by U(+-25 cm). With numba the default chain (this gate,
One Euro, the projection without propagation) runs as one compiled call per body-frame
(:func:`streamfix.core.kernels.live_step`, the same values); its cost is in
``benchmarks/results/streaming.json``.

A joint missing in the input is predicted (the gate's line; held when it has too few
samples, and always with ``gate='none'``) and flagged recovered. Units: metres, seconds.

What the window solver finds and one frame cannot (a frozen, swapped or lost limb) reaches the
live topic after this path, in the engine (:mod:`streamfix.streaming.live_carry`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core import kernels, ray_depth
from ..core.excursion import bone_into
from ..core.filters import HoltFilter as _HOLT
from ..core.isometry import seen_bone_lengths
from ..core.points import finite_points

__all__ = ["LiveConfig", "LivePath", "tree_levels", "project_bone_lengths"]

RELEASE_RATIO = 0.5
"""A gated joint gets its raw sample back when its raw bones' length error is at most this
share of the gated value's (see :meth:`LivePath._release_rigid`)."""
RELEASE_FLOOR_M = 0.003
"""... and the gated value's bone-length error exceeds this (m): below it the line breaks
nothing and its verdict stands."""
PROVISIONAL_MEMORY_S = 2.0
"""Seconds of raw bone lengths the depth repair's provisional lengths are the median of,
while the engine has not handed over the body's (its first second or so)."""
PROVISIONAL_EVERY = 5
"""...taken again every this many frames (frames between reuse the last)."""


@dataclass(frozen=True)
class LiveConfig:
    """Parameters of the live path.

    filter: 'one_euro' | 'holt' | 'none'. min_cutoff (Hz), beta (s/m), d_cutoff (Hz):
    One Euro parameters. gate: 'theil_sen' | 'predict' | 'none'; gate_frames: raw
    samples in the Theil-Sen line; gate_min_m: smallest gate radius (m); gate_k: radius
    in units of the residual scale; reacquire ('predict' gate): consecutive rejections
    after which self-consistent raw samples are accepted; project: apply the bone-length
    projection; propagate: forward-kinematics projection (see the module doc);
    rigid_release: give gated joints that keep their bones' lengths their raw sample
    ('theil_sen' gate); project_tracked: the projection moves tracked joints the gate
    accepted too (without propagation it moves only joints the gate replaced or the sensor
    lost: a depth sensor's bones vary by centimetres, and moving its tracked joints onto
    the robust lengths raised the debiased error against Vicon on UI-PRMD and KERAAL);
    repair_depth: a raw sample thrown along its camera ray (a depth read off the background,
    :mod:`streamfix.core.ray_depth`) is moved back along it first, on a path built with
    ``camera_space`` (the engine: a depth sensor's or pose estimator's layout);
    match_noise: the One Euro filter smooths as much as the window solver finds sensor noise
    (:meth:`LivePath.set_noise_share`: the engine hands over each solved window's share; 1
    until the first, 0 for exact motion capture, whose samples then pass unfiltered).
    """

    filter: str = "one_euro"
    min_cutoff: float = 3.0
    beta: float = 10.0
    d_cutoff: float = 1.0
    gate_min_m: float = 0.03
    gate_k: float = 4.0
    reacquire: int = 3
    gate: str = "theil_sen"
    gate_frames: int = 7
    project: bool = True
    propagate: bool = False
    rigid_release: bool = True
    project_tracked: bool = False
    repair_depth: bool = True
    match_noise: bool = True

    def __post_init__(self) -> None:
        if self.filter not in ("one_euro", "holt", "none"):
            raise ValueError(f"live filter must be 'one_euro', 'holt' or 'none', got {self.filter!r}")
        if self.gate not in ("theil_sen", "predict", "none"):
            raise ValueError(f"live gate must be 'theil_sen', 'predict' or 'none', got {self.gate!r}")
        if self.gate_frames < 3:
            raise ValueError(f"gate_frames must be >= 3, got {self.gate_frames}")
        if self.reacquire < 1:
            raise ValueError(f"reacquire must be >= 1 frame, got {self.reacquire}")


def tree_levels(bones: np.ndarray, n_joints: int) -> list[np.ndarray]:
    """Bones grouped by the depth of their child in a spanning forest of the bone graph.

    Returns a list of ``(k, 2)`` (parent, child) arrays, roots' children first; a joint
    reachable by several bones keeps the first (breadth-first) one, so graphs that are
    not trees (MediaPipe) are handled.
    """
    bones = np.asarray(bones, dtype=np.intp).reshape(-1, 2)
    if len(bones) == 0:
        return []
    children: dict[int, list[int]] = {}
    has_parent = np.zeros(n_joints, dtype=bool)
    for a, b in bones:
        children.setdefault(int(a), []).append(int(b))
        has_parent[b] = True
    seen = np.zeros(n_joints, dtype=bool)
    frontier = [j for j in range(n_joints) if not has_parent[j] and j in children]
    if not frontier:  # a cycle through every joint: start anywhere
        frontier = [int(bones[0, 0])]
    for j in frontier:
        seen[j] = True
    levels: list[np.ndarray] = []
    while frontier:
        level, nxt = [], []
        for p in frontier:
            for c in children.get(p, []):
                if not seen[c]:
                    seen[c] = True
                    level.append((p, c))
                    nxt.append(c)
        if level:
            levels.append(np.asarray(level, dtype=np.intp))
        frontier = nxt
    return levels


def project_bone_lengths(
    positions: np.ndarray, levels: list[np.ndarray], lengths_by_child: np.ndarray, propagate: bool = True
) -> np.ndarray:
    """Place each child at ``parent' + l * unit(child - parent)`` level by level (m).

    ``propagate`` True: ``parent'`` is the parent's projected position (forward
    kinematics: bone lengths exact, a parent's correction moves its subtree); False:
    the parent's unprojected position (each joint moves only along its own bone, so
    an error in one joint never spreads to its descendants).

    ``positions`` ``(J, 3)``; ``lengths_by_child`` ``(J,)`` target length of the bone
    ending at each joint (NaN = leave that bone's length alone, only follow the
    parent's displacement). Non-iterative: one pass over the tree depth.
    """
    out = positions.copy()
    if not propagate and levels:  # independent bones: one vectorised step over the tree
        levels = [np.concatenate(levels)] if len(levels) > 1 else levels
    for lv in levels:
        p, c = lv[:, 0], lv[:, 1]
        vec = positions[c] - positions[p]  # direction from the unprojected pose
        norm = np.linalg.norm(vec, axis=1)
        target = lengths_by_child[c]
        ok = np.isfinite(target) & (norm > 1e-9) & np.isfinite(norm)
        scale = np.where(ok, target / np.where(ok, norm, 1.0), 1.0)[:, None]
        new = (out[p] if propagate else positions[p]) + vec * scale
        good = np.isfinite(new).all(axis=1)
        out[c[good]] = new[good]
    return out


def _nanmedian0(a: np.ndarray) -> np.ndarray:
    """Median over axis 0 ignoring NaN (NaN where a column has none); fast for small axis 0."""
    srt = np.sort(a, axis=0)  # NaN sorts last
    n = (~np.isnan(a)).sum(axis=0)
    lo = np.maximum((n - 1) // 2, 0)[None]
    hi = np.maximum(n // 2, 0)[None]
    med = 0.5 * (np.take_along_axis(srt, lo, 0)[0] + np.take_along_axis(srt, hi, 0)[0])
    return np.where(n > 0, med, np.nan)


def _release_order(levels: list[np.ndarray]) -> list[np.ndarray]:
    """The tree's joints by depth, roots first (a joint off the tree has no bone to judge it by)."""
    if not levels:
        return []
    roots = np.setdiff1d(np.unique(levels[0][:, 0]), np.concatenate([lv[:, 1] for lv in levels]))
    return [roots] + [lv[:, 1] for lv in levels]


def _make_filter(cfg: LiveConfig, rate_hz: float):
    """The low-pass stage: streaming filters of :mod:`streamfix.core.filters`."""
    from streamfix.core.filters import HoltFilter, OneEuroFilter

    if cfg.filter == "none":
        return None
    if cfg.filter == "holt":
        return HoltFilter()  # the Kinect SDK's default smoothing parameters
    return OneEuroFilter(rate_hz, cfg.min_cutoff, cfg.beta, cfg.d_cutoff)


class LivePath:
    """Causal per-body estimator: ``step(x, valid, t) -> (positions, recovered)``.

    ``camera_space``: the stream is in a sensor's camera space (the depth repair runs);
    ``mirror_bones`` ``(B,)``: each bone's left/right counterpart (:func:`streamfix.limbs.mirror_bones`),
    for the depth repair's provisional lengths before :meth:`set_bone_lengths` (None: no twins)."""

    def __init__(self, n_joints: int, bones: np.ndarray, rate_hz: float, config: LiveConfig = LiveConfig(),
                 camera_space: bool = False, mirror_bones: np.ndarray | None = None) -> None:
        self.cfg = config
        self._repair_depth = bool(config.repair_depth and camera_space)
        self.n_joints = n_joints
        self.rate_hz = float(rate_hz)
        self.levels = tree_levels(bones, n_joints)
        self._tree = [np.concatenate(self.levels)] if self.levels else []  # all tree bones at once
        tree = self._tree[0] if self._tree else np.zeros((0, 2), dtype=np.intp)
        self._tree_pc = np.ascontiguousarray(tree[:, 0]), np.ascontiguousarray(tree[:, 1])
        self._fused = config.gate == "theil_sen" and config.filter == "one_euro" and not config.propagate
        self._noise_share = 1.0  # smooth fully until the engine's windows say how noisy the sensor is
        self._params = (config.min_cutoff, config.beta, config.d_cutoff, config.gate_min_m, config.gate_k)
        self.bones = np.asarray(bones, dtype=np.intp).reshape(-1, 2)
        self._child_len = np.full(n_joints, np.nan)
        # each tree bone's index in ``bones`` (a joint two bones end at takes its tree bone's length)
        index = {(int(a), int(c)): k for k, (a, c) in enumerate(self.bones)}
        self._tree_bone = np.array([index[(int(a), int(c))] for a, c in tree], dtype=np.intp)
        # the depth repair judges each joint by the later-listed bone into it (core.excursion.bone_into)
        into = bone_into(self.bones, n_joints)
        self._ray_child = np.flatnonzero(into >= 0)
        self._ray_bone = into[self._ray_child]
        self._ray_parent = self.bones[self._ray_bone, 0] if len(self.bones) else self._ray_child
        self._bone_len = None  # (B,) m once set_bone_lengths gives them
        # until then the depth repair judges by the raw frames' own lengths (core.ray_depth.provisional_lengths)
        self._mirror_bones = (None if mirror_bones is None or len(mirror_bones) != len(self.bones)
                              else np.asarray(mirror_bones, dtype=np.intp))
        memory = max(int(round(PROVISIONAL_MEMORY_S * self.rate_hz)), ray_depth.PROVISIONAL_MIN_FRAMES)
        self._raw_lengths = np.full((memory, len(self.bones)), np.nan)
        self._raw_lengths_n = 0
        self._provisional = None  # the last provisional_lengths taken
        self._release_order = _release_order(self.levels)
        self._release_flat = np.ascontiguousarray(np.concatenate(self._release_order) if self._release_order
                                                  else np.zeros(0, dtype=np.intp), dtype=np.intp)
        self.reset()

    def reset(self) -> None:
        """Forget the motion history (kept: bone lengths)."""
        J = self.n_joints
        self._g = np.full((3, J, 3), np.nan)  # gated samples g_{t-1}, g_{t-2}, g_{t-3}
        K = self.cfg.gate_frames
        self._hist = np.full((K, J, 3), np.nan)  # raw samples, oldest first (theil_sen gate)
        self._u = np.arange(K, dtype=np.float64)
        self._pi, self._pj = np.triu_indices(K, 1)
        self._du = (self._u[self._pj] - self._u[self._pi])[:, None, None]
        self._raw = np.full((max(self.cfg.reacquire, 1), J, 3), np.nan)  # newest first
        self._scale = np.full((J, 3), np.nan)  # running mean |innovation| (m)
        self._rejected = np.zeros((J, 3), dtype=np.int64)
        self._filter = _make_filter(self.cfg, self.rate_hz)
        self._apply_noise_share()
        self._last = np.full((J, 3), np.nan)
        self.gated_total = 0

    def set_noise_share(self, share: float) -> None:
        """How much of the input is sensor noise, in [0, 1]: a solved window's share
        (:data:`streamfix.streaming.solver_api.NOISE_SHARE_KEY`, the same verdict by which the
        clean topic is smoothed). The One Euro filter's resting cutoff becomes ``min_cutoff /
        share``: 1 keeps the configured filter bit for bit, 0 passes the gated samples through
        unfiltered. Why: on exact motion capture the filter removes no noise and only lags, moving
        joints the sensor has right (the live column of ``benchmarks/results/sensor.md``), while a
        depth sensor's windows report a share of 1. Ignored unless ``match_noise``; the Holt
        filter keeps its parameters."""
        if not self.cfg.match_noise:
            return
        self._noise_share = float(np.clip(share, 0.0, 1.0)) if np.isfinite(share) else 1.0  # NaN: smooth
        self._apply_noise_share()

    def _apply_noise_share(self) -> None:
        """The One Euro resting cutoff for the current noise share (see :meth:`set_noise_share`)."""
        cfg = self.cfg
        min_cutoff = cfg.min_cutoff / self._noise_share if self._noise_share > 0.0 else np.inf
        self._params = (min_cutoff, cfg.beta, cfg.d_cutoff, cfg.gate_min_m, cfg.gate_k)
        if self._filter is not None and not isinstance(self._filter, _HOLT):
            self._filter.min_cutoff = min_cutoff

    def set_bone_lengths(self, lengths: np.ndarray | None) -> None:
        """Target ``(B,)`` bone lengths (m) for the projection; NaN/None leaves bones alone."""
        child_len = np.full(self.n_joints, np.nan)
        self._bone_len = None
        if lengths is not None and len(self.bones):
            lengths = np.asarray(lengths, dtype=np.float64)
            child_len[self._tree_pc[1]] = lengths[self._tree_bone]
            self._bone_len = lengths
        self._child_len = child_len

    def anchor(self, recent: np.ndarray) -> None:
        """Re-anchor the gate's history on a solved window's newest frames.

        ``recent`` ``(k, J, 3)`` m, oldest first, ending at the frame just pushed. The
        gate's reference then follows the robust window solution instead of its own
        (possibly wrongly gated) history; finite values only.
        """
        k = min(len(recent), 3)
        for i in range(k):
            row = recent[-1 - i]
            ok = np.isfinite(row)
            self._g[i][ok] = row[ok]

    def predict(self, x: np.ndarray | None = None, valid: np.ndarray | None = None) -> np.ndarray:
        """Prediction ``r_t`` (m) of every joint from the gated history, ``(J, 3)``.

        ``r_t = g_{t-1} + d_t + (v_j - c)``: ``v_j`` the joint's last gated velocity, ``c``
        its median over joints (the body's common motion), and ``d_t`` the common motion
        of the current frame, the median over joints of ``x_t - g_{t-1}`` (robust to a
        minority of corrupted joints). Without the current frame, ``d_t = c``.
        """
        g1, g2, _ = self._g
        vel = np.where(np.isfinite(g2), g1 - g2, 0.0)
        vel = np.where(np.isfinite(vel), vel, 0.0)
        ok = np.isfinite(g1).all(axis=1)
        if not ok.any():
            return g1.copy()
        common = np.median(vel[ok], axis=0)
        d = common
        if x is not None:
            cur = ok & valid
            if cur.sum() >= 3:
                d = np.median(x[cur] - g1[cur], axis=0)
        return g1 + d + (vel - common)

    def robust_line(self) -> tuple[np.ndarray, np.ndarray]:
        """Theil-Sen line through the last ``gate_frames`` raw samples of each coordinate.

        Slope ``b`` = median of the pairwise slopes, intercept ``a`` = median of
        ``x_i - b u_i`` (breakdown point 29 %: two corrupted samples out of 7 do not move
        it). Returns the line's value at the newest sample ``(J, 3)`` m and the robust
        residual scale ``1.4826 MAD`` ``(J, 3)`` m (NaN with fewer than 3 samples).
        """
        H = self._hist
        if kernels.COMPILED:  # the same medians in one compiled pass
            return kernels.theil_sen_line(H, self._u, self._pi, self._pj)
        slopes = (H[self._pj] - H[self._pi]) / self._du
        b = _nanmedian0(slopes)
        a = _nanmedian0(H - b[None] * self._u[:, None, None])
        resid = H - (a[None] + b[None] * self._u[:, None, None])
        sigma = 1.4826 * _nanmedian0(np.abs(resid))
        n = (~np.isnan(H)).sum(axis=0)
        r = np.where(n >= 3, a + b * self._u[-1], np.nan)
        return r, np.where(n >= 3, sigma, np.nan)

    def step(self, x: np.ndarray, valid: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        """One frame: raw ``(J, 3)`` m (NaN missing), ``valid (J,)``, time ``t`` s.

        Returns ``(positions (J, 3), recovered (J,) bool)``; ``recovered`` marks
        joints that were missing or whose sample the gate replaced (or the depth repair moved).
        """
        if not self._repair_depth:
            return self._step(x, valid, t)
        lengths, floor_m = self._bone_len, ray_depth.FLOOR_M
        if lengths is None:  # the body's lengths are not known yet: gross throws only
            lengths, floor_m = self._provisional_lengths(x, valid), ray_depth.PROVISIONAL_FLOOR_M
            if lengths is None:
                return self._step(x, valid, t)
        # the repair's own first test, on the tree's bones at once: nothing stretched, nothing to judge
        length = lengths[self._ray_bone]
        bone = np.linalg.norm(x[self._ray_child] - x[self._ray_parent], axis=1)
        if not (bone - length > np.maximum(ray_depth.FRACTION * length, floor_m)).any():
            return self._step(x, valid, t)
        # a stretched bone whose joint stays near the last output is noise, not a throw: the same
        # answer as the repair's at a fraction of its cost (most stretched frames of a Kinect)
        if ray_depth.reference_rules_out_throws(x, valid & finite_points(x), self._ray_child, self._ray_parent, length,
                                                self._last, floor_m=floor_m):
            return self._step(x, valid, t)
        # judged against the body's lengths and the last output (where each joint was expected)
        fixed, moved = ray_depth.repair_ray_depth(x[None], valid[None].astype(np.float64), self.bones, lengths,
                                                  floor_m=floor_m, reference=self._last[None])
        if not moved.any():
            return self._step(x, valid, t)
        y, rec = self._step(fixed[0], valid, t)
        return y, rec | moved[0]

    def _provisional_lengths(self, x: np.ndarray, valid: np.ndarray) -> np.ndarray | None:
        """File this raw frame's bone lengths and return the provisional lengths of the frames
        filed so far (:func:`streamfix.core.ray_depth.provisional_lengths`; None with no bones):
        the depth repair's lengths before the engine knows the body's."""
        if not len(self.bones):
            return None
        self._raw_lengths[self._raw_lengths_n % len(self._raw_lengths)] = seen_bone_lengths(x, valid, self.bones)
        self._raw_lengths_n += 1
        n = self._raw_lengths_n
        # the median moves slowly: taken again every PROVISIONAL_EVERY frames once a few are in
        # (each take costs more than the rest of a live frame)
        if self._provisional is None or n <= 2 * PROVISIONAL_EVERY or n % PROVISIONAL_EVERY == 0:
            self._provisional = ray_depth.provisional_lengths(self._raw_lengths[:n], self._mirror_bones)
        return self._provisional

    def _step(self, x: np.ndarray, valid: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`step` after the depth repair."""
        cfg = self.cfg
        if self._fused and kernels.COMPILED:  # the default chain in one compiled call, same values
            return self._step_compiled(x, valid, t)
        valid3 = np.broadcast_to(valid[:, None], x.shape)
        if cfg.gate == "theil_sen":
            return self._step_theil_sen(x, valid, valid3, t)
        if cfg.gate == "none":  # missing joints hold their last output
            return self._finish(np.where(valid3, x, self._last), np.zeros(x.shape, dtype=bool), valid, t)
        r = self.predict(x, valid)
        have_ref = np.isfinite(r)
        innov = np.abs(x - r)
        scale = np.where(np.isfinite(self._scale), self._scale, cfg.gate_min_m)
        tau = np.maximum(cfg.gate_min_m, cfg.gate_k * scale)
        outlier = valid3 & have_ref & (innov > tau)
        # Re-acquisition: a long-rejected coordinate whose recent raw samples agree.
        self._raw = np.roll(self._raw, 1, axis=0)
        self._raw[0] = np.where(valid3, x, np.nan)
        reacquired = None
        if cfg.reacquire >= 1:
            long_rej = outlier & (self._rejected >= cfg.reacquire)
            if long_rej.any():
                spread = self._raw.max(axis=0) - self._raw.min(axis=0)  # NaN if any missing
                spread = np.where(np.isfinite(spread), spread, np.inf)
                reacquired = long_rej & (spread <= tau)
                outlier &= ~reacquired
        accepted = valid3 & ~outlier
        self._rejected = np.where(outlier, self._rejected + 1, 0)
        self.gated_total += int(outlier.any(axis=1).sum())
        # running mean absolute innovation of accepted samples (EMA, 10-frame memory)
        upd = accepted & have_ref
        self._scale = np.where(
            upd, np.where(np.isfinite(self._scale), 0.9 * self._scale + 0.1 * innov, innov), self._scale
        )
        g = np.where(accepted, x, np.where(have_ref, r, np.nan))
        self._g = np.roll(self._g, 1, axis=0)
        self._g[0] = g
        if reacquired is not None and reacquired.any():  # restart those coordinates at rest
            self._g[1:, reacquired] = x[reacquired]
            self._scale[reacquired] = np.nan
        return self._finish(g, outlier, valid, t)

    def _step_compiled(self, x, valid, t):
        """:meth:`step` for the default chain via :func:`streamfix.core.kernels.live_step`;
        the state is the numpy path's own (the same arrays), so either may take the next frame."""
        f = self._filter
        if f._x is None:  # the filter's state before its first frame, as OneEuroFilter.step makes it
            J = self.n_joints
            f._x, f._dx, f._t, f._seen = np.full((J, 3), np.nan), np.zeros((J, 3)), np.zeros(J), np.zeros(J, dtype=bool)
        f._frame += 1
        tree_p, tree_c = self._tree_pc
        y, outlier, n_gated = kernels.live_step(
            x, valid, t, self._hist, self._u, self._pi, self._pj, self._scale, self._last,
            (f._x, f._dx, f._t, f._seen), self._params, tree_p, tree_c, self._child_len,
            bool(self.cfg.project and self.levels), bool(self.cfg.project_tracked),
            (self._release_flat, RELEASE_RATIO if self.cfg.rigid_release else -1.0, RELEASE_FLOOR_M),
        )
        self.gated_total += n_gated
        self._last = y.copy()
        return y, ~valid | outlier.any(axis=1)

    def _step_theil_sen(self, x, valid, valid3, t):
        """Gate against the robust line through the raw history (no feedback of gated values)."""
        cfg = self.cfg
        self._hist = np.roll(self._hist, -1, axis=0)
        self._hist[-1] = np.where(valid3, x, np.nan)
        r, sigma = self.robust_line()
        have_ref = np.isfinite(r)
        innov = np.abs(x - r)
        # robust residual scale, smoothed over time (EMA, ~10 frames)
        upd = np.isfinite(sigma)
        self._scale = np.where(
            upd, np.where(np.isfinite(self._scale), 0.9 * self._scale + 0.1 * sigma, sigma), self._scale
        )
        scale = np.where(np.isfinite(self._scale), self._scale, cfg.gate_min_m)
        tau = np.maximum(cfg.gate_min_m, cfg.gate_k * scale)
        outlier = valid3 & have_ref & (innov > tau)
        last = self._last
        g = np.where(valid3 & ~outlier, x, np.where(have_ref, r, last))
        if cfg.rigid_release and outlier.any():
            self._release_rigid(x, valid, g, outlier)
        self.gated_total += int(outlier.any(axis=1).sum())
        return self._finish(g, outlier, valid, t)

    def _release_rigid(self, x: np.ndarray, valid: np.ndarray, g: np.ndarray, outlier: np.ndarray) -> None:
        """Give gated joints whose raw sample keeps their bones back their raw sample, in place.

        The line through the last raw samples cannot follow a fast real movement (a foot at
        toe-off, a punch): the newest sample leaves it by more than the gate radius. The
        skeleton tells such motion from a spike: a real movement keeps the lengths of the
        joint's bones and the line's value breaks them; a spike breaks them and the line's
        value keeps them. Joint by joint, roots first (a released parent counts as raw for
        its children): ``E_raw`` is the mean over the joint's tree bones of
        ``| |x_j - x_k| - L_b |`` (the parent as judged, the children raw where valid: a
        forearm flung off the elbow's line value stays gated joint by joint), ``E_rep`` the
        same for the gated values; the joint is released when ``E_raw <= RELEASE_RATIO * E_rep`` and
        ``E_rep > RELEASE_FLOOR_M``. ``L_b`` is the engine's robust bone length, else the
        bone's length in the previous output.
        """
        tree_p, tree_c = self._tree_pc
        if not len(tree_p):
            return
        length = self._child_len[tree_c]
        prev = np.linalg.norm(self._last[tree_c] - self._last[tree_p], axis=1)
        length = np.where(np.isfinite(length), length, prev)
        child_raw = np.where(valid[:, None], x, g)
        for joints in self._release_order:
            cand = joints[valid[joints] & outlier[joints].any(axis=1)]
            if not len(cand):
                continue
            e_raw = np.zeros(len(cand))
            e_rep = np.zeros(len(cand))
            n = np.zeros(len(cand))
            # children (not judged yet) raw where valid; the parent as judged (roots first)
            for end, other, neighbour in ((tree_p, tree_c, child_raw), (tree_c, tree_p, g)):
                hit = end[None, :] == cand[:, None]  # (candidates, bones)
                ci, bi = np.nonzero(hit)
                k = other[bi]
                ok = np.isfinite(length[bi]) & np.isfinite(neighbour[k]).all(axis=1) & np.isfinite(g[k]).all(axis=1)
                ci, bi, k = ci[ok], bi[ok], k[ok]
                j = cand[ci]
                raw = np.abs(np.linalg.norm(x[j] - neighbour[k], axis=1) - length[bi])
                rep = np.abs(np.linalg.norm(g[j] - g[k], axis=1) - length[bi])
                np.add.at(e_raw, ci, raw)
                np.add.at(e_rep, ci, rep)
                np.add.at(n, ci, 1.0)
            have = n > 0
            e_raw = np.where(have, e_raw / np.maximum(n, 1), np.inf)
            e_rep = np.where(have, e_rep / np.maximum(n, 1), 0.0)
            free = cand[(e_raw <= RELEASE_RATIO * e_rep) & (e_rep > RELEASE_FLOOR_M)]
            g[free] = x[free]
            outlier[free] = False

    def _finish(self, g, outlier, valid, t):
        cfg = self.cfg
        joint_ok = np.isfinite(g).all(axis=1)
        if self._filter is not None:
            if isinstance(self._filter, _HOLT):
                y = self._filter.step(g, joint_ok)
            else:
                y = self._filter.step(g, joint_ok, t)
        else:
            y = g.copy()
        y = np.where(np.isfinite(y), y, self._last)
        recovered = ~valid | outlier.any(axis=1)
        if cfg.project and self.levels:
            projected = project_bone_lengths(y, self.levels if cfg.propagate else self._tree, self._child_len,
                                             cfg.propagate)
            # without propagation each joint moves along its own bone only: a tracked joint the
            # gate accepted stays where it was measured
            y = projected if cfg.propagate or cfg.project_tracked else np.where(recovered[:, None], projected, y)
        self._last = y
        return y, recovered
