"""The procedural Kinect v2 body: isometric, smooth, facing the sensor, deterministic."""
from __future__ import annotations

import numpy as np
import pytest

from streamfix.sim.body import ACTIVITIES, generate_clean
from streamfix.skeletons import KINECT_V2 as K

LENGTHS = np.array([0.30, 0.07, 0.14, 0.18, 0.24, 0.22, 0.06, 0.18, 0.25, 0.22, 0.05, 0.09, 0.32, 0.35, 0.11,
                    0.09, 0.34, 0.34, 0.11, 0.22, 0.08, 0.09, 0.08, 0.08])
PLACE = np.array([0.0, -0.35, 2.7])


@pytest.mark.parametrize("activity", sorted(ACTIVITIES))
def test_isometric_smooth_and_facing_the_sensor(activity):
    m = generate_clean(activity, 20.0, 30.0, LENGTHS, PLACE, seed=3, subject_scale=1.0)
    assert m.n_frames == 600 and m.skeleton is K and m.observed.all()
    b = K.bone_array
    L = np.linalg.norm(m.positions[:, b[:, 0]] - m.positions[:, b[:, 1]], axis=2)
    sym = LENGTHS.copy()
    names = K.joint_names
    for i, (p, c) in enumerate(K.bones):
        if "Left" in names[c]:
            k = [kk for kk, (pp, cc) in enumerate(K.bones) if names[cc] == names[c].replace("Left", "Right")][0]
            sym[i] = sym[k] = 0.5 * (LENGTHS[i] + LENGTHS[k])
    np.testing.assert_allclose(L, np.broadcast_to(sym, L.shape), atol=1e-9)
    # smooth: second differences (m/frame^2) far below the real sensor's per-frame jitter
    acc = np.linalg.norm(np.diff(m.positions, 2, axis=0), axis=2)
    assert np.percentile(acc, 99) < 0.02
    # facing the sensor as the Kinect SDK reports a subject: left at -x, toes towards the camera
    x = lambda n: m.positions[:, K.index(n)]
    assert np.median(x("ShoulderLeft")[:, 0] - x("ShoulderRight")[:, 0]) < 0
    assert np.median(x("FootLeft")[:, 2] - x("AnkleLeft")[:, 2]) < 0
    assert np.all(x("Head")[:, 1] > x("SpineShoulder")[:, 1])
    np.testing.assert_allclose(np.median(x("SpineBase"), axis=0), PLACE, atol=0.2)


def test_activities_do_what_they_say():
    st = generate_clean("standing", 30.0, 30.0, LENGTHS, PLACE, seed=4)
    hand, head = st.positions[:, K.index("HandRight")], st.positions[:, K.index("Head")]
    assert (hand[:, 1] > head[:, 1] - 0.1).any()  # the wave raises the hand to head height
    assert (hand[:, 1] < head[:, 1] - 0.6).any()  # and it hangs down otherwise
    seated = generate_clean("seated", 10.0, 30.0, LENGTHS, PLACE, seed=4)
    knee, hip = seated.positions[:, K.index("KneeLeft")], seated.positions[:, K.index("HipLeft")]
    assert np.median(hip[:, 2] - knee[:, 2]) > 0.25  # thighs point at the sensor
    step = generate_clean("stepping", 20.0, 30.0, LENGTHS, PLACE, seed=4)
    ankles = step.positions[:, [K.index("AnkleLeft"), K.index("AnkleRight")], 1]
    assert np.ptp(ankles[:, 0]) > 0.1 and np.ptp(ankles[:, 1]) > 0.1  # both feet are lifted


def test_seeded():
    a = generate_clean("standing", 5.0, 30.0, LENGTHS, PLACE, seed=7)
    b = generate_clean("standing", 5.0, 30.0, LENGTHS, PLACE, seed=7)
    c = generate_clean("standing", 5.0, 30.0, LENGTHS, PLACE, seed=8)
    np.testing.assert_array_equal(a.positions, b.positions)
    assert np.abs(a.positions - c.positions).max() > 0.01
    with pytest.raises(ValueError, match="unknown activity 'dance'; known: standing, seated, stepping"):
        generate_clean("dance", 1.0, 30.0, LENGTHS, PLACE)
