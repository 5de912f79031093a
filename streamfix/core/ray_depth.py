"""Joints a depth sensor put at the wrong depth along their own camera ray.

Why: a sensor that measures depth per pixel (stereo, time of flight) places a joint where
its image position meets the depth it reads there. Where a thin limb (a wrist, a hand, a
shin) lies on the body's silhouette, that depth can come from the wall behind it or from
something in front: a DepthAI spatial keypoint takes the median depth within 10 px of the
2-D keypoint, which flips to the background once most of those pixels miss the limb. The
joint is then thrown metres back *along the ray from the camera through it*, while its
image position, the part the pose network got right, is kept. Such runs last as long as the
limb stays on the edge (seconds), so the window's robust temporal fit follows them and the
bone projection splits the error between the two ends; the live gate re-acquires the new
place after a few frames.

The repair: a joint whose bone to its parent is longer than the body's length by
``FRACTION`` of it and ``FLOOR_M``, whose camera ray passes within the bone's length of the
parent (moving it along the ray can give the bone its length back) and whose parent sits
where its own bone allows, is moved along its ray to the point at the bone's length from the
parent: ``|s u - p| = L`` with ``u`` the unit ray through the joint, two roots
``s = u.p +- sqrt(L^2 - |p|^2 + (u.p)^2)``. Where the joint's own seen children (an ankle for a
knee) lie at their bones' lengths from only one of the two, that one is taken (near the edge of
the sphere the two lie close, and a swinging leg crosses from one to the other); else the root
nearest the joint's offset to its parent in the good samples around it (interpolated in time),
else the one on the sensor's side of the two (the wall the depth came from is behind the limb),
unless that one lies behind the sensor. Where a joint is expected (a thrown sample departs from
that along its ray, a good one whose parent was thrown does not) is where its own good samples
around put it, linear in time; more than ``STALE_S`` from any of them (a throw from a take's
first frames on, the body moving on), where its parent carries the joint's offset in them.
Parents first: an elbow put back moves the point its wrist is judged from. A joint two bones
end at (MediaPipe's graph) is judged by the later-listed one.

Lengths: the body's (the engine's estimate); before it has one (a stream's first second, when
a person walking into view is most often half on the silhouette's edge) the median of the raw
frames at hand (:func:`provisional_lengths`), with only gross throws judged
(``PROVISIONAL_FLOOR_M``). Either way a sample longer than ``MAX_BONE_M`` is no person's bone
and makes no length (both wrists thrown for most of a take leave both forearms' medians at the
wall, where no left/right comparison can tell).

The coordinates must be a sensor's camera space (the sensor at the origin): the caller
says so by the layout (depth sensors and pose estimators, not optical markers or BVH), and a
frame whose seen joints' median is nearer the origin than ``MIN_SENSOR_DISTANCE_M`` (a take re-centred on
the body) is left alone.

Arrays: positions ``(T, J, 3)`` metres, confidence ``(T, J)``, bones ``(B, 2)`` (parent, child).
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from .bone_rotations import depth_levels
from .excursion import bone_into, parents_from_bones
from .interpolate import interpolate_linear, neighbour_observations
from .isometry import thrown_twins
from .points import finite_points, point_dots, point_norms
from .robust_stats import nanmedian

__all__ = ["repair_ray_depth", "reference_rules_out_throws", "provisional_lengths", "PROVISIONAL_MIN_FRAMES", "PROVISIONAL_FLOOR_M", "MAX_BONE_M", "STALE_S", "FRACTION", "FLOOR_M", "RAY_SLACK", "RAY_NOISE_M", "MIN_DEPARTURE_M", "SIDEWAYS_RATIO",
           "PROXIMAL_FRACTION", "MIN_SENSOR_DISTANCE_M", "CHILD_FIT", "CHILD_MARGIN_M"]

FRACTION = 0.5
"""A bone longer than the body's length by this fraction of it (and ``FLOOR_M``) is judged."""

FLOOR_M = 0.08
"""...and by this much (m): a depth read off the background is decimetres to metres off,
while a Kinect's or a stereo camera's depth noise moves a joint by a few centimetres."""

RAY_SLACK = 0.1
"""The ray may pass up to this fraction of the bone's length beyond it from the parent (the
joint then goes to the ray's point nearest the parent): the body's length is an estimate."""

RAY_NOISE_M = 0.03
"""...and this much (m): the joints' own noise moves a short bone's ray (a hand's, 8 cm) off it."""

MIN_DEPARTURE_M = 0.25
"""...and it must lie this far (m) along its ray from where its own samples around put it: a
depth read off the background is decimetres to metres off, while a hand thrown 12 cm down and
back is off its ray by centimetres, and the dislocated-end stage, which interpolates its offset
to the wrist across the run, places it better (``tests/test_dislocated.py``)."""

SIDEWAYS_RATIO = 0.5
"""A sample whose departure from where it is expected has a part across the ray larger than
this times its part along the ray was not thrown along it (a random-direction jump)."""

CHILD_FIT = 0.25
"""A thrown joint's seen children choose between the two points on its ray only where one point
puts each of them within this fraction of its bone's length (or ``RAY_NOISE_M``)..."""

CHILD_MARGIN_M = 0.03
"""...and puts them closer to their lengths than the other point does by this much (m) per child."""

PROXIMAL_FRACTION = 0.25
"""The parent is trusted only where its own bone is within this fraction of its length, or of
``floor_m`` (a bone does not say which end is wrong; a parent off its length is judged first, or
not; a hip 8 cm from the pelvis is off by a quarter of it with 2 cm of a sensor's noise)."""

MIN_SENSOR_DISTANCE_M = 0.5
"""A frame whose joints' median lies nearer the origin than this is not in a sensor's camera space."""

STALE_S = 0.2
"""With the rate known, a sample further than this (s) from its joint's own good samples is
expected where its parent carries the joint's offset in them, not where they lie in the room."""

MAX_BONE_M = 0.75
"""No bone of a person in these layouts is longer (m; a tall adult's thigh is about half a metre):
a sample longer is a throw whatever its twin's says, and a length is never made of it (both
wrists at the wall's depth for most of a take leave both forearms' medians there)."""

PROVISIONAL_MIN_FRAMES = 1
"""Frames a bone must be seen in before :func:`provisional_lengths` gives it a length: one, as
samples longer than ``MAX_BONE_M`` make none (at 3, a live stream whose hand was thrown from its
second frame on passed the throw through for two frames, much of the run's mean error)."""

PROVISIONAL_FLOOR_M = 0.25
"""``floor_m`` while the lengths are provisional: a median of a stream's first frames is
rough, and a live path's last output is not settled yet, so only a gross throw (the wall
is metres behind) is judged; at ``FLOOR_M`` a Kinect v2's hand 4 cm off in its first half
second (KERAAL, against Vicon) was pushed far back along its ray."""


def provisional_lengths(lengths: np.ndarray, mirror: np.ndarray | None) -> np.ndarray:
    """``(B,)`` bone lengths (m) to judge throws by before a body's own lengths are known.

    Why: the engine trusts a body's lengths only after about a second of well-supported
    samples, and until then nothing is judged, while a person walking into view is where a
    depth sensor reads the wall behind a limb most. ``lengths`` ``(N, B)``: raw bone lengths of
    the frames at hand (a window's, or the live path's memory of the stream so far; NaN where an
    end is not seen, :func:`~streamfix.core.isometry.seen_bone_lengths`); samples longer than
    :data:`MAX_BONE_M` are left out, and each bone takes its median over the rest (a throw that
    lasts less than half of those frames does not move it), NaN with fewer than
    :data:`PROVISIONAL_MIN_FRAMES`. A bone left NaN, or still twice its left/right twin's and a
    quarter metre longer (a throw from the first frame on:
    :func:`~streamfix.core.isometry.thrown_twins`), takes the twin's. ``mirror`` ``(B,)``: each
    bone's counterpart (None: no twins)."""
    n = np.asarray(lengths, dtype=np.float64)
    if n.ndim != 2:
        raise ValueError(f"lengths must be (frames, bones), got {n.shape}")
    with np.errstate(invalid="ignore"):
        n = np.where(n > MAX_BONE_M, np.nan, n)
    est = np.where(np.isfinite(n).sum(axis=0) >= PROVISIONAL_MIN_FRAMES, nanmedian(n, axis=0), np.nan)
    if mirror is not None and len(est):
        m = np.asarray(mirror, dtype=np.intp)
        est = np.where(thrown_twins(est, m) | np.isnan(est), est[m], est)  # unseen or thrown: the twin's
    return est


def _carried_by_parent(world: np.ndarray, x: np.ndarray, own_good: np.ndarray, seen: np.ndarray, cols: np.ndarray,
                       parents: np.ndarray, stale_frames: int) -> np.ndarray:
    """``world`` ``(T, n, 3)`` (joints ``cols`` where their own good samples put them, linear in
    time) with the samples more than ``stale_frames`` from any good one replaced by their parent's
    position plus the joint's offset to it in the good samples (linear in time)."""
    T = len(x)
    prev, nxt = neighbour_observations(own_good)
    t = np.arange(T)[:, None]
    stale = np.minimum(np.where(prev >= 0, t - prev, T), np.where(nxt < T, nxt - t, T)) > stale_frames
    if not stale.any():
        return world
    rel_good = own_good & seen[:, parents]
    offset = np.where(rel_good[..., None], x[:, cols] - x[:, parents], np.nan)
    carried = interpolate_linear(offset, rel_good)[0] + x[:, parents]
    use = stale & finite_points(carried)
    return np.where(use[..., None], carried, world)


@lru_cache(maxsize=64)
def _child_table(parents_bytes: bytes) -> np.ndarray:
    """``(J, C)`` each joint's children (-1 padded; ``C`` >= 1), read-only; ``parents_bytes``: a
    ``(J,)`` intp parent array's ``tobytes()`` (the key it is cached by)."""
    parents = np.frombuffer(parents_bytes, dtype=np.intp)
    J = len(parents)
    counts = np.bincount(parents[parents >= 0], minlength=J)
    table = np.full((J, max(1, int(counts.max()) if J else 1)), -1, dtype=np.intp)
    for j in np.flatnonzero(counts):  # once per skeleton, over its joints
        kids = np.flatnonzero(parents == j)
        table[j, :len(kids)] = kids
    table.flags.writeable = False
    return table


def _children_choose(x: np.ndarray, seen: np.ndarray, length: np.ndarray, kids: np.ndarray, near: np.ndarray,
                     far: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(told, near_is_it)`` ``(T, n)``: where the seen children ``kids`` ``(n, C)`` of ``n`` thrown
    joints tell the two points on each one's ray apart (each child at its bone's length from one
    of them within ``CHILD_FIT``, and that one closer to it by ``CHILD_MARGIN_M`` over the
    children), and whether the near point is the one."""
    has = kids >= 0
    k = np.maximum(kids, 0)
    L = np.where(has, length[k], np.nan)  # (n, C)
    use = has[None] & seen[:, k] & np.isfinite(L)[None]  # (T, n, C)
    if not use.any():
        return np.zeros(near.shape[:2], dtype=bool), np.zeros(near.shape[:2], dtype=bool)
    pos = x[:, k]  # (T, n, C, 3)
    miss_near = np.abs(point_norms(pos - near[:, :, None]) - L[None])
    miss_far = np.abs(point_norms(pos - far[:, :, None]) - L[None])
    cost_near = np.where(use, miss_near, 0.0).sum(axis=2)
    cost_far = np.where(use, miss_far, 0.0).sum(axis=2)
    tol = np.where(use, np.maximum(CHILD_FIT * L[None], RAY_NOISE_M), 0.0).sum(axis=2)
    n_used = use.sum(axis=2)
    told = (n_used > 0) & (np.minimum(cost_near, cost_far) <= tol) & (np.abs(cost_near - cost_far) > CHILD_MARGIN_M * n_used)
    return told, cost_near < cost_far


def reference_rules_out_throws(
    frame: np.ndarray,
    seen: np.ndarray,
    child: np.ndarray,
    parent: np.ndarray,
    length: np.ndarray,
    reference: np.ndarray,
    *,
    floor_m: float = FLOOR_M,
) -> bool:
    """True when :func:`repair_ray_depth` of this one frame, judged against ``reference``, would
    move no joint; False when it might (then run it).

    Why: a live path calls the repair on the frames with a stretched bone (a Kinect's noise
    stretches a hand tip's 8 cm bone now and then), and the repair, made for windows, costs
    several whole live steps on one frame. A stretched joint is moved
    only when its sample departs from where it is expected by more than
    ``max(FRACTION L, MIN_DEPARTURE_M)`` along its ray, and a departure along the ray is at
    most the sample's distance from the reference: a joint within that distance of its
    reference (finite, and not itself stretched from its parent: the repair then expects
    nothing) is left alone, and with no joint moved no child is judged anew.

    ``frame`` ``(J, 3)`` m, ``seen`` ``(J,)`` bool (observed and finite), ``reference`` ``(J, 3)``
    m (the last output); ``child``, ``parent`` ``(n,)`` int and ``length`` ``(n,)`` m: each
    judged joint, the parent it is judged from (:func:`~streamfix.core.excursion.bone_into`'s
    bone) and that bone's length (NaN: not judged). ``floor_m`` as the repair's.
    """
    judged = np.isfinite(length) & (length > 0)
    bone = point_norms(frame[child] - frame[parent])
    with np.errstate(invalid="ignore"):
        stretched = seen[child] & seen[parent] & judged & (bone - length > np.maximum(FRACTION * length, floor_m))
    if not stretched.any():
        return True
    c, p, L = child[stretched], parent[stretched], length[stretched]
    ref, ref_p = reference[c], reference[p]
    with np.errstate(invalid="ignore"):
        ref_stretched = point_norms(ref - ref_p) - L > np.maximum(FRACTION * L, floor_m)
        # a hair inside the bound: the repair's departure is a dot product with a unit ray, rounded
        near = point_norms(frame[c] - ref) <= np.maximum(FRACTION * L, MIN_DEPARTURE_M) * (1.0 - 1e-9)
    return bool((finite_points(ref) & ~ref_stretched & near).all())


def repair_ray_depth(
    positions: np.ndarray,
    confidence: np.ndarray,
    bones: np.ndarray,
    bone_lengths: np.ndarray | None,
    *,
    fraction: float = FRACTION,
    floor_m: float = FLOOR_M,
    ray_slack: float = RAY_SLACK,
    proximal_fraction: float = PROXIMAL_FRACTION,
    joints: np.ndarray | None = None,
    reference: np.ndarray | None = None,
    rate_hz: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``(positions, repaired)``: the samples judged thrown along their camera ray (module doc)
    moved back along it to their bone's length, and the ``(T, J)`` bool mask of those samples.

    ``bone_lengths`` ``(B,)`` m: the body's lengths (NaN: that bone is not judged; None:
    nothing is). ``joints`` ``(J,)`` bool: only these joints are judged (None = every one).
    ``reference`` ``(T, J, 3)`` m: where each joint is expected (NaN: unknown; a reference
    joint whose own bone is stretched counts as unknown), in place of the interpolation
    between its good samples: a causal caller (the live path, one frame at a time) passes
    its last output. ``rate_hz`` (Hz): without a reference, samples more than ``STALE_S`` from
    their joint's good ones are expected where the parent carries them (None: never)."""
    x = np.array(positions, dtype=np.float64)
    conf = np.asarray(confidence, dtype=np.float64)
    T, J = conf.shape
    done = np.zeros((T, J), dtype=bool)
    b = np.asarray(bones, dtype=np.intp).reshape(-1, 2)
    if T == 0 or not len(b) or bone_lengths is None:
        return x, done
    into = bone_into(b, J)
    parents = parents_from_bones(b, J).astype(np.intp)
    length = np.where(into >= 0, np.asarray(bone_lengths, dtype=np.float64)[np.maximum(into, 0)], np.nan)
    judged = np.isfinite(length) & (length > 0)
    if joints is not None:
        judged &= np.asarray(joints, dtype=bool)
    if not judged.any():
        return x, done
    seen = (conf > 0) & finite_points(x)
    pj = np.where(parents >= 0, parents, 0)

    def stretched(pos: np.ndarray, cols: np.ndarray | slice = slice(None)) -> np.ndarray:
        """(T, len(cols)) bool: the joints ``cols`` whose bone to their parent is stretched."""
        p, L = pj[cols], length[cols]
        bone = point_norms(pos[:, cols] - pos[:, p])
        return seen[:, cols] & seen[:, p] & judged[cols] & (bone - L > np.maximum(fraction * L, floor_m))

    raw_stretched = stretched(x)
    if not raw_stretched.any():  # the common case: nothing to judge
        return x, done
    # what follows is worked out only for the joints and frames that need it (a sensor's noise
    # stretches a short bone now and then: most windows judge a few joints, if any)
    own = np.full((T, J, 3), np.nan)  # where each joint is expected; filled per joint on demand
    ref = None if reference is None else np.asarray(reference, dtype=np.float64)
    own_known = np.zeros(J, dtype=bool)

    def expected(cols: np.ndarray) -> np.ndarray:
        """``own[:, cols]``: where each of the joints ``cols`` is expected (see below)."""
        need = cols[~own_known[cols]]
        if len(need):
            if reference is None:
                # where each joint's own good samples around a run put it: a sample thrown along its
                # ray departs from that along the ray, while a good one whose parent was thrown (or
                # put back at the wrong one of its two roots) does not (linear in time, joint by joint)
                own_good = seen[:, need] & ~raw_stretched[:, need]
                own[:, need] = interpolate_linear(np.where(own_good[..., None], x[:, need], np.nan), own_good)[0]
                if rate_hz is not None:
                    own[:, need] = _carried_by_parent(own[:, need], x, own_good, seen, need, pj[need],
                                                      int(round(STALE_S * rate_hz)))
            else:
                own[:, need] = ref[:, need]
                # a reference that took the throw itself (the live output followed a joint thrown
                # before the body's lengths were known) says nothing of where the joint belongs
                ref_bone = point_norms(ref[:, need] - ref[:, pj[need]])
                with np.errstate(invalid="ignore"):
                    took = judged[need][None, :] & (ref_bone - length[need] > np.maximum(fraction * length[need], floor_m))
                own[:, need] = np.where(took[..., None], np.nan, own[:, need])
            own_known[need] = True
        return own[:, cols]

    x_raw = np.asarray(positions)  # the medians below are of the raw frames, whatever the levels move
    camera = np.zeros(T, dtype=bool)
    camera_known = np.zeros(T, dtype=bool)

    def in_camera_space(rows: np.ndarray) -> np.ndarray:
        """The ``(T,)`` mask of frames whose seen joints' median lies at least ``MIN_SENSOR_DISTANCE_M``
        from the origin (the thrown joints themselves do not move a median), worked out for the
        frames ``rows`` ``(T,)`` bool and those asked for before (False at the others)."""
        need = rows & ~camera_known
        if need.any():
            centre = nanmedian(np.where(seen[need][..., None], x_raw[need], np.nan), axis=1)  # (n, 3); NaN: none seen
            camera[need] = ~(np.linalg.norm(centre, axis=1) < MIN_SENSOR_DISTANCE_M) & seen[need].any(axis=1)
            camera_known[need] = True
        return camera

    children = _child_table(parents.tobytes())
    into_ok = np.ones((T, J), dtype=bool)  # each joint's own bone within proximal_fraction (roots: True)
    for level_all, _ in depth_levels(parents.tobytes())[1:]:  # roots have no bone to judge
        bone_all = point_norms(x[:, level_all] - x[:, parents[level_all]])
        cand = stretched(x, level_all) & into_ok[:, parents[level_all]]
        rows = cand.any(axis=1)
        if rows.any():
            cand &= in_camera_space(rows)[:, None]
        hit = cand.any(axis=0)
        if hit.any():  # only this level's joints with a candidate frame are worked on
            level, cand = level_all[hit], cand[:, hit]
            p, L = parents[level], length[level]
            dist = point_norms(x[:, level])
            u = x[:, level] / np.where(dist > 0, dist, 1.0)[..., None]  # unit ray through the joint
            along = point_dots(u, x[:, p])  # s of the ray's point nearest the parent
            miss2 = point_dots(x[:, p], x[:, p]) - along ** 2  # squared distance of that point to the parent
            reach = L * (1.0 + ray_slack) + RAY_NOISE_M
            off = x[:, level] - expected(level)  # NaN: no good sample
            departure = point_dots(off, u)
            sideways = point_norms(off - departure[..., None] * u)
            departure = np.abs(departure)
            # thrown along the ray: far from where the joint is expected, and mostly along the ray
            # (a joint thrown in another direction is the jump stage's: moved along its ray, it
            # would keep the sideways part of its error)
            along_ray = ~(departure <= np.maximum(fraction * L, MIN_DEPARTURE_M)) & ~(sideways > SIDEWAYS_RATIO * departure)
            cand &= (miss2 <= reach ** 2) & (along > 0) & along_ray
            if cand.any():
                h = np.sqrt(np.maximum(L ** 2 - miss2, 0.0))
                near, far = (along - h)[..., None] * u, (along + h)[..., None] * u
                if reference is None:  # the joint's offset to its parent in the good samples around each run, in time
                    good = seen[:, level] & seen[:, p] & ~cand
                    offset = np.where(good[..., None], x[:, level] - x[:, p], np.nan)
                    guess = interpolate_linear(offset, good)[0] + x[:, p]
                else:
                    guess = x[:, p] + (expected(level) - expected(p))
                known = finite_points(guess)
                use_near = np.where(known, point_norms(near - guess) <= point_norms(far - guess),
                                    True)  # no guess: the sensor's side
                # the joint's own children say which of the two it is where they can: each must lie at
                # its bone's length from it (the ankle from a knee), which only one point may give them
                told, child_near = _children_choose(x, seen, length, children[level], near, far)
                use_near = np.where(told, child_near, use_near)
                use_near &= along - h > 0  # never behind the sensor
                fixed = np.where(use_near[..., None], near, far)
                x[:, level] = np.where(cand[..., None], fixed, x[:, level])
                done[:, level] = cand
                bone_all[:, hit] = np.where(cand, point_norms(x[:, level] - x[:, p]), bone_all[:, hit])
        L_all = length[level_all]
        into_ok[:, level_all] = ~judged[level_all] | (np.abs(bone_all - L_all) <= np.maximum(proximal_fraction * L_all, floor_m)) | ~np.isfinite(L_all)
    return x, done
