"""``streamfix clean DIR OUT_DIR``: a folder of real Kinect v2 takes, one process, a process pool, a real Dask cluster.

The recordings are short slices of the real CSVs in ``shared/data/kinect_v2`` written to
``tmp_path``. Checks: a 2-worker ``distributed.LocalCluster`` on 127.0.0.1 writes files
byte-for-byte equal to the single-process run (and to ``streamfix clean FILE OUT``);
a corrupt input is reported in the JSON summary and the others are still cleaned; a
second run skips complete outputs, re-does a missing one and ignores a stale partial.
"""
from __future__ import annotations

import json
import os

import pytest

from streamfix.cli import main

FRAMES = 45  # per recording: long enough for a solved window, short enough for a fast test


def _slices(shared_data, folder, n: int) -> list:
    """``n`` recordings of FRAMES lines cut from the real Kinect v2 CSVs (one frame per line)."""
    folder.mkdir(parents=True, exist_ok=True)
    sources = sorted((shared_data / "kinect_v2").glob("Ges*.csv"))
    paths = []
    for k in range(n):
        lines = sources[k % len(sources)].read_text().splitlines()
        start = (k // len(sources)) * FRAMES
        path = folder / f"take{k:02d}.csv"
        path.write_text("\n".join(lines[start:start + FRAMES]) + "\n")
        paths.append(path)
    return paths


def _corrupt(shared_data, path) -> None:
    lines = (shared_data / "kinect_v2" / "Ges01_wavehand.csv").read_text().splitlines()[:FRAMES]
    lines[20] = lines[20][:40]  # a frame cut short, as a copy interrupted mid-write leaves it
    path.write_text("\n".join(lines) + "\n")


def _summary(out_dir) -> dict:
    return json.loads((out_dir / "streamfix-clean-summary.json").read_text())


def test_dask_cluster_writes_the_same_bytes_as_one_process(shared_data, tmp_path):
    import distributed  # the 'cluster' extra, part of the 'test' extra: CI has it
    takes = _slices(shared_data, tmp_path / "in" / "session", 10)
    single, clustered = tmp_path / "single", tmp_path / "cluster"
    assert main(["clean", str(tmp_path / "in"), str(single), "--quiet"]) == 0
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as cluster:
        assert cluster.scheduler_address.startswith("tcp://127.0.0.1:")
        assert main(["clean", str(tmp_path / "in" / "session" / "take*.csv"), str(clustered),
                     "--cluster", cluster.scheduler_address, "--quiet"]) == 0
    for take in takes:
        a, b = single / "session" / take.name, clustered / take.name  # a folder keeps its sub-folders
        assert a.read_bytes() == b.read_bytes(), take.name
        assert a.read_bytes() != take.read_bytes()  # cleaned, not copied
    summary = _summary(clustered)
    assert (summary["inputs"], summary["ok"], summary["failed"]) == (10, 10, 0)
    assert all(r["frames"] == FRAMES and r["seconds"] > 0 for r in summary["files"])
    # and the archive's file is the single-file command's file
    one = tmp_path / "one.csv"
    assert main(["clean", str(takes[3]), str(one), "--quiet"]) == 0
    assert one.read_bytes() == (single / "session" / takes[3].name).read_bytes()


def test_corrupt_input_is_reported_and_a_rerun_resumes(shared_data, tmp_path, capsys):
    takes = _slices(shared_data, tmp_path / "in", 3)
    bad = tmp_path / "in" / "take99.csv"
    _corrupt(shared_data, bad)
    out = tmp_path / "out"
    assert main(["clean", str(tmp_path / "in"), str(out), "--jobs", "2"]) == 1  # one failed: non-zero
    err = capsys.readouterr().err
    assert "[4/4]" in err and "take99.csv: FAILED" in err and "1 failed" in err
    records = {os.path.basename(r["input"]): r for r in _summary(out)["files"]}
    assert records["take99.csv"]["status"] == "failed" and "line 21" in records["take99.csv"]["error"]
    assert not (out / "take99.csv").exists()
    assert all(records[t.name]["status"] == "ok" and (out / t.name).stat().st_size > 0 for t in takes)
    assert sorted(p.name for p in out.iterdir()) == sorted([t.name for t in takes] + ["streamfix-clean-summary.json"])

    # resume: one output lost, a partial file left by a killed run; the complete ones are kept as they are
    kept = out / takes[0].name
    os.utime(kept, (1_000_000, 1_000_000))
    before = kept.read_bytes()
    (out / takes[1].name).unlink()
    (out / f".{takes[1].stem}.part-12345.csv").write_text("1,2,3\n")
    assert main(["clean", str(tmp_path / "in"), str(out), "--quiet"]) == 1
    files = _summary(out)["files"]
    status = {os.path.basename(r["input"]): r["status"] for r in files}
    assert status == {takes[0].name: "skipped", takes[1].name: "ok", takes[2].name: "skipped", "take99.csv": "failed"}
    assert all(r["frames"] == FRAMES for r in files if r["status"] != "failed")  # carried from the first run
    assert kept.stat().st_mtime == 1_000_000 and kept.read_bytes() == before
    assert (out / takes[1].name).stat().st_size > 0

    # the input fixed, a third run completes with exit 0
    bad.write_text(takes[2].read_text())
    assert main(["clean", str(tmp_path / "in"), str(out), "--quiet"]) == 0
    assert _summary(out)["failed"] == 0


@pytest.mark.parametrize("case", ["out_is_file", "nothing_matches", "lengths", "jobs_and_cluster", "bad_local",
                                  "jobs_for_one_file"])
def test_bad_archive_requests_exit_2_with_a_reason(shared_data, tmp_path, capsys, case):
    _slices(shared_data, tmp_path / "in", 1)
    out = tmp_path / "out"
    args = {
        "out_is_file": ([str(tmp_path / "in"), str(tmp_path / "in" / "take00.csv")], "must be a folder"),
        "nothing_matches": ([str(tmp_path / "in" / "*.bvh"), str(out)], "no motion files found"),
        "lengths": ([str(tmp_path / "in"), str(out), "--skeleton-lengths", "0.1"], "not to a folder"),
        "jobs_and_cluster": ([str(tmp_path / "in"), str(out), "--jobs", "2", "--cluster", "local:2"], "exclude"),
        "bad_local": ([str(tmp_path / "in"), str(out), "--cluster", "local:zero"], "local:N"),
        "jobs_for_one_file": ([str(tmp_path / "in" / "take00.csv"), str(tmp_path / "o.csv"), "--jobs", "2"],
                              "apply when IN is a folder or a glob"),
    }[case]
    code = main(["clean", *args[0]])
    assert code in (1, 2) if case == "bad_local" else code == 2
    assert args[1] in capsys.readouterr().err


def test_outputs_inside_the_input_folder_are_not_cleaned_again(shared_data, tmp_path):
    takes = _slices(shared_data, tmp_path / "in", 2)
    out = tmp_path / "in" / "cleaned"
    assert main(["clean", str(tmp_path / "in"), str(out), "--quiet"]) == 0
    assert main(["clean", str(tmp_path / "in"), str(out), "--quiet"]) == 0
    summary = _summary(out)
    assert summary["inputs"] == len(takes) and summary["skipped"] == len(takes)
    assert not (out / "cleaned").exists()


def test_a_folder_takes_the_single_file_schedule_options(shared_data, tmp_path):
    """--lookahead (seconds or frames, as for one file) and --schedule reach every file of a folder:
    each output equals ``streamfix clean FILE OUT`` with the same options (a lookahead of
    '15f' once reached the engine as text and failed every file)."""
    takes = _slices(shared_data, tmp_path / "in", 2)
    for k, opts in enumerate((["--lookahead", "15f"], ["--lookahead", "0.5"], ["--schedule", "serve"])):
        out = tmp_path / f"out{k}"
        assert main(["clean", str(tmp_path / "in"), str(out), "--quiet", *opts]) == 0
        assert _summary(out)["failed"] == 0
        single = tmp_path / f"single{k}.csv"
        assert main(["clean", str(takes[0]), str(single), "--quiet", *opts]) == 0
        assert (out / "take00.csv").read_bytes() == single.read_bytes()
    assert main(["clean", str(tmp_path / "in"), str(tmp_path / "bad"), "--quiet", "--lookahead", "soon"]) == 2
