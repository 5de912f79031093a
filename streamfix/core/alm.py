"""Yang et al. (2019) spatio-temporal motion recovery, solved by ADM-ALM (Algorithm 1).

Model (Eq. 8), with the paper's symbols::

    min  ||A||_* + lam ||E||_1 + mu ||C||_1 + gamma/2 E_iso(N)
    s.t. D = A + E,   N = A,   C = W A

``D`` is the paper's ``3T x S`` motion matrix (Eq. 1): row ``3t + c`` holds
coordinate ``c`` of every joint at frame ``t``, column ``i`` is joint i's trajectory.
The nuclear norm / SVD (Eq. 14) is taken in exactly that layout. Internally every
variable is stored as a ``(T, S, 3)`` array (frame, joint, coordinate); the paper's
matrix is ``X.transpose(0, 2, 1).reshape(3T, S)``. The wavelet W (Eq. 6) acts along
time on each of the ``3S`` coordinate channels (see :mod:`streamfix.core.wavelets`);
C and Z3 live in the wavelet domain.

Modes (Table I of the paper):
  ``'wang'``  low rank + sparse error only (Wang et al. [16]): variables A, E.
  ``'li'``    + isometry (Li et al. [17]): A, E, N.
  ``'yang'``  + wavelet sparsity (the paper): A, E, N, C.

Observation mask
----------------
Entries of D that were not observed are unknowns, not data. We enforce the data
constraint ``D = A + E`` only on observed entries, which is the same as letting E be
free (unpenalised) on unobserved ones: the E-subproblem there,
``min_E <Z1, E - D + A> + rho1/2 ||E - D + A||^2``, has the minimiser
``E = D - A - Z1/rho1`` (no shrinkage). Then ``Z1 <- Z1 + rho1 (E - D + A) = 0`` on
those entries after the first iteration, and ``H1 = D - E - Z1/rho1 = A^k``: the data
term contributes no pull there, only the low-rank, isometry and wavelet terms decide
the missing values. The primal residual is measured on observed entries only.

Initial penalty
---------------
The paper uses rho1 = rho2 = rho3 = 0.5 with ``A^0 = 0``. In metre units the
thresholds lam/rho1 (E-step) and 1/(sum rho) (SVT) are then larger than the whole
signal: E absorbs all of D and A stays ~0 (AJE > 1 m). The penalties are not scale
free, so we use the inexact-ALM rule of the paper's reference [45] (Lin, Chen & Ma):
``rho0 = 1.25 / ||D||_2`` (spectral norm of the observed, centred D), for all three.

Measured on CMU 131_01 + 131_02 (120 Hz, uniform [-0.25, 0.25] m noise on 5-80 % of the
entries of D, bone lengths estimated from the corrupted input; paper Table II totals
0.004/0.006/0.007/0.010/0.067): up to 20 % the defaults (centre 'global', detail_only)
matched centre 'none' and beat centre 'channel', detail_only=False and the paper as printed
(centre 'none', detail_only=False); the paper's rho0 = 0.5 failed at every level;
eta = 1.1 was more accurate up to 20 % at about twice the iterations; 'li' (from 10 %) and
'wang' were less accurate. At 80 % the true bone lengths (as the paper does on CMU) help
most: no clean frame is left to estimate lengths from. ``benchmarks/bench_accuracy.py``
compares the modes on the paper's protocol.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .interpolate import interpolate_linear
from .isometry import estimate_bone_lengths, gauss_newton_step
from .points import finite_points
from .wavelets import TemporalWavelet

__all__ = ["SolverParams", "SolverState", "SolverResult", "solve", "default_rho0"]

_MODES = ("yang", "li", "wang")
_CENTERS = ("none", "global", "channel")


@dataclass(frozen=True)
class SolverParams:
    """Parameters of Algorithm 1 (defaults: the paper's Section IV-A, rho0 see module doc).

    mode: 'yang' (all terms) | 'li' (no wavelet term) | 'wang' (low rank + sparse).
    lam: weight of ||E||_1; None -> 1/sqrt(T) (T = frames), the paper's choice.
    gamma: weight of the isometry energy (metres^-2 scale: residuals are m^2).
    mu: weight of ||W A||_1.
    eta: penalty growth per iteration, rho^{k+1} = eta rho^k (Algorithm 1, lines 15-17).
    rho0: initial penalty for rho1, rho2, rho3; None -> 1.25 / ||D||_2.
    rho0_scale: multiplies rho0 (default rule or given). > 1 starts the continuation
        later, which suits a good ``init`` (e.g. a learned prior's prediction) that
        small penalties would otherwise wash out.
    wavelet, level: orthogonal Daubechies wavelet and decomposition depth (2); windows
        shorter than 2**level frames use the deepest level that fits (1 frame: none).
    detail_only: apply the mu-shrinkage only to detail coefficients (not the coarse
        approximation), so the l1 term does not pull trajectories toward the origin.
    center: subtract a mean of the observed data before solving and add it back:
        'none' | 'global' (one mean per coordinate over all joints and frames) |
        'channel' (one mean per joint and coordinate).
    max_iter: iteration cap (the paper: 1000).
    tol: stop when the relative primal residual
        ||(D - A - E)_obs, N - A, C - W A||_F / ||D_obs||_F drops below it. 1e-4 gave
        practically the same AJE as 1e-5 and 1e-7 on CMU 131_01/02 at 5-80 % corruption.
    gn_steps: Gauss-Newton steps per N-subproblem (Algorithm 1 line 4 does one).
    warm_skip: on a warm start, penalties restart at rho0 * eta**warm_skip, i.e. the
        first ``warm_skip`` penalty steps of a cold start are skipped. Restarting at the
        previous window's final rho does not work: the thresholds lam/rho and 1/sum(rho)
        are then ~0, E absorbs the new frames' data unshrunk and A stays at its
        extrapolated guess (measured: the solution was lost within a few hops). On CMU 131_01 at 10 %
        corruption (sliding windows, 120 Hz hop 16 and 30 Hz hop 8), skipping 5-10 steps
        took fewer iterations at a similar window AJE, the hop's newest frames losing a
        little as the skip grows. Skipping more (15+) costs accuracy on the new
        frames quickly.
    """

    mode: str = "yang"
    lam: float | None = None
    gamma: float = 100.0
    mu: float = 0.01
    eta: float = 1.3
    rho0: float | None = None
    rho0_scale: float = 1.0
    wavelet: str = "db10"
    level: int = 2
    detail_only: bool = True
    center: str = "global"
    max_iter: int = 1000
    tol: float = 1e-4
    gn_steps: int = 1
    warm_skip: int = 8

    def __post_init__(self) -> None:
        if self.mode not in _MODES:
            raise ValueError(f"mode must be one of {_MODES}, got {self.mode!r}")
        if self.center not in _CENTERS:
            raise ValueError(f"center must be one of {_CENTERS}, got {self.center!r}")
        if not self.eta > 1.0:
            raise ValueError(f"eta must be > 1 (Algorithm 1), got {self.eta}")
        for name in ("gamma", "mu"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if self.lam is not None and not self.lam > 0:
            raise ValueError(f"lam must be > 0 or None, got {self.lam}")
        if not self.rho0_scale > 0:
            raise ValueError(f"rho0_scale must be > 0, got {self.rho0_scale}")
        if self.rho0 is not None and not self.rho0 > 0:
            raise ValueError(f"rho0 must be > 0 or None, got {self.rho0}")
        if self.max_iter < 1 or self.gn_steps < 1:
            raise ValueError("max_iter and gn_steps must be >= 1")


@dataclass
class SolverState:
    """All ALM variables of one solved window, in absolute coordinates, ``(T, S, 3)``.

    ``A, N`` positions (m); ``E`` sparse error (m; 0 where unobserved);
    ``Ct = W^T C`` and ``Z3t = W^T Z3`` (the wavelet-domain variables mapped back to
    time, so that a state can be shifted in time independently of W);
    ``Z1, Z2`` multipliers; ``rho`` = (rho1, rho2, rho3) at exit; ``rho0`` the
    cold-start penalty; ``bone_lengths`` used; ``fresh``: number of trailing frames that
    are placeholders added by :meth:`shifted` (``solve`` re-initialises their A, N and
    W^T C from the new window's data).
    """

    A: np.ndarray
    E: np.ndarray
    Ct: np.ndarray
    N: np.ndarray
    Z1: np.ndarray
    Z2: np.ndarray
    Z3t: np.ndarray
    rho: np.ndarray
    rho0: float
    bone_lengths: np.ndarray | None = None
    iterations: int = 0
    fresh: int = 0

    @property
    def n_frames(self) -> int:
        return self.A.shape[0]

    def shifted(self, hop: int) -> "SolverState":
        """Warm start for the window advanced by ``hop`` frames (same length T).

        Drops the first ``hop`` frames; the ``hop`` new frames at the end repeat the last
        frame's positions (A, N, W^T C) and get zero sparse error and zero multipliers.
        (Constant-velocity extrapolation was tried: a window's last frames are its least
        constrained, and their velocity extrapolated over a hop put joints far off.)
        """
        hop = int(hop)
        n_frames = self.n_frames
        if not 0 <= hop <= n_frames:
            raise ValueError(f"hop must be in 0..{n_frames} frames, got {hop}")
        if hop == 0:
            return replace(self, **{k: getattr(self, k).copy() for k in ("A", "E", "Ct", "N", "Z1", "Z2", "Z3t", "rho")})

        def extend_pos(x: np.ndarray) -> np.ndarray:
            return np.concatenate([x[hop:], np.repeat(x[-1:], hop, axis=0)], axis=0)

        def extend_zero(x: np.ndarray) -> np.ndarray:
            return np.concatenate([x[hop:], np.zeros((hop,) + x.shape[1:])], axis=0)

        return replace(
            self,
            A=extend_pos(self.A),
            N=extend_pos(self.N),
            Ct=extend_pos(self.Ct),
            E=extend_zero(self.E),
            Z1=extend_zero(self.Z1),
            Z2=extend_zero(self.Z2),
            Z3t=extend_zero(self.Z3t),
            rho=self.rho.copy(),
            fresh=min(self.fresh + hop, n_frames),
        )


@dataclass
class SolverResult:
    """Output of :func:`solve`.

    positions: ``(T, S, 3)`` recovered A (m). sparse_error: ``(T, S, 3)`` E (m), NaN
    where unobserved. isometric: ``(T, S, 3)`` the isometry proxy N (m).
    primal_residuals: ``(iterations,)`` relative primal residual per iteration.
    """

    positions: np.ndarray
    sparse_error: np.ndarray
    isometric: np.ndarray
    iterations: int
    converged: bool
    primal_residuals: np.ndarray
    state: SolverState
    bone_lengths: np.ndarray | None = None
    params: SolverParams = field(default_factory=SolverParams)


def _soft(x: np.ndarray, tau: float | np.ndarray) -> np.ndarray:
    """Shrinkage S_tau(x) = sgn(x) max(|x| - tau, 0), entrywise."""
    return np.sign(x) * np.maximum(np.abs(x) - tau, 0.0)


def _paper_layout(x: np.ndarray) -> np.ndarray:
    """(T, S, 3) -> the paper's 3T x S matrix (Eq. 1)."""
    n_frames, n_joints, _ = x.shape
    return x.transpose(0, 2, 1).reshape(3 * n_frames, n_joints)


def _from_paper_layout(m: np.ndarray, n_frames: int) -> np.ndarray:
    return m.reshape(n_frames, 3, -1).transpose(0, 2, 1)


def _svt(y: np.ndarray, tau: float) -> np.ndarray:
    """Singular value thresholding U S_tau(Sigma) V^T of a (T, S, 3) array in 3T x S layout.

    Computed from the ``S x S`` Gram matrix M^T M = V Sigma^2 V^T (S joints << 3T rows):
    SVT(M) = M V diag(max(sigma - tau, 0) / sigma) V^T. Same result as a thin SVD to
    ~1e-12 on motion matrices, and cheaper.
    """
    n_frames = y.shape[0]
    m = _paper_layout(y)
    w, V = np.linalg.eigh(m.T @ m)
    sigma = np.sqrt(np.maximum(w, 0.0))
    keep = (sigma > tau) & (sigma > 1e-12 * max(float(sigma[-1]), 1e-300))
    if not keep.any():
        return np.zeros_like(y)
    V = V[:, keep]
    shrink = (sigma[keep] - tau) / sigma[keep]
    return _from_paper_layout(((m @ V) * shrink) @ V.T, n_frames)


def _rho0_rule(Dc: np.ndarray) -> float:
    """rho0 = 1.25 / ||D||_2 (inexact ALM, the paper's ref. [45]); D in the 3T x S layout."""
    return 1.25 / max(float(np.linalg.norm(_paper_layout(Dc), 2)), 1e-12)


def _center(D: np.ndarray, observed: np.ndarray, center: str) -> tuple[np.ndarray, np.ndarray]:
    """(offset ``(1, 1|J, 3)`` in metres, centred D with 0 on unobserved entries)."""
    obs3 = np.broadcast_to(observed[..., None], D.shape)
    if center == "none" or not observed.any():
        offset = np.zeros((1, 1, 3))
    elif center == "global":
        offset = np.nanmean(np.where(obs3, D, np.nan), axis=(0, 1), keepdims=True)
    else:
        cnt = observed.sum(axis=0)[None, :, None]
        offset = np.where(obs3, D, 0.0).sum(axis=0, keepdims=True) / np.maximum(cnt, 1)
    return offset, np.where(obs3, D - offset, 0.0)


def default_rho0(D: np.ndarray, observed: np.ndarray | None = None, center: str = "global") -> float:
    """The initial penalty :func:`solve` uses when ``SolverParams.rho0`` is None (1/m)."""
    D, observed, _ = _validate(D, observed, np.zeros((0, 2), dtype=np.intp))
    return _rho0_rule(_center(D, observed, center)[1])


def _validate(D: np.ndarray, observed: np.ndarray | None, bones: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    D = np.asarray(D, dtype=np.float64)
    if D.ndim != 3 or D.shape[2] != 3:
        raise ValueError(f"D must be (T, J, 3) positions in metres, got shape {D.shape}")
    n_frames, n_joints, _ = D.shape
    if observed is None:
        observed = np.ones((n_frames, n_joints), dtype=bool)
    observed = np.asarray(observed, dtype=bool)
    if observed.shape != (n_frames, n_joints):
        raise ValueError(f"observed must be (T, J) = {(n_frames, n_joints)}, got {observed.shape}")
    observed = observed & finite_points(D)
    bones = np.asarray(bones, dtype=np.intp).reshape(-1, 2)
    if bones.size and (bones.min() < 0 or bones.max() >= n_joints):
        raise ValueError(f"bones must index the {n_joints} joints of D, got indices up to {bones.max()}")
    return D, observed, bones


def solve(
    D: np.ndarray,
    observed: np.ndarray | None,
    bones: np.ndarray,
    bone_lengths: np.ndarray | None = None,
    params: SolverParams = SolverParams(),
    init: np.ndarray | None = None,
    state: SolverState | None = None,
    *,
    weights: np.ndarray | None = None,
) -> SolverResult:
    """Recover a motion with Algorithm 1 of Yang et al. (2019).

    D: ``(T, J, 3)`` positions (m), NaN allowed where not observed. observed: ``(T, J)``
    bool (None = every finite joint). bones: ``(B, 2)`` (parent, child). bone_lengths:
    ``(B,)`` m; None -> estimated from this window's observed frames by
    :func:`~streamfix.core.isometry.estimate_bone_lengths` (robust mode; the
    paper uses the skeleton's known lengths on CMU, pass them when known). init:
    ``(T, J, 3)`` replaces the default initialisation of A and N (e.g. a learned
    prior's prediction). state: a previous :class:`SolverState` of the same length
    (typically ``prev.state.shifted(hop)``) to warm-start from; wins over ``init``.
    weights: optional ``(T, J)`` or ``(T, J, 3)`` non-negative multipliers of lam per
    entry (weighted l1 on E): below 1 makes an entry cheaper to declare an outlier
    (e.g. 0.5 for Kinect *inferred* joints), 0 leaves it unpenalised. None = all 1.
    Raises ValueError when no joint is observed (there is nothing to recover from).
    """
    D, observed, bones = _validate(D, observed, bones)
    n_frames, n_joints, _ = D.shape
    p = params
    use_iso = p.mode in ("yang", "li") and len(bones) > 0 and p.gamma > 0
    # a window shorter than 2**level frames gets the deepest level it can hold (none for
    # a single frame), so the stream's first frames can be solved too
    level = min(p.level, int(np.floor(np.log2(max(n_frames, 1)))))
    use_wav = p.mode == "yang" and level >= 1
    W = TemporalWavelet(n_frames, p.wavelet, level) if use_wav else None
    if not observed.any():
        raise ValueError(f"no observed joint in the {n_frames}-frame window: nothing to solve")
    lam = p.lam if p.lam is not None else 1.0 / np.sqrt(n_frames)
    if weights is not None:
        weights = np.asarray(weights, dtype=np.float64)
        if weights.shape == (n_frames, n_joints):
            weights = weights[..., None]
        if weights.shape not in ((n_frames, n_joints, 1), D.shape) or not (weights >= 0).all():
            raise ValueError(f"weights must be non-negative, (T, J) = {(n_frames, n_joints)} or (T, J, 3), got {weights.shape}")
        lam = lam * weights  # lam_ij: per-entry threshold of Eq. (12)

    if bone_lengths is None:
        bone_lengths = estimate_bone_lengths(D, bones, observed) if len(bones) else np.zeros(0)
    else:
        bone_lengths = np.asarray(bone_lengths, dtype=np.float64)
        if bone_lengths.shape != (len(bones),):
            raise ValueError(f"bone_lengths must be ({len(bones)},) metres, got {bone_lengths.shape}")

    # --- centring (Section "center" in SolverParams): D <- D - m on observed entries
    obs3 = np.broadcast_to(observed[..., None], D.shape)
    offset, Dc = _center(D, observed, p.center)  # unobserved entries of Dc: 0, never data

    d_fro = float(np.linalg.norm(Dc))
    if d_fro == 0.0:
        d_fro = 1.0
    rho0 = (p.rho0 if p.rho0 is not None else _rho0_rule(Dc)) * p.rho0_scale

    # --- Algorithm 1, line 2: initialisation
    zeros = np.zeros_like(Dc)
    if state is not None:
        if state.A.shape != D.shape:
            raise ValueError(f"state is for {state.A.shape} arrays, D is {D.shape}")
        A = state.A - offset
        E = np.where(obs3, state.E, 0.0)
        N = state.N - offset
        Z1 = np.where(obs3, state.Z1, 0.0)
        Z2 = state.Z2.copy()
        Ct = state.Ct - offset
        if state.fresh > 0:
            # New frames start from their own (gap-filled) data, as N^0 = D does in a cold
            # start; repeating the previous last frame there measured worse on the new frames.
            f = slice(n_frames - state.fresh, n_frames)
            filled = np.nan_to_num(interpolate_linear(np.where(obs3, Dc, np.nan), observed)[0])
            A[f], N[f], Ct[f] = filled[f], filled[f], filled[f]
        C = W.forward(Ct) if use_wav else zeros.copy()
        Z3 = W.forward(state.Z3t) if use_wav else zeros.copy()
        rho_start = rho0 * p.eta**p.warm_skip
        rho = np.full(3, rho_start)
    else:
        if init is not None:
            init = np.asarray(init, dtype=np.float64)
            if init.shape != D.shape:
                raise ValueError(f"init must be {D.shape} like D, got {init.shape}")
            A = init - offset
            N = A.copy()
        else:
            A = zeros.copy()                                  # A^0 = 0
            # N^0 = D, gaps filled by linear interpolation over time (0 = mean if never seen)
            N = np.nan_to_num(interpolate_linear(np.where(obs3, Dc, np.nan), observed)[0])
        E = zeros.copy()                                      # E^0 = 0
        Z1, Z2, Z3 = zeros.copy(), zeros.copy(), zeros.copy() # Z^0 = 0
        C = W.forward(A) if use_wav else zeros.copy()
        rho = np.full(3, rho0)                                # rho1 = rho2 = rho3 = rho0

    if use_wav and p.detail_only:
        shrink_mask = W.detail[:, None, None]  # mu applies to detail rows only
    else:
        shrink_mask = None
    iso_bones = bones[np.isfinite(bone_lengths)] if use_iso else bones
    iso_lengths = bone_lengths[np.isfinite(bone_lengths)] if use_iso else bone_lengths

    residuals = []
    converged = False
    k = 0
    WA = W.forward(A) if use_wav else None
    for k in range(1, p.max_iter + 1):
        rho1, rho2, rho3 = rho
        # line 4-5, Eq. (20): N^{k+1} = N^k + (gamma J^T J + rho2 I)^-1 (-Z2 - rho2 (N - A) - gamma J^T F)
        if use_iso:
            for _ in range(p.gn_steps):
                if p.center == "channel":  # bone vectors need absolute positions
                    N = gauss_newton_step(N + offset, A + offset, Z2, rho2, p.gamma, iso_bones, iso_lengths) - offset
                else:  # a global offset cancels in n_i - n_j
                    N = gauss_newton_step(N, A, Z2, rho2, p.gamma, iso_bones, iso_lengths)
        # line 6, Eq. (11): C^{k+1} = S_{mu/rho3}(W A^k - Z3/rho3)
        if use_wav:
            V = WA - Z3 / rho3
            if shrink_mask is None:
                C = _soft(V, p.mu / rho3)
            else:
                C = np.where(shrink_mask, _soft(V, p.mu / rho3), V)
        # line 7, Eq. (12): E^{k+1} = S_{lam/rho1}(D - A^k - Z1/rho1) on observed entries;
        # free (no shrinkage) on unobserved ones, where it equals -A^k - Z1/rho1 with D := 0.
        R = Dc - A - Z1 / rho1
        E = np.where(obs3, _soft(R, lam / rho1), R)
        # lines 8-11, Eq. (14): A^{k+1} = SVT_{1/sum rho}(sum rho_i H_i / sum rho_i)
        H = rho1 * (Dc - E - Z1 / rho1)                       # rho1 H1
        rsum = rho1
        if use_iso:
            H = H + rho2 * (N + Z2 / rho2)                    # rho2 H2
            rsum += rho2
        if use_wav:
            H = H + rho3 * W.inverse(C + Z3 / rho3)           # rho3 H3, H3 = W^T C + W^T Z3 / rho3
            rsum += rho3
        A = _svt(H / rsum, 1.0 / rsum)
        # lines 12-14: multiplier updates
        r1 = E - Dc + A
        Z1 = Z1 + rho1 * r1
        res2 = float(np.sum(r1[obs3] ** 2))
        if use_iso:
            r2 = N - A
            Z2 = Z2 + rho2 * r2
            res2 += float(np.sum(r2**2))
        if use_wav:
            WA = W.forward(A)                                 # reused by the next C-step
            r3 = C - WA
            Z3 = Z3 + rho3 * r3
            res2 += float(np.sum(r3**2))
        # lines 15-17: rho^{k+1} = eta rho^k
        rho = rho * p.eta
        residuals.append(np.sqrt(res2) / d_fro)
        if residuals[-1] < p.tol:
            converged = True
            break

    out_state = SolverState(
        A=A + offset,
        E=np.where(obs3, E, 0.0),
        Ct=(W.inverse(C) if use_wav else A) + offset,
        N=(N if use_iso else A) + offset,
        Z1=np.where(obs3, Z1, 0.0),
        Z2=Z2 if use_iso else zeros.copy(),
        Z3t=W.inverse(Z3) if use_wav else zeros.copy(),
        rho=rho.copy(),
        rho0=float(rho0),
        bone_lengths=bone_lengths,
        iterations=k,
    )
    return SolverResult(
        positions=A + offset,
        sparse_error=np.where(obs3, E, np.nan),
        isometric=(N if use_iso else A) + offset,
        iterations=k,
        converged=converged,
        primal_residuals=np.asarray(residuals),
        state=out_state,
        bone_lengths=bone_lengths,
        params=p,
    )
