"""Azure Kinect body tracking JSON (``offline_processor`` export) as an input file.

The fixture ``tests/fixtures/azure_kinect_wavehand.json`` is SYNTHETIC (no Azure Kinect
recording is available): ``make_azure_kinect_fixture.py`` builds it from the real Kinect v2
take ``Ges01_wavehand.csv``, in the export's own units and axes (mm, depth camera x right,
y down, z forward). Joints copied from the Kinect take must come back exactly where the
Kinect put them (metres, Kinect camera space), which checks the scale and both axis flips.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from streamfix.io import MotionFileError, read_motion
from streamfix.service.items import Frame
from streamfix.service.sources import open_source
from streamfix.skeletons import AZURE_KINECT, KINECT_V2

from test_e2e_harness import PROJECT_ROOT, child_env

FIXTURE = Path(__file__).resolve().parent / "fixtures" / "azure_kinect_wavehand.json"


def test_export_reads_as_metres_in_kinect_camera_space(shared_data):
    motion = read_motion(FIXTURE)
    kinect = read_motion(shared_data / "kinect_v2" / "Ges01_wavehand.csv")
    assert motion.skeleton is AZURE_KINECT and motion.positions.shape == (75, 32, 3)
    assert motion.meta["body_id"] == 1  # the person, not body 7 seen in three frames
    assert 29.0 < motion.rate_hz < 31.5
    np.testing.assert_allclose(motion.timestamps - motion.timestamps[0],
                               kinect.timestamps[:75] - kinect.timestamps[0], atol=1e-6)
    for azure_name, kinect_name in (("WRIST_LEFT", "WristLeft"), ("KNEE_RIGHT", "KneeRight"), ("HEAD", "Head"),
                                    ("PELVIS", "SpineBase"), ("HANDTIP_RIGHT", "HandTipRight")):
        got = motion.positions[:, AZURE_KINECT.index(azure_name)]
        want = kinect.positions[:75, KINECT_V2.index(kinect_name)]
        ok = np.isfinite(got).all(axis=1)
        np.testing.assert_allclose(got[ok], want[ok], atol=1e-4)  # the export rounds to 0.1 mm
    # frame 40 has no body: every joint missing there, tracked elsewhere
    assert not motion.observed[40].any() and motion.observed[41].all()


def test_confidence_levels_and_body_choice(tmp_path):
    doc = json.loads(FIXTURE.read_text())
    doc["frames"] = doc["frames"][:5]
    levels = [3] * 32
    levels[7], levels[14] = 1, 0  # WRIST_LEFT predicted, WRIST_RIGHT out of range
    for frame in doc["frames"]:
        for body in frame["bodies"]:
            body["confidence_level"] = levels
    path = tmp_path / "levels.json"
    path.write_text(json.dumps(doc))
    motion = read_motion(path)
    assert motion.confidence[0, 7] == 0.5 and motion.confidence[0, 14] == 0.0 and motion.confidence[0, 0] == 1.0
    assert np.isnan(motion.positions[0, 14]).all()
    from streamfix.io.azure_kinect import read_azure_kinect_json

    with pytest.raises(MotionFileError, match="no body 3; bodies in the file: \\[1\\]"):
        read_azure_kinect_json(path, body_id=3)


@pytest.mark.parametrize("mutate, message", [
    (lambda d: d.pop("frames"), "no 'frames' list"),
    (lambda d: d.update(joint_names=d["joint_names"][:25]), "not the 32 k4abt joints"),
    (lambda d: d["frames"][2]["bodies"][0]["joint_positions"].pop(), "shape \\(31, 3\\)"),
    (lambda d: d["frames"][3].update(timestamp_usec=0), "timestamps must increase"),
])
def test_malformed_exports_name_the_problem(tmp_path, mutate, message):
    doc = json.loads(FIXTURE.read_text())
    mutate(doc)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(MotionFileError, match=message):
        read_motion(path)


def test_serve_source_file_replays_the_export():
    source = open_source(str(FIXTURE), speed=float("inf"))
    frames = []
    while not source.exhausted:
        frames.extend(it.frame for it in source.poll(0.05) if isinstance(it, Frame))
    source.close()
    assert len(frames) == 75 and {f.skeleton for f in frames} == {AZURE_KINECT.name}
    assert frames[0].bodies[0].positions.shape == (32, 3)


def test_clean_reads_the_export(tmp_path):
    out = tmp_path / "clean.sfrec"
    proc = subprocess.run([sys.executable, "-m", "streamfix", "clean", str(FIXTURE), str(out), "--quiet"],
                          capture_output=True, text=True, timeout=120, env=child_env(), cwd=str(PROJECT_ROOT))
    assert proc.returncode == 0, proc.stderr
    cleaned = read_motion(out)
    assert cleaned.skeleton.name == AZURE_KINECT.name and cleaned.n_frames >= 75


def test_live_azure_kinect_says_it_is_not_built_in_and_what_works():
    """One message, binding installed or not (installing one would not make live capture work)."""
    with pytest.raises(RuntimeError, match="not built in yet.*offline_processor.*--source take.json"):
        open_source("azure-kinect")
