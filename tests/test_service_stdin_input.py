"""``serve --source stdin`` on bad lines, hostile skeleton lines and a sensor clock that goes back:
the real stdin reader thread and the real service loop (passthrough engine), recording publisher."""
from __future__ import annotations

import io
import json
import logging
import time

import pytest

from streamfix.cli import main
from streamfix.frames import BodyFrame, SkeletonFrame
from streamfix.io import read_motion
from streamfix.service import sources
from streamfix.service.engines import EngineOptions, engine_factory
from streamfix.service.items import Frame
from streamfix.service.server import Service
from streamfix.service.sources import StdinSource

from test_service_loop import RecordingPublisher, ScriptedSource


@pytest.fixture(scope="module")
def csv_lines(shared_data) -> list[str]:
    """The Kinect v2 recording's frame lines, as a sensor bridge would print them."""
    text = (shared_data / "kinect_v2" / "Ges01_wavehand.csv").read_text().splitlines()
    return [line for line in text if line.strip() and line[0].isdigit()]


def _serve(source, status=None, engine: str = "passthrough") -> tuple[Service, RecordingPublisher]:
    pub = RecordingPublisher()
    svc = Service(source, pub, engine_factory(engine, EngineOptions(threaded=False)), status_interval_s=0,
                  status_stream=status if status is not None else io.StringIO(), status_at_exit=True)
    assert svc.run() == 0
    return svc, pub


def _read_all(source: StdinSource, timeout_s: float = 20.0) -> None:
    """Start the reader thread and wait until it has read every line (ahead of the service)."""
    source.start()
    deadline = time.monotonic() + timeout_s
    while source._thread.is_alive() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert not source._thread.is_alive()


def test_lines_the_parser_cannot_read_are_counted_and_the_input_goes_on(csv_lines, monkeypatch):
    bad = [
        '{"t": "abc", "bodies": []}',              # a time that is not a number
        '{"t": null, "bodies": []}',
        '{"seq": 1e400, "bodies": []}',            # JSON's 1e400 is inf
        '{"sensor_time_ns": 1e400, "bodies": []}',
        '{"t": 1e300, "bodies": []}',              # beyond int64 nanoseconds
        '{"bodies": ' + "[" * 50_000 + "]" * 50_000 + "}",  # deeper than the JSON parser's stack
        "BOOM",                                    # the parser itself fails (below)
    ]
    real_parse = sources.parse_line

    def parse(line, stream_id, seq):
        if line.startswith("BOOM"):
            raise RuntimeError("a parser bug")
        return real_parse(line, stream_id, seq)

    monkeypatch.setattr(sources, "parse_line", parse)
    lines = csv_lines[:20] + bad + csv_lines[20:]
    svc, pub = _serve(StdinSource(io.StringIO("\n".join(lines) + "\n")))
    live = [f for k, f in pub.sent if k == "live" and not f.filled]
    assert len(live) == len(csv_lines), "every good line after the bad ones is still read"
    assert sum(svc.m.malformed.values().values()) == len(bad)


def test_a_skeleton_line_redefining_a_built_in_layout_cannot_take_over_the_stream(csv_lines):
    # the reader thread has read the whole input before the service starts: the old reader kept
    # the 1-joint 'kinect_v2' itself and every frame, earlier ones included, was refused
    fake = json.dumps({"type": "skeleton", "skeleton": "kinect_v2", "joint_names": ["a"], "bones": []})
    source = StdinSource(io.StringIO("\n".join(csv_lines[:20] + [fake] + csv_lines[20:]) + "\n"))
    _read_all(source)
    svc, pub = _serve(source)
    assert len([f for k, f in pub.sent if k == "live" and not f.filled]) == len(csv_lines)
    assert svc.m.limit_hits.value(limit="builtin_skeleton") == 1
    assert sum(svc.m.malformed.values().values()) == 0


def _frame(seq: int, t_ns: int, motion, i: int) -> Frame:
    return Frame(SkeletonFrame("cam", seq, t_ns, "kinect_v2", [BodyFrame(0, motion.positions[i], motion.confidence[i])]),
                 0)


def test_a_sensor_clock_reset_restarts_the_stream_instead_of_dropping_every_later_frame(shared_data, caplog):
    m = read_motion(shared_data / "kinect_v2" / "Ges01_wavehand.csv")
    period = 33_333_333
    items = [_frame(i, 1_000_000_000_000 + i * period, m, i) for i in range(60)]
    # the sensor (or its bridge) restarted: its clock starts again near 0, seq goes on
    items += [_frame(60 + i, 5_000_000 + i * period, m, 60 + i) for i in range(60)]
    with caplog.at_level(logging.WARNING, logger="streamfix.service"):
        svc, pub = _serve(ScriptedSource(items))
    live = [f for k, f in pub.sent if k == "live" and not f.filled]
    assert [f.sensor_time_ns for f in live] == [it.frame.sensor_time_ns for it in items]
    assert svc.m.restarts.value(cause="clock_reset") == 1 and svc.m.late.value() == 0
    assert any("sensor time went back" in r.getMessage() for r in caplog.records)


def test_frames_out_of_order_are_skipped_counted_logged_and_shown(shared_data, caplog):
    m = read_motion(shared_data / "kinect_v2" / "Ges01_wavehand.csv")
    period = 33_333_333
    items = [_frame(i, i * period, m, i) for i in range(40)]
    items[30] = _frame(30, 10 * period, m, 10)  # 0.67 s back in time: out of order, not a reset
    status = io.StringIO()
    with caplog.at_level(logging.WARNING, logger="streamfix.service"):
        svc, pub = _serve(ScriptedSource(items), status, engine="streamfix")  # the engine skips late frames
    assert svc.m.late.value() == 1 and svc.m.restarts.value(cause="clock_reset") == 0
    assert any("out of order" in r.getMessage() for r in caplog.records)
    lines = status.getvalue().splitlines()
    assert len(lines) == 1 and "late 1" in lines[0], "serve --status-interval 0: one status line, at exit"


@pytest.mark.parametrize("option, value", [("--sensor-rate", "0"), ("--sensor-rate", "nan"), ("--max-rate", "0"),
                                           ("--sndhwm", "-1"), ("--linger-ms", "-5"), ("--meta-interval", "0")])
def test_serve_refuses_bad_numbers_before_it_starts(option, value, capsys):
    with pytest.raises(SystemExit) as exc:  # the parser refuses it, naming the flag
        main(["serve", "--source", "stdin", option, value])
    assert exc.value.code == 2 and option in capsys.readouterr().err


def test_serve_refuses_a_sensor_rate_its_limits_would_refuse(capsys):
    assert main(["serve", "--source", "stdin", "--sensor-rate", "300", "--max-rate", "240"]) == 2
    assert "--sensor-rate must be a rate from 1 Hz to --max-rate (240 Hz), got 300" in capsys.readouterr().err
