"""``streamfix serve --vmc``: a real serve process replays a recording; a real OSC server receives the avatar."""
from __future__ import annotations

import subprocess
import sys
import threading

import numpy as np
import pytest

pytest.importorskip("pythonosc", reason="VMC output needs python-osc (the 'outputs' extra)")
from pythonosc.dispatcher import Dispatcher
from pythonosc.osc_server import BlockingOSCUDPServer

from streamfix.cli import main
from streamfix.io import read_motion
from streamfix.streaming.engine import EngineConfig
from streamfix.streaming.offline import clean_motion

from test_e2e_harness import PROJECT_ROOT, child_env, free_port, kill
from test_transport_vmc import KINECT_JOINT, _rebuild


def test_serve_sends_the_clean_output_over_vmc(shared_data, tmp_path):
    path = shared_data / "kinect_v2" / "Ges01_wavehand.csv"
    frames: list[dict] = []

    def on_message(address, *args):
        if address == "/VMC/Ext/OK":
            frames.append({})
        elif address == "/VMC/Ext/Bone/Pos":
            frames[-1][args[0]] = np.array(args[1:], dtype=np.float64)

    dispatcher = Dispatcher()
    dispatcher.set_default_handler(on_message)
    server = BlockingOSCUDPServer(("127.0.0.1", 0), dispatcher)
    receiver = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    receiver.start()
    err = open(tmp_path / "serve.stderr", "wb")
    proc = subprocess.Popen(
        [sys.executable, "-m", "streamfix", "serve", "--source", f"replay:{path}", "--speed", "0", "--sync",  # --sync: deterministic, what `clean` writes
         "--out", f"tcp://127.0.0.1:{free_port()}", "--status-interval", "0",
         "--vmc", f"127.0.0.1:{server.server_address[1]}"],
        stdout=subprocess.DEVNULL, stderr=err, env=child_env(), cwd=str(PROJECT_ROOT),
    )
    try:
        assert proc.wait(timeout=120) == 0, (tmp_path / "serve.stderr").read_text()
    finally:
        kill(proc)
        server.shutdown()
        server.server_close()
    motion = read_motion(path)
    expect, _ = clean_motion(motion, EngineConfig(rate_hz=motion.rate_hz), keep_filled=True)
    assert len(frames) == expect.n_frames  # every clean frame, one bundle each (loopback loses none here)
    hips, hand = motion.skeleton.index("SpineBase"), motion.skeleton.index(KINECT_JOINT["LeftHand"])
    got = np.array([[_rebuild(f)[0][b] for b in ("Hips", "LeftHand")] for f in frames])
    np.testing.assert_allclose(got[:, 0], expect.positions[:, hips], atol=0.01)
    np.testing.assert_allclose(got[:, 1], expect.positions[:, hand], atol=0.01)


def test_bad_vmc_target_fails_at_start(capsys):
    assert main(["serve", "--source", "stdin", "--vmc", "host:notaport"]) == 2
    assert "not a number" in capsys.readouterr().err


def test_vmc_sink_reports_an_unsupported_layout_once_then_skips_it():
    from streamfix.frames import BodyFrame, SkeletonFrame
    from streamfix.service.sinks import VmcSink
    from streamfix.skeletons import COCO_17

    sink = VmcSink("127.0.0.1", 9)
    frame = SkeletonFrame("s", 0, 0, COCO_17.name, [BodyFrame(0, np.zeros((17, 3)), np.ones(17))])
    with pytest.raises(ValueError, match="coco17"):
        sink.send("clean", frame, COCO_17, 30.0)
    sink.send("clean", frame, COCO_17, 30.0)  # no second report
    sink.send("live", frame, COCO_17, 30.0)  # other topic: ignored
    assert sink.frames_sent == 0
    with pytest.raises(ValueError, match="output topic"):
        VmcSink("127.0.0.1", 9, topic="raw")
