"""``prepare_streamfix_engine`` (serve, before its first frame) imports everything a stream's
windows import: an import in the solver thread holds the GIL and the import lock while the
live path waits, mid-stream."""
from __future__ import annotations

import subprocess
import sys
import textwrap

SCRIPT = textwrap.dedent('''
    import sys
    from pathlib import Path
    import numpy as np
    from streamfix.service.engines import prepare_streamfix_engine
    from streamfix.io import read_motion
    from streamfix.frames import BodyFrame, SkeletonFrame
    from streamfix.skeletons import KINECT_V2
    from streamfix.streaming.engine import EngineConfig, StreamEngine

    prepare_streamfix_engine()
    takes = [read_motion(f) for f in sorted(Path(sys.argv[1]).glob("*.csv"))]
    pos = np.concatenate([m.positions for m in takes])[:600].copy()
    conf = np.concatenate([m.confidence for m in takes])[:600].copy()
    arm = [KINECT_V2.joint_names.index(n) for n in ("ElbowLeft", "WristLeft", "HandLeft", "HandTipLeft", "ThumbLeft")]
    pos[400:520, arm] = np.nan  # an arm lost for 4 s after 13 s of history: PCA and the prior bridge it
    conf[400:520, arm] = 0.0
    before = {k for k in sys.modules if k.startswith("streamfix")}
    engine = StreamEngine(KINECT_V2, EngineConfig(rate_hz=30.0))
    for i in range(len(pos)):
        engine.push(SkeletonFrame("k", i, int(i * 1e9 / 30), KINECT_V2.name, [BodyFrame(0, pos[i], conf[i])]))
    engine.flush()
    m = engine.metrics()
    print(m["joints_bridged_pca"], m["joints_bridged_prior"])
    print(" ".join(sorted(k for k in sys.modules if k.startswith("streamfix") and k not in before)))
''')


def test_a_streams_windows_import_nothing_after_prepare(shared_data):
    run = subprocess.run([sys.executable, "-c", SCRIPT, str(shared_data / "kinect_v2")],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    lines = run.stdout.splitlines() + [""]
    pca, prior = (int(v) for v in lines[0].split())
    assert pca > 0 and prior > 0  # the bridge's lazy paths ran
    assert lines[1] == "", f"imported by the windows, not by prepare_streamfix_engine: {lines[1]}"
