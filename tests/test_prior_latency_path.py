"""The streaming bridge's prior fill (``fill_long_gaps``, D(z*)) against a reference built from the general code.

The latency path validates its input once, uses per-layout index maps built once and fits the one
window of a stream; the reference below goes the long way on the same real Kinect v2 take: the
public canonical mapping, windows cut with NaN and zeroed, ``fit_latent`` on a *batch* (its general
multi-window code) holding the window's mirror image too (``MIRROR_ENSEMBLE``: the two fits are
averaged, the mirrored one mirrored back), the public ``from_canonical`` and the gap offsets frame by frame. The fills must
agree to 1e-6 m. ``normalise`` is checked against textbook numpy (np.interp, np.median, the
Procrustes sums) on windows whose root is observed, missing (hips fallback) or gone with the hips.
"""
from __future__ import annotations

import numpy as np
import pytest

from streamfix.canonical import CANONICAL_BONES, CANONICAL_MIRROR, from_canonical, to_canonical
from streamfix.prior.data import CANONICAL_NORM, cut_windows, load_take
from streamfix.prior.init import CHORD_DAMPING, CHORD_STEPS, MIRROR_ENSEMBLE, fill_long_gaps
from streamfix.prior.latent import fit_latent
from streamfix.prior.normalize import normalise, rot_y
from streamfix.prior.runtime import load_default_prior
from streamfix.skeletons import KINECT_V2

LEG = [KINECT_V2.index(n) for n in ("HipRight", "KneeRight", "AnkleRight", "FootRight")]


@pytest.fixture(scope="module")
def take(shared_data):
    return load_take(shared_data / "kinect_v2" / "Ges04_comehere.csv")


def _reference_fill(prior, x, obs, min_gap_frames, other_window):
    """fill_long_gaps(..., prior=prior) of a Kinect v2 window (<= one prior window at 30 Hz), the long way."""
    cx, cobs = to_canonical(x, obs, "kinect_v2")
    wins, masks, _ = cut_windows(cx, cobs, prior.window)
    assert len(wins) == 1
    flip = np.array([-1.0, 1.0, 1.0])
    mirrored = np.nan_to_num(wins[0])[:, CANONICAL_MIRROR] * flip  # x negated, left and right swapped
    batch = np.concatenate([wins, other_window[0], mirrored[None]])
    batch_masks = np.concatenate([masks, other_window[1], masks[:, :, CANONICAL_MIRROR]])
    fit = fit_latent(prior, np.nan_to_num(batch), batch_masks, max_iter=CHORD_STEPS, jacobian_steps=0,
                     damping=CHORD_DAMPING)  # the general batch code (B = 3)
    assert MIRROR_ENSEMBLE  # the default: the window and its mirror image, the second mirrored back
    canonical_est = 0.5 * (fit.decoded[0] + fit.decoded[2][:, CANONICAL_MIRROR] * flip)
    return _gap_fill(from_canonical(canonical_est[:len(x)], "kinect_v2", x, obs), x, obs, min_gap_frames)


def _gap_fill(est, x, obs, min_gap_frames):
    """The gaps of >= min_gap_frames filled from est (T, J, 3), offset to meet the observed ends."""
    out = np.where(obs[..., None], x, np.nan)
    for j in range(x.shape[1]):  # joints and their gaps, one at a time
        seen = np.flatnonzero(obs[:, j])
        for t in np.flatnonzero(~obs[:, j]):
            before, after = seen[seen < t], seen[seen > t]
            t0 = before[-1] if len(before) else -1
            t1 = after[0] if len(after) else len(x)
            if t1 - t0 - 1 < min_gap_frames:
                continue
            d0 = x[t0, j] - est[t0, j] if len(before) else None
            d1 = x[t1, j] - est[t1, j] if len(after) else None
            d0, d1 = (d1, d1) if d0 is None else (d0, d0) if d1 is None else (d0, d1)
            a = (t - t0) / (t1 - t0)
            out[t, j] = est[t, j] + ((1 - a) * d0 + a * d1 if d0 is not None else 0.0)
    return out


@pytest.mark.parametrize("start, pattern", [(0, "leg"), (56, "leg"), (84, "leg_and_random"), (112, "edges")])
def test_fill_long_gaps_matches_the_general_code(take, start, pattern):
    prior = load_default_prior()
    x = np.nan_to_num(take.positions[start:start + 60])
    obs = take.observed[start:start + 60].copy()
    rng = np.random.default_rng(start)
    if pattern in ("leg", "leg_and_random"):
        obs[:, LEG] = False  # the bench's case: the right leg missing for the whole window
    if pattern == "leg_and_random":
        obs &= rng.random(obs.shape) > 0.2
    if pattern == "edges":  # gaps at the window's start and end, and one inside
        obs[:20, LEG[:2]] = False
        obs[45:, LEG[2:]] = False
        obs[10:40, KINECT_V2.index("ElbowLeft")] = False
        obs[5:30, KINECT_V2.index("HandTipLeft")] = False  # not a canonical joint: placed along the hand
    assert obs.any(axis=0).sum() >= 15
    # a second, different window in the reference's batch: the batch code keeps windows apart
    cx2, cobs2 = to_canonical(take.positions[108:172], take.observed[108:172], "kinect_v2")
    other = (np.nan_to_num(cx2)[None], (cobs2 & (rng.random(cobs2.shape) > 0.5))[None])
    got, filled = fill_long_gaps(x, obs, 30.0, min_gap_frames=15, prior=prior)
    want = _reference_fill(prior, x, obs, 15, other)
    assert filled.any() and np.array_equal(np.isfinite(got).all(axis=2), np.isfinite(want).all(axis=2))
    np.testing.assert_allclose(got[filled], want[filled], rtol=0, atol=1e-6)
    np.testing.assert_array_equal(got[obs], x[obs])


def _reference_normalise(pos, obs, bones, ref, template, root, hips, scale_bones):
    """normalise's definition (module doc of streamfix.prior.normalize) in plain numpy."""
    t = np.arange(len(pos))
    if obs[:, root].any():
        track, valid = pos[:, root], obs[:, root]
    elif (obs[:, hips[0]] & obs[:, hips[1]]).any():
        track, valid = 0.5 * (pos[:, hips[0]] + pos[:, hips[1]]), obs[:, hips[0]] & obs[:, hips[1]]
    else:
        valid = obs.any(axis=1)
        track = np.array([pos[i][obs[i]].mean(axis=0) if valid[i] else np.zeros(3) for i in t])
    r = np.stack([np.interp(t, t[valid], track[valid, c]) for c in range(3)], axis=1)
    ratios = []
    for b, (p, c) in enumerate(bones):
        both = obs[:, p] & obs[:, c]
        if c in scale_bones and ref[b] > 1e-6 and both.any():
            ratios.append(np.median(np.linalg.norm(pos[both, c] - pos[both, p], axis=-1)) / ref[b])
    k = float(np.clip(np.median(ratios), 0.5, 2.0)) if ratios else 1.0
    y = np.where(obs[..., None], (pos - r[:, None]) / k, 0.0)
    s = np.sum(template[None, :, 0] * y[..., 2] - template[None, :, 2] * y[..., 0])
    c = np.sum(template[None, :, 0] * y[..., 0] + template[None, :, 2] * y[..., 2])
    theta = float(np.arctan2(s, c))
    return np.where(obs[..., None], y @ rot_y(theta).T, 0.0), r, k, theta


@pytest.mark.parametrize("case", ["root_seen", "root_missing", "hips_missing", "gaps_in_time"])
def test_normalise_matches_its_definition(take, case):
    prior = load_default_prior()
    cx, cobs = to_canonical(take.positions[100:164], take.observed[100:164], "kinect_v2")
    pos, obs = np.nan_to_num(cx), cobs.copy()
    hips = CANONICAL_NORM["hips"]
    if case in ("root_missing", "hips_missing"):
        obs[:, CANONICAL_NORM["root"]] = False
    if case == "hips_missing":
        obs[:, hips[0]] = False
    if case == "gaps_in_time":
        obs[:10] = False
        obs[30:35, CANONICAL_NORM["root"]] = False
        obs[50:] = False
    template = prior.facing_template
    y, norm = normalise(pos, obs, CANONICAL_BONES, prior.reference_lengths, template=template, **CANONICAL_NORM)
    want_y, want_r, want_k, want_theta = _reference_normalise(pos, obs, CANONICAL_BONES, prior.reference_lengths,
                                                              template, **CANONICAL_NORM)
    np.testing.assert_allclose(norm.root, want_r, rtol=0, atol=1e-12)
    assert norm.scale == pytest.approx(want_k, abs=1e-12) and norm.theta == pytest.approx(want_theta, abs=1e-12)
    np.testing.assert_allclose(y, want_y, rtol=0, atol=1e-12)
    # the model's own constants (Prior.norm_spec, what fit_latent uses) give the same window
    y2, obs2, norms2 = prior.normalise(np.where(obs[..., None], pos, np.nan)[None], obs[None])
    np.testing.assert_array_equal(y2[0], y)
    np.testing.assert_array_equal(obs2[0], obs)
    assert norms2[0].scale == norm.scale and norms2[0].theta == norm.theta


class _NoPrior:
    """The default prior that says which layouts it maps (its card) but fails the test when anything
    else of it is read: its window, rate or networks (a fit)."""

    def __init__(self):
        self.card, self.n_joints = load_default_prior().card, load_default_prior().n_joints

    def __getattr__(self, name):
        raise AssertionError(f"the prior was used ({name}) where the observed anchors place the joints")


@pytest.mark.parametrize("lost", [("HandTipLeft",), ("HandTipLeft", "ThumbLeft", "HandTipRight")])
def test_lost_joints_the_canonical_body_lacks_ride_on_their_observed_anchors_without_a_fit(take, lost):
    """A hand tip or thumb sits at its anchor + k (anchor - anchor's parent) + d whatever the prior
    says (from_canonical's rule): with the anchors observed no latent fit is run (it cost 12 ms a
    streamed window) and the observed anchors place them."""
    x = np.nan_to_num(take.positions[82:134])  # every joint observed in these frames
    obs = take.observed[82:134].copy()
    assert obs.all()
    cols = [KINECT_V2.index(n) for n in lost]
    obs[:, cols[0]] = False  # never seen in the window
    obs[10:40, cols[1:]] = False  # seen before and after a long gap
    got, filled = fill_long_gaps(x, obs, 30.0, min_gap_frames=15, prior=_NoPrior())
    canonical, _ = to_canonical(x, obs, "kinect_v2")
    want = _gap_fill(from_canonical(canonical, "kinect_v2", x, obs), x, obs, 15)
    assert filled[:, cols].any(axis=0).all() and not filled[:, [j for j in range(25) if j not in cols]].any()
    np.testing.assert_allclose(got[filled], want[filled], rtol=0, atol=1e-9)
    hand = KINECT_V2.index("HandLeft")
    np.testing.assert_allclose(got[:, cols[0]], x[:, hand], atol=1e-9)  # never seen: at its observed anchor


def test_a_lost_hand_tip_with_its_hand_lost_too_is_the_prior_s(take):
    x = np.nan_to_num(take.positions[40:100])
    obs = take.observed[40:100].copy()
    obs[:, [KINECT_V2.index("HandTipLeft"), KINECT_V2.index("HandLeft")]] = False
    with pytest.raises(AssertionError, match="the prior was used"):
        fill_long_gaps(x, obs, 30.0, min_gap_frames=15, prior=_NoPrior())
    got, filled = fill_long_gaps(x, obs, 30.0, min_gap_frames=15, prior=load_default_prior())
    assert filled[:, KINECT_V2.index("HandTipLeft")].all() and np.isfinite(got[filled]).all()
