"""DepthAI input on real depthai objects, no camera: a host node replays a recorded pose stream.

The fixture (``tests/fixtures/depthai_coco17_wavehand.npz``, made by
``make_depthai_fixture.py`` beside it from a real Kinect v2 take) holds COCO-17 keypoints
the way ``dai.SpatialKeypoint.spatialCoordinates`` carries them: millimetres, DepthAI axes
(X right, Y up, Z forward). A ``dai.node.ThreadedHostNode`` in a ``dai.Pipeline(False)``
(no device) sends them as real ``dai.SpatialImgDetections``; :class:`DepthaiSource`
reads its host queue and the frames go through the streaming engine.
"""
from __future__ import annotations

import os
import subprocess
import sys
import time
from datetime import timedelta
from pathlib import Path

import depthai as dai  # in the test extra: these tests run in CI, they never skip for want of it
import numpy as np
import pytest

from streamfix.io.depthai_device import parse_depthai_spec
from streamfix.io.depthai_keypoints import detections_to_frame
from streamfix.service.engines import EngineOptions, engine_factory
from streamfix.service.items import Frame, Rejected
from streamfix.service.sources import DepthaiSource
from streamfix.skeletons import BLAZEPOSE_33, COCO_17

FIXTURE = Path(__file__).resolve().parent / "fixtures" / "depthai_coco17_wavehand.npz"
ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def recording():
    data = np.load(FIXTURE)
    return {k: data[k] for k in data.files}


def _message(keypoints_mm: np.ndarray, confidence: np.ndarray, seq: int, t_ns: int):
    """One real SpatialImgDetections with one person's spatial keypoints."""
    detection = dai.SpatialImgDetection()
    detection.setKeypoints([
        dai.SpatialKeypoint(0.0, 0.0, 0.0, float(x), float(y), float(z), float(c), j)
        for j, ((x, y, z), c) in enumerate(zip(keypoints_mm, confidence))
    ])
    detection.confidence = 0.9
    message = dai.SpatialImgDetections()
    message.detections = [detection]
    message.setSequenceNum(seq)
    message.setTimestamp(timedelta(microseconds=t_ns // 1000))
    return message


class RecordedPose(dai.node.ThreadedHostNode):
    """Sends a recorded keypoint stream as SpatialImgDetections, then stops."""

    def __init__(self) -> None:
        super().__init__()
        self.output = self.createOutput()
        self.recording: dict = {}

    def run(self) -> None:
        rec = self.recording
        for i, (kp, conf, t) in enumerate(zip(rec["keypoints_mm"], rec["confidence"], rec["timestamps_ns"])):
            if not self.isRunning():
                return
            self.output.send(_message(kp, conf, 1000 + i, 5_000_000_000 + int(t)))


def _expected_metres(keypoints_mm: np.ndarray, confidence: np.ndarray) -> np.ndarray:
    """The protocol's camera space, written out independently: x = -X, y = Y, z = Z, mm -> m."""
    expected = np.stack([-keypoints_mm[..., 0], keypoints_mm[..., 1], keypoints_mm[..., 2]], axis=-1) / 1000.0
    expected[(keypoints_mm[..., 2] <= 0) | (confidence <= 0)] = np.nan
    return expected


def _read_all(source: DepthaiSource, n: int, pipeline, timeout_s: float = 10.0) -> list[Frame]:
    frames: list[Frame] = []
    deadline = time.monotonic() + timeout_s
    while len(frames) < n and time.monotonic() < deadline:
        frames.extend(it for it in source.poll(0.2) if isinstance(it, Frame))
    pipeline.stop()
    pipeline.wait()
    frames.extend(it for it in source.poll(0.05) if isinstance(it, Frame))
    assert source.exhausted, "a stopped pipeline closes the queue: the source must say it has ended"
    return frames


def test_host_pipeline_keypoints_reach_the_engine_in_metres_and_camera_axes(recording):
    pipeline = dai.Pipeline(False)
    node = pipeline.create(RecordedPose)
    node.recording = recording
    queue = node.output.createOutputQueue(maxSize=256, blocking=True)
    source = DepthaiSource(pipeline, queue, stream_id="oak", rate_hz=float(recording["rate_hz"]))
    pipeline.start()
    frames = _read_all(source, len(recording["keypoints_mm"]), pipeline)

    n = len(recording["keypoints_mm"])
    assert [f.frame.seq for f in frames] == list(range(1000, 1000 + n))
    assert {f.frame.skeleton for f in frames} == {COCO_17.name}
    times = np.array([f.frame.sensor_time_ns for f in frames])
    np.testing.assert_array_equal(times, 5_000_000_000 + recording["timestamps_ns"] // 1000 * 1000)
    got = np.stack([f.frame.bodies[0].positions for f in frames])
    conf = np.stack([f.frame.bodies[0].confidence for f in frames])
    expected = _expected_metres(recording["keypoints_mm"].astype(np.float64), recording["confidence"])
    np.testing.assert_allclose(got, expected, atol=1e-6, equal_nan=True)
    np.testing.assert_allclose(conf, np.where(np.isnan(expected[..., 0]), 0.0, recording["confidence"]), atol=1e-6)
    # joint order and axes on the body itself: head above ankles, the subject (facing the camera)
    # has the left shoulder on the camera's right, i.e. at smaller x in Kinect-style camera space
    i = COCO_17.index
    assert np.nanmedian(got[:, i("nose"), 1] - got[:, i("left_ankle"), 1]) > 1.2
    assert np.nanmedian(got[:, i("left_shoulder"), 0] - got[:, i("right_shoulder"), 0]) < -0.2
    assert 1.5 < np.nanmedian(got[:, i("left_hip"), 2]) < 4.0  # metres from the camera, not millimetres

    # through the engine: the clean output is the same body in the same frame, with the same joint order
    engine = engine_factory("streamfix", EngineOptions(threaded=False))(COCO_17, float(recording["rate_hz"]))
    clean = []
    for f in frames:
        clean.extend(out for kind, out in engine.push(f.frame) if kind == "clean")
    clean.extend(out for kind, out in engine.flush(10.0) if kind == "clean")
    clean = [c for c in clean if not c.filled]  # frames synthesised where the take skipped a sensor frame
    assert [c.sensor_time_ns for c in clean] == list(times)
    cleaned = np.stack([c.bodies[0].positions for c in clean])
    assert np.isfinite(cleaned).all()
    err = np.linalg.norm(cleaned - expected, axis=-1)
    tracked = np.isfinite(err)
    assert np.median(err[tracked]) < 0.03, f"median clean-vs-input distance {np.median(err[tracked]):.3f} m"


def test_blazepose_33_order_units_and_missing_depth():
    """33 keypoints are BlazePose in keypoint order; the message's length unit is honoured;
    no depth (Z = 0) is a missing joint; an unset confidence (-1) counts as tracked."""
    rng = np.random.default_rng(3)
    cm = rng.uniform(-80, 80, size=(33, 3)) + [0.0, 0.0, 250.0]
    cm[7, 2] = 0.0  # left_ear without depth
    detection = dai.SpatialImgDetection()
    detection.setKeypoints([dai.SpatialKeypoint(dai.Point3f(0, 0, 0), dai.Point3f(*map(float, p)), -1.0, j)
                            for j, p in enumerate(cm)])
    message = dai.SpatialImgDetections()
    message.detections = [detection]
    message.unit = dai.LengthUnit.CENTIMETER
    frame = detections_to_frame(message, "oak", seq=4, empty_layout=COCO_17)
    assert frame.skeleton == BLAZEPOSE_33.name and frame.seq == 4
    pos, conf = frame.bodies[0].positions, frame.bodies[0].confidence
    expected = cm / 100.0 * [-1.0, 1.0, 1.0]
    ok = np.arange(33) != 7
    np.testing.assert_allclose(pos[ok], expected[ok], atol=1e-6)
    assert np.isnan(pos[7]).all() and conf[7] == 0.0 and (conf[ok] == 1.0).all()
    assert BLAZEPOSE_33.joint_names[7] == "left_ear"


class SendMessages(dai.node.ThreadedHostNode):
    """Sends prepared messages once."""

    def __init__(self) -> None:
        super().__init__()
        self.output = self.createOutput()
        self.messages: list = []

    def run(self) -> None:
        for message in self.messages:
            self.output.send(message)


def test_unsupported_keypoint_count_is_counted_and_the_stream_goes_on(recording):
    bad = dai.SpatialImgDetections()
    detection = dai.SpatialImgDetection()
    detection.setKeypoints([dai.SpatialKeypoint(0.0, 0.0, 0.0, 1.0, 2.0, 1000.0, 1.0, j) for j in range(21)])
    bad.detections = [detection]
    with pytest.raises(ValueError, match="21 keypoints.*17 \\(coco17\\).*33"):
        detections_to_frame(bad, "oak")
    pipeline = dai.Pipeline(False)
    node = pipeline.create(SendMessages)
    node.messages = [bad, _message(recording["keypoints_mm"][0], recording["confidence"][0], 1, 0)]
    source = DepthaiSource(pipeline, node.output.createOutputQueue(), stream_id="oak")
    pipeline.start()
    items = []
    deadline = time.monotonic() + 5.0
    while len(items) < 2 and time.monotonic() < deadline:
        items.extend(source.poll(0.2))
    source.close()
    assert isinstance(items[0], Rejected) and items[0].reason == "wrong_joint_count"
    assert isinstance(items[1], Frame) and items[1].frame.skeleton == COCO_17.name


class Idle(dai.node.ThreadedHostNode):
    """Sends nothing; runs until its pipeline stops (a camera node between frames)."""

    def __init__(self) -> None:
        super().__init__()
        self.output = self.createOutput()

    def run(self) -> None:
        while self.isRunning():
            time.sleep(0.02)


def _threads_named(prefix: str) -> list[str]:
    names = []
    for task in os.listdir("/proc/self/task"):
        try:
            names.append(Path(f"/proc/self/task/{task}/comm").read_text().strip())
        except OSError:  # the thread ended while listed
            pass
    return [n for n in names if n.startswith(prefix)]


def test_closing_the_source_leaves_no_pipeline_thread_for_the_destructor_to_join():
    """``close()`` stops the pipeline and waits for its host threads (the wait releases the
    GIL). The pipeline's destructor joins them holding the GIL: a host thread still on its
    way back into Python when the last reference went hung the test suite once."""
    pipeline = dai.Pipeline(False)
    node = pipeline.create(Idle)
    source = DepthaiSource(pipeline, node.output.createOutputQueue(), stream_id="oak")
    pipeline.start()
    deadline = time.monotonic() + 5.0
    while not _threads_named("Idle") and time.monotonic() < deadline:
        time.sleep(0.01)
    assert _threads_named("Idle"), "the host node's thread never started"
    source.close()
    assert _threads_named("Idle") == [] and not pipeline.isRunning()
    source.close()  # twice is harmless


def test_depthai_spec_options_and_errors():
    assert parse_depthai_spec("depthai").fps == 30.0
    opts = parse_depthai_spec("depthai:model=luxonis/some-pose:coco,fps=15,device=1944301011")
    assert (opts.model, opts.fps, opts.device) == ("luxonis/some-pose:coco", 15.0, "1944301011")
    for bad in ("depthai:fps=fast", "depthai:fps=0", "depthai:colour=1", "depthai:model"):
        with pytest.raises(ValueError, match="depthai"):
            parse_depthai_spec(bad)


def test_serve_without_a_device_says_so_and_exits_nonzero():
    if dai.Device.getAllAvailableDevices():
        pytest.skip("a DepthAI device is attached to this machine")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.run(
        [sys.executable, "-m", "streamfix", "serve", "--source", "depthai", "--out", "tcp://127.0.0.1:0"],
        capture_output=True, text=True, timeout=60, env=env,
    )
    assert proc.returncode != 0
    assert "no DepthAI device found" in proc.stderr
    assert "Traceback" not in proc.stderr


@pytest.mark.parametrize("source, says", [("depthai", "no DepthAI device found"),
                                          ("depthai:fps=0", "fps must be in (0, 240]"),
                                          ("azure-kinect", "not built in yet"),
                                          ("replay:nowhere.csv", "no such file"),
                                          ("nowhere.csv", "is not understood")])
def test_serve_checks_its_source_before_it_builds_the_engine(source, says, monkeypatch, capsys):
    """Building the engine takes seconds (imports, compiled kernels, the prior): a source that
    cannot open is said before any of it, so a missing camera fails at once."""
    if source == "depthai" and dai.Device.getAllAvailableDevices():
        pytest.skip("a DepthAI device is attached to this machine")
    import streamfix.service.engines as engines
    from streamfix.cli import main

    def engine_built(*args, **kwargs):
        raise AssertionError("the engine was built before the source was checked")

    monkeypatch.setattr(engines, "engine_factory", engine_built)
    assert main(["serve", "--source", source, "--out", "tcp://127.0.0.1:0"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("streamfix serve: cannot open source") and says in err, err
