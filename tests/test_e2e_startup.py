"""A producer started before ``streamfix serve`` is ready loses nothing: real processes on loopback.

The README's order of steps is serve, then replay, from two terminals; a person who starts
the replay first (or a service whose first start compiles its kernels) must not see the
service shed the first seconds as an overload burst.
"""
from __future__ import annotations

import subprocess
import sys
import time

from test_e2e_harness import PROJECT_ROOT, ServeProcess, child_env, free_port, kill, wait_metric

STREAM = "early"


def test_a_replay_started_before_the_service_is_played_in_full_and_nothing_is_shed(shared_data, tmp_path):
    take = shared_data / "kinect_v2" / "Ges01_wavehand.csv"  # 154 frames, 5 s
    port = free_port()
    replay = subprocess.Popen(
        [sys.executable, "-m", "streamfix", "replay", str(take), "--to", f"tcp://127.0.0.1:{port}",
         "--stream-id", STREAM, "--wait", "60"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=child_env(), cwd=str(PROJECT_ROOT))
    sp = None
    try:
        time.sleep(3.0)  # the replay is up and waiting; the service is not
        # the service's default overload policy (shed frames older than its 50 ms backlog bound)
        sp = ServeProcess(tmp_path, "--overload", "shed", source=f"tcp://127.0.0.1:{port}")
        _, err = replay.communicate(timeout=120)
        assert replay.returncode == 0, err
        assert "sent 154 frames" in err
        m = wait_metric(sp, f'streamfix_frames_in_total{{stream="{STREAM}"}}', 154)
        assert m[f'streamfix_frames_in_total{{stream="{STREAM}"}}'] == 154, sp.stderr[-2000:]
        assert m['streamfix_shed_frames_total{reason="backlog"}'] == 0, sp.stderr[-2000:]
    finally:
        kill(replay)
        if sp is not None:
            sp.close()
