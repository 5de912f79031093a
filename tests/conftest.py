"""Shared fixtures: where the real recordings live (never copied into the project)."""
from __future__ import annotations

import signal
from pathlib import Path

import pytest

PROJECT_ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = (PROJECT_ROOT / ".." / "shared" / "data").resolve()

# A shell without job control starts a background command with SIGINT ignored, and an ignored
# signal stays ignored in every child it runs: the tests that Ctrl-C a `streamfix` subprocess
# would see it run to the end. The suite restores the default so it passes however it was started.
if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.fail(f"real recordings not found at {SHARED_DATA}: the checkout needs ../shared/data beside it")
    return SHARED_DATA


@pytest.fixture(scope="session")
def keraal(shared_data):
    """The KERAAL Kinect v2 + Vicon take of ../shared/data/paired (a streamfix.io.paired.PairedTake)."""
    from streamfix.io.paired import find_takes, load_take

    refs = [r for r in find_takes(shared_data / "paired") if r.dataset == "keraal"]
    assert refs, "the KERAAL paired take is missing from ../shared/data/paired"
    return load_take(refs[0])


@pytest.fixture(scope="session")
def walking_kinect30(shared_data):
    """CMU 131_01 as exact Kinect v2 joints at 30 Hz, 20 s: feet at toe-off and heel strike
    accelerate faster than a line through 7 samples (0.23 s) can follow. Exact
    optical motion capture: no sensor noise."""
    from streamfix.evaluation.sensor import ground_truth

    walking = ground_truth(shared_data / "cmu_bvh" / "131_01.bvh", 30.0).positions[:600]
    walking.setflags(write=False)  # shared by every test of the session
    return walking


@pytest.fixture(scope="session")
def project_root() -> Path:
    return PROJECT_ROOT
