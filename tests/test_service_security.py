"""Remote use: CURVE on a real ``serve``, refusal of unauthenticated public binds, metrics bounds.

With ``--curve-secret``/``--curve-clients`` a subscriber or producer without an allowed
key gets nothing and injects nothing, while ``replay`` / ``tap`` with a client key from
``streamfix keys`` stream end to end. Binding ``tcp://*`` without CURVE is refused
unless ``--insecure``. The metrics HTTP server drops silent clients after its timeout
and never serves more than its bound at once.
"""
from __future__ import annotations

import json
import socket
import subprocess
import sys
import threading
import time
import urllib.request

import zmq

from streamfix.cli import main
from streamfix.service.metrics import MetricsServer, Registry
from streamfix.skeletons import KINECT_V2
from streamfix.transport.curve import CurveClient, is_loopback_endpoint
from streamfix.transport.wire import encode_skeleton_message, topic_for
from streamfix.transport.zmq_io import Subscriber

from test_e2e_harness import PROJECT_ROOT, child_env, free_port, run_replay, serve


def _cli(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "streamfix", *args], capture_output=True, text=True,
                          timeout=timeout, env=child_env(), cwd=str(PROJECT_ROOT))


def test_curve_only_allowed_clients_receive_or_inject(tmp_path, shared_data):
    keys = tmp_path / "keys"
    r = _cli("keys", str(keys), "--client", "good", "--client", "rogue")
    assert r.returncode == 0, r.stderr
    assert (keys / "server.key_secret").stat().st_mode & 0o077 == 0
    allowed = tmp_path / "allowed"
    allowed.mkdir()
    (allowed / "good.key").write_bytes((keys / "good.key").read_bytes())
    assert _cli("keys", str(keys)).returncode == 1, "existing keys are never overwritten"
    client = ("--curve-secret", str(keys / "good.key_secret"), "--curve-server", str(keys / "server.key"))
    rogue = ("--curve-secret", str(keys / "rogue.key_secret"), "--curve-server", str(keys / "server.key"))  # not allowed
    path = shared_data / "kinect_v2" / "Ges01_wavehand.csv"
    with serve(tmp_path, "--curve-secret", str(keys / "server.key_secret"), "--curve-clients", str(allowed),
               "--engine", "passthrough") as sp:
        # the hint it prints to watch the output carries the keys (without them a tap waits silently)
        deadline = time.monotonic() + 20
        while "watch it:" not in sp.stderr and time.monotonic() < deadline:
            time.sleep(0.1)
        assert f"--curve-server {keys / 'server.key'}" in sp.stderr, sp.stderr
        ctx = zmq.Context.instance()
        plain_sub = ctx.socket(zmq.SUB)
        plain_sub.setsockopt(zmq.SUBSCRIBE, b"")
        plain_sub.connect(sp.out)
        plain_push = ctx.socket(zmq.PUSH)
        plain_push.setsockopt(zmq.LINGER, 0)
        plain_push.setsockopt(zmq.SNDTIMEO, 200)
        plain_push.connect(sp.source)
        try:
            tap = subprocess.Popen([sys.executable, "-m", "streamfix", "tap", sp.out, "--json", "--count", "20",
                                    "--duration", "60", *client], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                   text=True, env=child_env(), cwd=str(PROJECT_ROOT))
            rogue_sub = Subscriber(sp.out, (b"sf/",), curve=CurveClient(keys / "rogue.key_secret", keys / "server.key"))
            time.sleep(3.0)  # the taps connect (or fail to)
            try:  # an unauthenticated producer: its messages never reach the service
                plain_push.send_multipart([topic_for("meta", "intruder"),
                                           encode_skeleton_message(KINECT_V2, 30.0, "intruder")])
            except zmq.Again:
                pass
            rep = run_replay(path, sp.source, "--speed", "0", "--stream-id", "curve", *client)
            assert rep.returncode == 0, rep.stderr
            bad = run_replay(path, sp.source, "--speed", "0", "--stream-id", "rogue", "--timeout", "2", "--wait", "2", *rogue)
            assert bad.returncode == 1 and "no receiver" in bad.stderr, bad.stderr
            out, err = tap.communicate(timeout=60)
            rogue_got = list(rogue_sub.receive(timeout_s=0.5))
            rogue_sub.close()
            time.sleep(0.5)
            m = sp.metrics()
            assert plain_sub.poll(100) == 0, "a subscriber without a key receives nothing"
        finally:
            plain_sub.close(linger=0)
            plain_push.close(linger=0)
    lines = [json.loads(x) for x in out.splitlines()]
    assert tap.returncode == 0 and len(lines) == 20 and {x["stream"] for x in lines} == {"curve"}, err
    assert rogue_got == [] and rogue_sub.counters["received"] == 0, "a key not in the allowed directory gets nothing"
    assert m.get('streamfix_frames_in_total{stream="curve"}') == 154
    assert 'streamfix_frames_in_total{stream="rogue"}' not in m and 'streamfix_frames_in_total{stream="intruder"}' not in m


def test_public_bind_without_curve_is_refused_unless_insecure(capsys):
    assert main(["serve", "--source", f"tcp://*:{free_port()}", "--out", f"tcp://127.0.0.1:{free_port()}"]) == 2
    err = capsys.readouterr().err
    assert "--insecure" in err and "curve" in err.lower(), err
    assert main(["serve", "--source", "stdin", "--out", f"tcp://0.0.0.0:{free_port()}"]) == 2
    assert "refusing to bind" in capsys.readouterr().err
    assert is_loopback_endpoint("tcp://127.0.0.1:5555") and is_loopback_endpoint("ipc:///tmp/x")
    assert is_loopback_endpoint("tcp://localhost:1") and not is_loopback_endpoint("tcp://*:1")
    assert not is_loopback_endpoint("tcp://0.0.0.0:1") and not is_loopback_endpoint("tcp://10.1.2.3:1")


def test_metrics_server_drops_silent_clients_and_bounds_connections():
    reg = Registry()
    reg.counter("demo_total", "demo").inc(3)
    server = MetricsServer(reg, 0, timeout_s=0.5, max_connections=4).start()
    idle = []
    try:
        base = threading.active_count()
        for _ in range(20):  # slow clients: connect, send nothing
            s = socket.create_connection(("127.0.0.1", server.port))
            idle.append(s)
        deadline = time.monotonic() + 3
        while server._httpd.refused < 12 and time.monotonic() < deadline:
            assert threading.active_count() <= base + 4, "at most max_connections handler threads"
            time.sleep(0.05)
        assert server._httpd.refused >= 12, "connections beyond the bound are closed on accept"
        time.sleep(1.0)  # the silent ones time out and free their slots
        with urllib.request.urlopen(f"http://127.0.0.1:{server.port}/metrics", timeout=5) as resp:
            assert "demo_total 3" in resp.read().decode()
        assert threading.active_count() <= base + 1
    finally:
        for s in idle:
            s.close()
        server.close()
