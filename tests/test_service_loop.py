"""The service loop in process: a scripted source, the real engine, a recording publisher."""
from __future__ import annotations

import logging
import time

import numpy as np
import pytest

from streamfix.frames import BodyFrame, SkeletonFrame
from streamfix.io import read_motion
from streamfix.service.engines import EngineOptions, engine_factory, parse_lookahead
from streamfix.service.server import Service
from streamfix.service.items import Frame, Rejected


class ScriptedSource:
    def __init__(self, items, batch: int = 7) -> None:
        self.items = list(items)
        self.batch = batch
        self.exhausted = False
        self.closed = False

    def poll(self, timeout_s: float):
        out, self.items = self.items[: self.batch], self.items[self.batch:]
        self.exhausted = not self.items
        return out

    def close(self) -> None:
        self.closed = True


class RecordingPublisher:
    def __init__(self) -> None:
        self.sent: list[tuple[str, SkeletonFrame]] = []
        self.meta: list[str] = []
        self.counters: dict = {}
        self.drops: dict = {}
        self.closed = False

    def publish(self, kind, frame):
        self.sent.append((kind, frame))
        self.counters[kind] = self.counters.get(kind, 0) + 1
        return True

    def announce(self, stream_id, skeleton, rate_hz):
        self.meta.append(stream_id)

    def tick(self, now=None):
        pass

    def close(self):
        self.closed = True


@pytest.fixture(scope="module")
def kinect(shared_data):
    return read_motion(shared_data / "kinect_v2" / "Ges04_comehere.csv")


def _frames(motion, seqs, stream="s"):
    for n, i in enumerate(seqs):
        yield Frame(SkeletonFrame(stream, int(i), int(round(motion.timestamps[n] * 1e9)), "kinect_v2",
                                  [BodyFrame(0, motion.positions[n], motion.confidence[n])]), n * 1000)


def test_a_restarted_sender_gets_a_new_engine_instead_of_being_skipped_as_late(kinect, caplog):
    first, second = range(100), range(60)  # the sender restarts at seq 0
    items = list(_frames(kinect, first)) + list(_frames(kinect.slice(100, 160), second))
    pub = RecordingPublisher()
    svc = Service(ScriptedSource(items), pub, engine_factory("streamfix", EngineOptions(threaded=False)),
                  status_interval_s=0)
    with caplog.at_level(logging.WARNING, logger="streamfix.service"):
        assert svc.run() == 0
    clean = [f for k, f in pub.sent if k == "clean" and not f.filled]
    assert len(clean) == 160, "every frame of both sessions comes out on clean"
    assert [f.sensor_time_ns for f in clean] == [it.frame.sensor_time_ns for it in items]
    assert any("restarted (seq 0 after 99)" in r.getMessage() for r in caplog.records)
    assert svc.m.late.value() == 0
    assert pub.closed and svc.source.closed


def test_rejected_items_are_counted_and_logged_once_each(kinect, caplog):
    items = list(_frames(kinect, range(20)))
    items.insert(5, Rejected("garbage", "x"))
    items.insert(9, Rejected("truncated", "y"))
    bad = SkeletonFrame("s", 999, 0, "kinect_v2", [BodyFrame(0, np.zeros((3, 3)), np.ones(3))])
    items.insert(12, Frame(bad, 0))
    pub = RecordingPublisher()
    svc = Service(ScriptedSource(items), pub, engine_factory("passthrough", EngineOptions()), status_interval_s=0)
    with caplog.at_level(logging.WARNING, logger="streamfix.service"):
        svc.run()
    assert [f.seq for k, f in pub.sent if k == "live"] == list(range(20))
    for reason in ("garbage", "truncated", "wrong_joint_count"):
        assert svc.m.malformed.value(reason=reason) == 1
        assert sum(f"({reason})" in r.getMessage() for r in caplog.records) == 1
    assert "malformed 3" in svc.status_line()


def test_lookahead_argument_takes_seconds_or_frames():
    assert parse_lookahead("0.5") == (0.5, None)
    assert parse_lookahead("0.25s") == (0.25, None)
    assert parse_lookahead("15f") == (None, 15)
    for bad in ("x", "-1", "-2f", "nan"):
        with pytest.raises(ValueError, match="--lookahead"):
            parse_lookahead(bad)


def test_a_threaded_engine_wakes_a_source_that_can_be_woken(kinect):
    """A window finished on a solver thread wakes the loop's wait for input (ZmqSource.wake),
    so its clean frames are published at once, not at the loop's next turn (up to 10 ms)."""

    class WakeableSource(ScriptedSource):
        wakes = 0

        def poll(self, timeout_s: float):
            time.sleep(0.005)  # a frame every 5 ms: the solver keeps up, windows are solved
            return super().poll(timeout_s)

        def wake(self) -> None:
            WakeableSource.wakes += 1

    src = WakeableSource(list(_frames(kinect, range(90))), batch=1)
    pub = RecordingPublisher()
    engines = []
    make = engine_factory("streamfix", EngineOptions(threaded=True))

    def factory(skeleton, rate):
        engines.append(make(skeleton, rate))
        return engines[-1]

    svc = Service(src, pub, factory, status_interval_s=0)
    assert svc.run() == 0
    assert len(engines) == 1 and engines[0].on_window_done == src.wake
    m = engines[0].metrics()
    assert m["windows_solved"] > 0
    # once per window handed to the pool (solved, or dropped unsolved when it came too late);
    # the last call may land just after flush() saw its window done
    submitted = m["windows_scheduled"] - m["windows_skipped"]
    deadline = time.monotonic() + 10.0
    while WakeableSource.wakes < submitted and time.monotonic() < deadline:
        time.sleep(0.01)
    assert WakeableSource.wakes == submitted
    assert sum(k == "clean" and not f.filled for k, f in pub.sent) == 90


def test_input_waiting_is_handled_before_the_engines_background_work(kinect):
    """Frames that arrived together (one per stream) all get their live output before the
    engines are polled (which hands the scheduled windows to the solver), but input that
    keeps coming cannot hold the polls off for longer than a turn."""

    class PendingSource(ScriptedSource):
        def pending(self):
            return len(self.items), 0.0

    class RecordingEngine:
        def __init__(self, log, delay_s=0.0):
            self.log, self.delay_s = log, delay_s

        def push(self, frame, fill=True):
            time.sleep(self.delay_s)
            self.log.append("push")
            return [("live", frame)]

        def poll(self):
            self.log.append("poll")
            return []

        def flush(self, timeout=None):
            return []

        def metrics(self):
            return {"lookahead_frames": 0}

    streams = [list(_frames(kinect, range(3), stream=f"s{k}")) for k in range(5)]
    ticks = [streams[k][i] for i in range(3) for k in range(5)]  # 3 ticks of 5 streams
    log: list[str] = []
    svc = Service(PendingSource(ticks, batch=1), RecordingPublisher(), lambda sk, rate: RecordingEngine(log),
                  status_interval_s=0)
    assert svc.run() == 0
    first_poll = log.index("poll")
    assert log[:first_poll] == ["push"] * 15  # everything waiting was handled first

    slow: list[str] = []
    svc = Service(PendingSource(list(_frames(kinect, range(150))), batch=1), RecordingPublisher(),
                  lambda sk, rate: RecordingEngine(slow, delay_s=0.002), status_interval_s=0)
    assert svc.run(max_turn_s=0.01) == 0
    runs, n = [], 0
    for entry in slow:
        if entry == "push":
            n += 1
        elif n:
            runs.append(n)
            n = 0
    assert runs and max(runs) <= 10  # 2 ms a frame: polled at least every ~10 ms of input


def test_input_that_keeps_coming_starves_no_engine_of_its_polls(kinect):
    """While input waits, a turn polls one engine and leaves the rest for the next turns,
    starting where it stopped: a stream that went quiet still gets its clean frames out
    while another keeps sending (not only when the input stops)."""

    class PendingSource(ScriptedSource):
        def pending(self):
            return len(self.items), 0.0

    class PollLog:
        def __init__(self, name, log, source):
            self.name, self.log, self.source = name, log, source

        def push(self, frame, fill=True):
            time.sleep(0.002)
            return [("live", frame)]

        def poll(self):
            if self.source.items:  # polled while input waits
                self.log.append(self.name)
            return []

        def flush(self, timeout=None):
            return []

        def metrics(self):
            return {"lookahead_frames": 0}

    quiet = [next(_frames(kinect, [0], stream=s)) for s in ("a", "b", "c")]
    busy = list(_frames(kinect, range(1, 80), stream="a"))  # only stream a goes on sending
    log: list[str] = []
    made = iter(("a", "b", "c"))
    source = PendingSource(quiet + busy, batch=1)
    svc = Service(source, RecordingPublisher(), lambda sk, rate: PollLog(next(made), log, source),
                  status_interval_s=0)
    assert svc.run(max_turn_s=0.01) == 0
    # 79 frames of 2 ms in turns of ~10 ms: ~16 turns with input waiting, each polling one engine
    assert min(log.count(name) for name in ("a", "b", "c")) >= 3, log


def test_the_first_engines_import_and_read_nothing_the_service_did_not_load_before_listening():
    """``engine_factory("streamfix")`` (called before the service listens) imports what an
    engine needs and reads the shipped sensor-bias models; building the first streams'
    engines on their first frames then imports no module and reads no model file (an import
    there held the input loop for 20-60 ms, a model file 8-18 ms: long enough to shed the
    frames behind them). In a fresh interpreter, so other tests' imports cannot hide one."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        "from streamfix.service.engines import EngineOptions, engine_factory\n"
        "import streamfix.sensor_bias.shipped as shipped\n"
        "from streamfix.skeletons import get_skeleton\n"
        "make = engine_factory('streamfix', EngineOptions())\n"
        "skeletons = [get_skeleton(name) for name in ('kinect_v2', 'kinect_v1_uiprmd')]\n"
        "reads, read = [], shipped.load_pose_bias\n"
        "shipped.load_pose_bias = lambda path: reads.append(path) or read(path)\n"
        "before = set(sys.modules)\n"
        "engines = [make(skeleton, 30.0) for skeleton in skeletons]\n"
        "print(sorted(set(sys.modules) - before), len(reads))\n"
        "for engine in engines:\n"
        "    engine.close()\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1] == "[] 0", out.stdout


def test_a_sensor_bias_model_file_is_read_once_for_every_stream(monkeypatch):
    """``--sensor-bias PATH``: the factory reads the file once and every stream's engine
    corrects with that model, instead of each new stream reading it on its first frame."""
    import streamfix.io.pose_bias_model as files
    import streamfix.sensor_bias.shipped as shipped
    from streamfix.core.pose_bias import PoseBiasModel
    from streamfix.sensor_bias.shipped import MODELS_DIR
    from streamfix.skeletons import get_skeleton

    reads = []
    real = files.load_pose_bias

    def counted(path):
        reads.append(path)
        return real(path)

    monkeypatch.setattr(files, "load_pose_bias", counted)
    monkeypatch.setattr(shipped, "load_pose_bias", counted)  # what an engine would call
    make = engine_factory("streamfix", EngineOptions(sensor_bias=str(MODELS_DIR / "kinect_v1_uiprmd.npz")))
    assert len(reads) == 1
    skeleton = get_skeleton("kinect_v1_uiprmd")
    engines = [make(skeleton, 30.0) for _ in range(3)]
    try:
        assert len(reads) == 1
        assert all(isinstance(e.cfg.sensor_bias, PoseBiasModel) and e.cfg.sensor_bias is engines[0].cfg.sensor_bias
                   for e in engines)
    finally:
        for e in engines:
            e.close()
