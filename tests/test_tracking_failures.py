"""Lost joints yield in the bone projection (core.bone_projection.tracking_failures, stage 5).

Real data: the KERAAL Kinect v2 + Vicon take, the paired protocol's ground truth."""
from __future__ import annotations

import numpy as np

from streamfix.core.bone_projection import tracking_failures
from streamfix.core.pipeline import PipelineConfig
from streamfix.core.reference_metrics import remove_mean_offset
from streamfix.streaming.config import schedule_config
from streamfix.streaming.offline import clean_motion


def test_only_runs_of_flags_as_long_as_the_span_are_failures():
    flagged = np.zeros((40, 3), dtype=bool)
    flagged[2, 0] = True                  # a spike
    flagged[10:14, 0] = True              # 4 frames: shorter than 1/6 s at 30 Hz
    flagged[20:25, 1] = True              # 5 frames: a failure
    flagged[35:40, 2] = True              # a failure still running at the window's end
    got = tracking_failures(flagged, 30.0, 1.0 / 6.0)
    expected = np.zeros_like(flagged)
    expected[20:25, 1] = expected[35:40, 2] = True
    assert np.array_equal(got, expected)
    assert not tracking_failures(flagged, 30.0, None).any()
    # the span is in seconds: at 120 Hz the same 5 frames are a jittery stretch, not a loss
    assert not tracking_failures(flagged, 120.0, 1.0 / 6.0).any()
    slow = np.zeros((100, 1), dtype=bool)
    slow[10:30, 0] = True
    assert tracking_failures(slow, 120.0, 1.0 / 6.0)[10:30, 0].all()


def test_joints_the_sensor_has_right_are_not_dragged_by_a_lost_neighbour(keraal):
    """KERAAL: when an arm's joints fail (runs of outlier flags), the projection used to
    split their bones' length errors with the tracked joints beside them and pulled the
    top of the spine off the Vicon. Treated as lost, the failed joints take the correction,
    and SpineShoulder stays as close to the Vicon as the raw sensor's."""
    m = keraal.sensor
    names = m.skeleton.joint_names
    ref = keraal.reference

    def error_mm(y: np.ndarray, joint: str) -> float:
        j = names.index(joint)
        return 1000.0 * float(np.nanmean(np.linalg.norm(remove_mean_offset(y, ref)[:, j] - ref[:, j], axis=1)))

    def cleaned(failure_s):
        config = schedule_config("file", m.rate_hz, solver_config=PipelineConfig(projection_failure_s=failure_s))
        return clean_motion(m, config)[0].positions

    raw = error_mm(m.positions, "SpineShoulder")
    before, after = cleaned(None), cleaned(PipelineConfig().projection_failure_s)
    assert error_mm(before, "SpineShoulder") > raw + 0.5          # the defect is there to see
    assert error_mm(after, "SpineShoulder") <= raw + 0.2
    for joint in ("ElbowLeft", "ElbowRight"):
        assert error_mm(after, joint) <= error_mm(before, joint)
