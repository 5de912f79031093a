"""Units test on real takes: metres pass, millimetres and centimetres are named, absolute position is not looked at."""
from __future__ import annotations

import numpy as np

from streamfix.core.units import units_problem
from streamfix.io import read_motion


def test_real_takes_in_metres_pass_and_scaled_ones_are_named(shared_data):
    kinect = read_motion(shared_data / "kinect_v2" / "Ges01_wavehand.csv")
    markers = read_motion(shared_data / "c3d" / "85_02.c3d")  # a marker set: no bones, its extent is measured
    for m in (kinect, markers):
        assert units_problem(m.positions, m.skeleton.bone_array) is None
        assert units_problem(m.positions + 5000.0, m.skeleton.bone_array) is None  # a far world origin
        assert units_problem(m.positions * 0.01, m.skeleton.bone_array) is None  # small, still not refused
        for scale in (100.0, 1000.0):
            said = units_problem(m.positions * scale, m.skeleton.bone_array)
            assert said is not None and "millimetres" in said
    x = kinect.positions * 1000.0
    x[:, 3:] = np.nan  # a few joints only: the bones that are seen decide
    assert units_problem(x, kinect.skeleton.bone_array) is not None
    assert units_problem(np.full_like(x, np.nan), kinect.skeleton.bone_array) is None  # nothing seen: nothing to say
