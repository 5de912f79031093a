"""The C++ reference subscriber (libzmq + msgpack-c): built with make, checked on every
test vector (and on tampered copies it must refuse), and run against a live loopback
PUB publishing real encoded frames."""
from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from test_protocol_live import MISSING_JOINT, LoopbackPublisher  # noqa: F401  (shared loopback publisher)
from test_protocol_vectors import VECTORS, _tampered_copies

from streamfix.skeletons import Skeleton

CPP = Path(__file__).resolve().parents[1] / "protocol" / "cpp"


@pytest.fixture(scope="module")
def cpp_subscriber(tmp_path_factory) -> Path:
    missing = [tool for tool in ("g++", "make") if shutil.which(tool) is None]
    if missing:
        pytest.skip(f"cannot build the C++ subscriber: {', '.join(missing)} not installed "
                    "(CI installs g++ make pkg-config libzmq3-dev libmsgpack-dev)")
    headers = [h for h in ("/usr/include/zmq.h", "/usr/include/msgpack.h") if not Path(h).exists()]
    build = tmp_path_factory.mktemp("cpp")
    # -O0: compiles in about half the time; speed does not matter for these checks
    proc = subprocess.run(["make", "-C", str(CPP), f"BUILD={build}", "CXXFLAGS=-O0 -g"],
                          capture_output=True, text=True, timeout=300)
    if proc.returncode != 0:
        if headers or "No such file or directory" in proc.stderr:
            pytest.skip(f"C++ subscriber headers missing ({', '.join(headers) or 'see make output'}): "
                        "apt-get install libzmq3-dev libmsgpack-dev")
        pytest.fail(f"make failed:\n{proc.stdout}\n{proc.stderr}")
    return build / "subscriber"


def test_cpp_subscriber_checks_every_vector(cpp_subscriber):
    proc = subprocess.run([str(cpp_subscriber), "--vectors", str(VECTORS)], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[-1].split()[0].split("/")[0] == lines[-1].split()[0].split("/")[1]
    assert not any(line.startswith("FAIL") for line in lines)
    assert sum(": rejected (" in line for line in lines) >= 15


def test_cpp_subscriber_notices_tampered_vectors(cpp_subscriber, tmp_path):
    for what, directory in _tampered_copies(tmp_path):
        proc = subprocess.run([str(cpp_subscriber), "--vectors", str(directory)],
                              capture_output=True, text=True, timeout=60)
        assert proc.returncode == 1, f"{what}: tampering not detected\n{proc.stdout}"


def _parse(line: str) -> dict:
    fields = line.split()
    out = {"topic": fields[0], "bodies": {}, "filled": "filled" in fields}
    for f in fields[1:]:
        if "=" in f:
            k, v = f.split("=")
            out["n_bodies" if k == "bodies" else k] = int(v)
        elif ":" in f:
            bid, counts = f.split(":")
            out["bodies"][int(bid)] = tuple(int(x) for x in counts.split("/"))
    return out


def test_cpp_subscriber_reads_a_live_stream(cpp_subscriber):
    with LoopbackPublisher(kind="clean", stream="kinect0", garbage_every=5) as lp:
        proc = subprocess.run(
            [str(cpp_subscriber), "--connect", lp.endpoint, "--topic", "sf/clean/", "--count", "15", "--timeout", "20"],
            capture_output=True, text=True, timeout=60,
        )
    assert proc.returncode == 0, proc.stderr
    frames = [_parse(line) for line in proc.stdout.strip().splitlines()]
    assert len(frames) == 15
    seqs = [f["seq"] for f in frames]
    assert seqs == list(range(seqs[0], seqs[0] + 15)), "in order, none lost on loopback"
    for f in frames:
        assert f["topic"] == "sf/clean/kinect0" and f["n_bodies"] == 2
        assert f["t_sensor_ns"] == f["seq"] * 33_333_333
        # 25 joints: 23 observed, 1 recovered, 1 missing (NaN on the wire), for bodies 1 and 4
        assert f["bodies"] == {1: (23, 1, 1), 4: (23, 1, 1)}
    assert "rejected on sf/clean/kinect0: garbage" in proc.stderr


def test_cpp_subscriber_learns_a_custom_skeleton(cpp_subscriber):
    arm = Skeleton("cpp_arm", tuple(f"j{i}" for i in range(10)), tuple((i, i + 1) for i in range(9)))
    with LoopbackPublisher(kind="live", stream="arm", skeleton=arm) as lp:
        proc = subprocess.run(
            [str(cpp_subscriber), "--connect", lp.endpoint, "--topic", "sf/live/arm", "--count", "5", "--timeout", "20"],
            capture_output=True, text=True, timeout=60,
        )
    assert proc.returncode == 0, proc.stderr
    frames = [_parse(line) for line in proc.stdout.strip().splitlines()]
    assert len(frames) == 5 and all(f["bodies"] == {1: (8, 1, 1), 4: (8, 1, 1)} for f in frames)
    assert "skeleton=cpp_arm joints=10 bones=9 rate_hz=30" in proc.stderr


def test_cpp_subscriber_times_out_without_a_publisher(cpp_subscriber):
    proc = subprocess.run([str(cpp_subscriber), "--connect", "tcp://127.0.0.1:9", "--count", "1", "--timeout", "0.5"],
                          capture_output=True, text=True, timeout=30)
    assert proc.returncode == 2
