"""Test vectors: they cannot drift from the wire module, and independent decoders agree."""
from __future__ import annotations

import ast
import json
import shutil
import subprocess
import sys
from pathlib import Path

import msgpack
import pytest

PROJECT = Path(__file__).resolve().parents[1]
PROTOCOL = PROJECT / "protocol"
VECTORS = PROTOCOL / "vectors"
REFERENCE = PROTOCOL / "python" / "subscriber.py"


def _make_vectors_module():
    sys.path.insert(0, str(PROTOCOL))
    try:
        import make_vectors  # noqa: PLC0415
    finally:
        sys.path.remove(str(PROTOCOL))
    return make_vectors


def test_committed_vectors_equal_a_fresh_generation(tmp_path):
    make_vectors = _make_vectors_module()
    names = make_vectors.write_vectors(tmp_path)
    fresh = sorted(p.name for p in tmp_path.iterdir())
    committed = sorted(p.name for p in VECTORS.iterdir())
    assert fresh == committed, "protocol/vectors has stale or missing files: run protocol/make_vectors.py"
    for name in fresh:
        assert (tmp_path / name).read_bytes() == (VECTORS / name).read_bytes(), (
            f"{name} differs from a fresh run of protocol/make_vectors.py"
        )
    assert len(names) >= 25


def test_vectors_cover_the_required_cases():
    index = json.loads((VECTORS / "index.json").read_text())
    metas = [json.loads((VECTORS / f"{n}.json").read_text()) for n in index["vectors"]]
    valid = [m for m in metas if m["valid"]]
    frames = [m["message"] for m in valid if m["message"]["type"] == "frame"]
    assert any(any(p is None for b in f["bodies"] for p in b["positions"]) for f in frames), "missing joints"
    assert any(len(f["bodies"]) > 1 for f in frames), "several bodies"
    assert any(f["filled"] for f in frames), "a filled frame"
    assert any(m["message"]["type"] == "skeleton" for m in valid), "a skeleton message"
    reasons = {m["reason"] for m in metas if not m["valid"]}
    assert {"joints", "truncated", "version", "garbage", "skeleton"} <= reasons


def test_payloads_use_no_extension_types():
    """Only maps, arrays, ints, floats, bools, strings and bin: decodable by any client."""
    index = json.loads((VECTORS / "index.json").read_text())
    for name in index["vectors"]:
        meta = json.loads((VECTORS / f"{name}.json").read_text())
        if not meta["valid"]:
            continue

        def no_ext(code, data):
            raise AssertionError(f"{name}: extension type {code}")

        msgpack.unpackb((VECTORS / f"{name}.bin").read_bytes(), raw=False, ext_hook=no_ext)


def test_schema_accepts_every_valid_vector_map():
    jsonschema = pytest.importorskip("jsonschema", reason="jsonschema is not a project dependency")
    schema = json.loads((PROTOCOL / "schema.json").read_text())
    index = json.loads((VECTORS / "index.json").read_text())
    validator = jsonschema.Draft202012Validator(schema)
    for name in index["vectors"]:
        meta = json.loads((VECTORS / f"{name}.json").read_text())
        decoded = msgpack.unpackb((VECTORS / f"{name}.bin").read_bytes(), raw=False) if meta["valid"] else None
        if decoded is not None:
            errors = list(validator.iter_errors(decoded))
            assert not errors, f"{name}: {errors[0].message}"


def test_reference_subscriber_is_standalone():
    """The Python reference imports only the standard library, msgpack and zmq."""
    tree = ast.parse(REFERENCE.read_text())
    modules = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            modules |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            modules.add(node.module.split(".")[0])
    third_party = modules - set(sys.stdlib_module_names)
    assert third_party == {"msgpack", "zmq"}


def test_reference_subscriber_checks_every_vector(tmp_path):
    proc = subprocess.run([sys.executable, str(REFERENCE), "--vectors", str(VECTORS)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    n = len(json.loads((VECTORS / "index.json").read_text())["vectors"])
    assert f"{n}/{n} vectors ok" in proc.stdout


def _tampered_copies(tmp_path: Path) -> list[tuple[str, Path]]:
    """Vector directories each broken in one way a correct checker must notice."""
    out = []
    d = tmp_path / "coord"
    shutil.copytree(VECTORS, d)
    meta = json.loads((d / "frame_raw_one_body.json").read_text())
    meta["message"]["bodies"][0]["positions"][0][1] += 1e-3
    (d / "frame_raw_one_body.json").write_text(json.dumps(meta))
    out.append(("coordinate", d))
    d = tmp_path / "valid_flag"
    shutil.copytree(VECTORS, d)
    meta = json.loads((d / "bad_wrong_joint_count.json").read_text())
    meta["valid"] = True
    meta["message"] = json.loads((d / "frame_raw_one_body.json").read_text())["message"]
    (d / "bad_wrong_joint_count.json").write_text(json.dumps(meta))
    out.append(("invalid accepted", d))
    d = tmp_path / "reason"
    shutil.copytree(VECTORS, d)
    meta = json.loads((d / "bad_newer_version.json").read_text())
    meta["reason"] = "garbage"
    (d / "bad_newer_version.json").write_text(json.dumps(meta))
    out.append(("reason", d))
    d = tmp_path / "recovered"
    shutil.copytree(VECTORS, d)
    meta = json.loads((d / "frame_clean_three_bodies.json").read_text())
    rec = meta["message"]["bodies"][2]["recovered"]
    rec[0] = not rec[0]
    (d / "frame_clean_three_bodies.json").write_text(json.dumps(meta))
    out.append(("recovered", d))
    return out


def test_reference_subscriber_notices_tampered_vectors(tmp_path):
    for what, directory in _tampered_copies(tmp_path):
        proc = subprocess.run([sys.executable, str(REFERENCE), "--vectors", str(directory)],
                              capture_output=True, text=True, timeout=60)
        assert proc.returncode == 1, f"{what}: tampering not detected\n{proc.stdout}"
        assert "FAIL" in proc.stdout
