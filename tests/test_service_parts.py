"""Unit tests of the service's parts: metrics text, drift-free pacing, stdin parsing, validation."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from streamfix.frames import BodyFrame, SkeletonFrame
from streamfix.io.kinect_csv import read_kinect_csv
from streamfix.service.metrics import Registry, parse_prometheus_text
from streamfix.service.playback import Pacer, motion_frames
from streamfix.service.items import wire_reason
from streamfix.service.sources import default_replay_file
from streamfix.service.textin import parse_line
from streamfix.service.validate import BadInput, validate_frame
from streamfix.transport.wire import WireError


def test_prometheus_text_counts_labels_and_cumulative_buckets():
    reg = Registry()
    c = reg.counter("x_total", "help", ("reason",))
    c.inc(reason="garbage")
    c.inc(2, reason="truncated")
    h = reg.histogram("lat_seconds", "latency", buckets=(0.001, 0.01))
    for v in (0.0005, 0.005, 0.005, 5.0):
        h.observe(v)
    text = reg.render()
    assert "# TYPE x_total counter" in text and "# TYPE lat_seconds histogram" in text
    m = parse_prometheus_text(text)
    assert m['x_total{reason="garbage"}'] == 1 and m['x_total{reason="truncated"}'] == 2
    assert m['lat_seconds_bucket{le="0.001"}'] == 1
    assert m['lat_seconds_bucket{le="0.01"}'] == 3
    assert m['lat_seconds_bucket{le="+Inf"}'] == 4 == m["lat_seconds_count"]
    assert m["lat_seconds_sum"] == pytest.approx(5.0105)
    assert h.quantile(0.5) == 0.005 and h.quantile(1.0) == 5.0
    with pytest.raises(ValueError):
        c.inc(-1, reason="garbage")
    with pytest.raises(ValueError, match="takes labels"):
        c.inc(stream="x")


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_pacer_schedule_is_absolute_so_late_sends_do_not_accumulate_drift():
    clock = FakeClock()
    pacer = Pacer(rate=2.0, clock=clock)
    assert pacer.wait_time(0.0) == 0.0
    # frame at t=1 s of the recording is due 0.5 s later at rate 2
    assert pacer.wait_time(1.0) == pytest.approx(0.5)
    clock.t += 0.9  # we overslept by 0.4 s
    assert pacer.wait_time(1.0) == 0.0
    # the next frame is still due at its own absolute time, not 0.5 s after the late send
    assert pacer.due(2.0) == pytest.approx(101.0)
    assert pacer.wait_time(2.0) == pytest.approx(0.1)
    fast = Pacer(rate=math.inf, clock=clock)
    assert fast.wait_time(1e6) == 0.0
    with pytest.raises(ValueError):
        Pacer(rate=0)


def test_motion_frames_loop_keeps_seq_and_sensor_time_increasing(shared_data):
    motion = read_kinect_csv(shared_data / "kinect_v2" / "Ges01_wavehand.csv")
    gen = motion_frames(motion, "s", loop=True)
    items = [next(gen) for _ in range(2 * motion.n_frames + 3)]
    seqs = [f.seq for _, f in items]
    times = [f.sensor_time_ns for _, f in items]
    assert seqs == list(range(len(items)))
    assert np.all(np.diff(times) > 0)
    first, again = items[0][1], items[motion.n_frames][1]
    np.testing.assert_array_equal(first.bodies[0].confidence, again.bodies[0].confidence)
    assert again.sensor_time_ns - first.sensor_time_ns == pytest.approx(
        (motion.timestamps[-1] - motion.timestamps[0] + 1 / motion.rate_hz) * 1e9, abs=2)
    once = list(motion_frames(motion, "s"))
    assert len(once) == motion.n_frames


def test_stdin_csv_line_matches_file_reader_and_treats_nan_as_missing(shared_data):
    path = shared_data / "kinect_v2" / "seated_joints.csv"
    motion = read_kinect_csv(path)
    lines = path.read_text().splitlines()
    frame = parse_line(lines[5], "cam", 5)
    assert frame.seq == 5 and frame.stream_id == "cam" and frame.skeleton == "kinect_v2"
    assert frame.sensor_time_ns == pytest.approx(motion.timestamps[5] * 1e9, abs=100)
    np.testing.assert_allclose(frame.bodies[0].confidence, motion.confidence[5])
    np.testing.assert_allclose(frame.bodies[0].positions, motion.positions[5], equal_nan=True)
    fields = lines[5].rstrip(",").split(",")
    fields[1:4] = ["nan", "inf", "0"]
    f2, n_bad = validate_frame(parse_line(",".join(fields), "cam", 6))
    assert n_bad == 1 and np.isnan(f2.bodies[0].positions[0]).all() and f2.bodies[0].confidence[0] == 0
    with pytest.raises(BadInput) as exc:
        parse_line(",".join(fields[: 1 + 4 * 24]), "cam", 7)
    assert exc.value.reason == "wrong_joint_count" and "expected 25" in str(exc.value)
    with pytest.raises(BadInput) as exc:
        parse_line("12,abc,3", "cam", 8)
    assert exc.value.reason == "garbage"
    assert parse_line("   ", "cam", 9) is None and parse_line("# comment", "cam", 9) is None


def test_stdin_json_line_defaults_and_reasons():
    joints = [[0.1 * j, 1.0, 2.0] for j in range(25)]
    joints[4] = [None, None, None]
    line = json.dumps({"seq": 3, "sensor_time_ns": 1000, "bodies": [{"id": 2, "joints": joints}]})
    f = parse_line(line, "js", 0)
    assert (f.stream_id, f.seq, f.sensor_time_ns, f.skeleton) == ("js", 3, 1000, "kinect_v2")
    assert f.bodies[0].body_id == 2 and f.bodies[0].confidence[4] == 0 and f.bodies[0].confidence[0] == 1
    with pytest.raises(BadInput) as exc:
        parse_line(line[: len(line) // 2], "js", 0)
    assert exc.value.reason == "truncated"
    with pytest.raises(BadInput) as exc:
        parse_line('{"bodies": 3}', "js", 0)
    assert exc.value.reason == "invalid"
    short = json.dumps({"bodies": [{"joints": joints[:20]}]})
    with pytest.raises(BadInput) as exc:
        validate_frame(parse_line(short, "js", 0))
    assert exc.value.reason == "wrong_joint_count" and "25 joints" in str(exc.value)
    other = json.dumps({"skeleton": "nope", "bodies": [{"joints": joints}]})
    with pytest.raises(BadInput) as exc:
        validate_frame(parse_line(other, "js", 0))
    assert exc.value.reason == "unknown_skeleton"


def test_validate_keeps_good_joints_and_clips_confidence():
    pos = np.zeros((25, 3))
    conf = np.full(25, 1.0)
    conf[0] = 7.0
    conf[1] = np.nan
    frame = SkeletonFrame("s", 0, 0, "kinect_v2", [BodyFrame(0, pos, conf)])
    out, n_bad = validate_frame(frame)
    assert n_bad == 0
    assert out.bodies[0].confidence[0] == 1.0 and out.bodies[0].confidence[1] == 0.0
    assert np.isnan(out.bodies[0].positions[1]).all() and np.isfinite(out.bodies[0].positions[2]).all()


@pytest.mark.parametrize(
    "wire,service",
    [("garbage", "garbage"), ("truncated", "truncated"), ("skeleton", "unknown_skeleton"),
     ("joints", "wrong_joint_count"), ("field", "invalid"), ("type", "invalid")],
)
def test_wire_reasons_map_to_service_reasons(wire, service):
    assert wire_reason(WireError("x", wire)) == service


def test_version_reason_distinguishes_newer_from_invalid():
    assert wire_reason(WireError("protocol version 2 is newer than supported 1", "version")) == "newer_version"
    assert wire_reason(WireError("protocol version 0 is not a valid version", "version")) == "invalid"


def test_default_replay_file_missing_names_where_it_looked(tmp_path, monkeypatch):
    monkeypatch.setenv("STREAMFIX_REPLAY_DATA", str(tmp_path))
    with pytest.raises(FileNotFoundError, match=str(tmp_path)):
        default_replay_file()
    (tmp_path / "b.csv").write_text("")
    (tmp_path / "a.csv").write_text("")
    (tmp_path / "0.bvh").write_text("")
    assert default_replay_file().name == "a.csv"


def test_stdin_accepts_what_tap_json_prints_including_skeleton_lines():
    from streamfix.transport.wire import SkeletonMessage

    arm = {"topic": "sf/meta/arm", "kind": "meta", "stream": "arm", "type": "skeleton", "skeleton": "arm3",
           "joint_names": ["a", "b", "c"], "bones": [[0, 1], [1, 2]], "rate_hz": 60.0, "units": "m"}
    msg = parse_line(json.dumps(arm), "stdin", 0)
    assert isinstance(msg, SkeletonMessage) and msg.skeleton.n_joints == 3 and msg.rate_hz == 60.0
    frame_line = {"topic": "sf/live/arm", "kind": "live", "stream": "arm", "type": "frame", "seq": 4,
                  "t_sensor_ns": 5_000, "t_publish_ns": 6_000, "latency_ms": 0.1, "skeleton": "arm3",
                  "filled": False, "bodies": [{"id": 1, "joints": [[0, 0, 1], None, [0, 1, 1]],
                                               "confidence": [1.0, 0.0, 0.5], "recovered": None}]}
    f = parse_line(json.dumps(frame_line), "stdin", 0)
    assert (f.stream_id, f.seq, f.sensor_time_ns, f.skeleton) == ("arm", 4, 5_000, "arm3")
    out, n_bad = validate_frame(f, {"arm3": msg.skeleton})
    assert n_bad == 1 and np.isnan(out.bodies[0].positions[1]).all()
    np.testing.assert_array_equal(out.bodies[0].confidence, [1.0, 0.0, 0.5])


def test_metrics_http_server_serves_the_registry_on_loopback():
    import urllib.error
    import urllib.request

    from streamfix.service.metrics import MetricsServer

    reg = Registry()
    reg.counter("hits_total", "hits").inc(3)
    server = MetricsServer(reg, 0).start()
    try:
        assert server.host == "127.0.0.1" and server.port > 0
        with urllib.request.urlopen(f"http://127.0.0.1:{server.port}/metrics", timeout=5) as resp:
            assert resp.headers["Content-Type"].startswith("text/plain; version=0.0.4")
            assert parse_prometheus_text(resp.read().decode())["hits_total"] == 3
        with pytest.raises(urllib.error.HTTPError) as exc:
            urllib.request.urlopen(f"http://127.0.0.1:{server.port}/other", timeout=5)
        assert exc.value.code == 404
    finally:
        server.close()
