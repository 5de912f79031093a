"""BVH writer: the input hierarchy kept, rotations solved from (cleaned) positions, read back by the BVH reader."""
from __future__ import annotations

import numpy as np
import pytest

from streamfix.cli import main
from streamfix.io import read_motion, write_motion
from streamfix.io.bvh import parse_bvh_hierarchy, read_bvh
from streamfix.motion import Motion
from streamfix.skeletons import COCO_17
from streamfix.streaming.engine import EngineConfig
from streamfix.streaming.offline import clean_motion


def _hierarchy(path):
    nodes, _ = parse_bvh_hierarchy(path, path.read_text().splitlines())
    return [(n.name, n.parent, tuple(np.round(n.offset, 5)), tuple(n.channels), n.end_site) for n in nodes]


@pytest.mark.parametrize("take", ["cmu_bvh/131_01.bvh", "xia_bvh/angry_13_000.bvh"])
def test_real_take_written_back_keeps_hierarchy_and_positions(shared_data, tmp_path, take):
    src = shared_data / take
    m = read_bvh(src)
    out = tmp_path / "out.bvh"
    write_motion(m, out)
    assert _hierarchy(out) == _hierarchy(src)  # names, offsets, channel order, End Sites
    r = read_bvh(out)
    assert r.skeleton == m.skeleton and r.n_frames == m.n_frames and r.rate_hz == m.rate_hz
    assert r.meta["scale"] == m.meta["scale"]
    assert np.abs(r.positions - m.positions).max() < 1e-4


def test_cleaned_bvh_round_trip_within_1mm(shared_data, tmp_path):
    src = shared_data / "xia_bvh" / "depressed_18_000.bvh"
    m = read_bvh(src)
    lossy = m.copy()  # a hand lost for 30 frames and a forearm for 20: the cleaner fills them
    # (gaps of 0.1 s or less are bridged through their neighbours in time, on mocap to
    # within a fraction of a millimetre: too close to the take to show it was cleaned)
    for joint, frames in (("LeftHand", slice(40, 70)), ("RightForeArm", slice(75, 95))):
        lossy.positions[frames, m.skeleton.index(joint)] = np.nan
        lossy.confidence[frames, m.skeleton.index(joint)] = 0.0
    cleaned, _ = clean_motion(lossy, EngineConfig(rate_hz=m.rate_hz))
    assert np.abs(cleaned.positions - m.positions).max() > 1e-3  # the cleaner did change the take
    out = tmp_path / "clean.bvh"
    write_motion(cleaned, out)
    assert _hierarchy(out) == _hierarchy(src)
    back = read_bvh(out)
    assert np.linalg.norm(back.positions - cleaned.positions, axis=2).max() < 1e-3


def test_clean_cli_kinect_csv_to_bvh(shared_data, tmp_path, capsys):
    src = shared_data / "kinect_v2" / "Ges01_wavehand.csv"
    out = tmp_path / "clean.bvh"
    assert main(["clean", str(src), str(out), "--quiet"]) == 0
    back = read_bvh(out)
    assert back.meta["scale"] == 1.0  # a new hierarchy, in metres
    expect, _ = clean_motion(read_motion(src), EngineConfig.for_files(read_motion(src).rate_hz))
    idx = [back.skeleton.index(n) for n in expect.skeleton.joint_names]
    assert back.n_frames == expect.n_frames
    assert np.linalg.norm(back.positions[:, idx] - expect.positions, axis=2).max() < 1e-3
    # rest pose of the new hierarchy is a T-pose: the left elbow hangs out to +x from the shoulder
    nodes, _ = parse_bvh_hierarchy(out, out.read_text().splitlines())
    elbow = next(n for n in nodes if n.name == "ElbowLeft")
    assert elbow.offset[0] > 0.2 and abs(elbow.offset[1]) < 1e-9
    assert "SpineShoulder_ShoulderLeft" in back.skeleton.joint_names  # branch joint: clavicle aimed on its own


def test_graph_skeleton_is_refused_before_solving(tmp_path, capsys):
    m = Motion.from_positions(np.random.default_rng(0).normal(size=(10, 17, 3)), COCO_17, 30.0)
    with pytest.raises(ValueError, match="coco17.*cannot be written as BVH.*trc"):
        write_motion(m, tmp_path / "x.bvh")
    write_motion(m, tmp_path / "x.sfrec")
    assert main(["clean", str(tmp_path / "x.sfrec"), str(tmp_path / "y.bvh"), "--quiet"]) == 2
    assert "cannot be written as BVH" in capsys.readouterr().err
    assert not (tmp_path / "y.bvh").exists()
