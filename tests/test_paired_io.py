"""Paired loaders on the real recordings: shapes, units, alignment quality, lost markers, errors."""
from __future__ import annotations

import csv

import numpy as np
import pytest

from streamfix.io import MotionFileError
from streamfix.io.paired import (
    KERAAL_PAIRS,
    UIPRMD_MARKERS,
    UIPRMD_REFERENCE,
    TakeRef,
    find_takes,
    load_keraal_take,
    load_take,
    load_uiprmd_take,
)
from streamfix.evaluation.paired import body_region
from streamfix.skeletons import get_skeleton


@pytest.fixture(scope="module")
def paired(shared_data):
    return shared_data / "paired"


@pytest.fixture(scope="module")
def npz(paired):
    return paired / "uiprmd" / "uiprmd_s01-s06.npz"


@pytest.fixture(scope="module")
def keraal(paired):
    return load_keraal_take(paired / "keraal" / "G3-Kinect-CTK-P1T1-Unknown-C-0.txt")


def _upper_ref_errors(take, debias: bool) -> np.ndarray:
    names = take.sensor.skeleton.joint_names
    upper = np.array([body_region(n) == "upper" for n in names]) & take.referenced
    d = take.sensor.positions[:, upper] - take.reference[:, upper]
    if debias:
        d = d - np.nanmean(d, axis=0)
    e = np.linalg.norm(d, axis=2)
    return e[np.isfinite(e)]


def test_uiprmd_take_shapes_units_and_alignment(npz):
    # shoulder abduction, standing, in the trustworthy subset
    take = load_uiprmd_take(npz, "cor_m07_s02_e01")
    m = take.sensor
    assert take.dataset == "uiprmd" and take.trustworthy and take.movement == "m07" and take.subject == "s02"
    assert m.skeleton is get_skeleton("kinect_v1_uiprmd") and m.positions.shape == take.reference.shape
    assert m.positions.shape[1:] == (22, 3) and m.n_frames > 30
    assert m.rate_hz == pytest.approx(take.meta["fs_hz"]) and 25 <= m.rate_hz <= 33
    np.testing.assert_allclose(np.diff(m.timestamps), 1.0 / m.rate_hz)
    # exactly the joints the README defines a marker mean for have a reference
    have = {m.skeleton.joint_names[j] for j in np.flatnonzero(take.referenced)}
    assert have == set(UIPRMD_REFERENCE)
    # metres: an upper arm is 20-40 cm in both systems, shoulders 25-50 cm apart
    li, le, ri = (m.skeleton.index(n) for n in ("LShoulder", "LElbow", "RShoulder"))
    for x in (m.positions, take.reference):
        assert 0.2 < np.nanmedian(np.linalg.norm(x[:, li] - x[:, le], axis=1)) < 0.4
        assert 0.25 < np.nanmedian(np.linalg.norm(x[:, li] - x[:, ri], axis=1)) < 0.5
    # alignment: the raw upper body within ~5 cm (marker offsets), a few cm once debiased
    assert np.median(_upper_ref_errors(take, debias=False)) < 0.08
    assert np.median(_upper_ref_errors(take, debias=True)) < 0.03


def test_uiprmd_alignment_is_inverted_correctly(npz):
    """Mapping the Vicon with R, t instead of their inverse puts it metres away."""
    take = load_uiprmd_take(npz, "cor_m07_s02_e01")
    R, t = take.meta["R"], take.meta["t"]
    wrong = take.reference @ R.T + t  # reference taken back to the Vicon frame
    err_right = np.nanmedian(np.linalg.norm(take.sensor.positions - take.reference, axis=2))
    err_wrong = np.nanmedian(np.linalg.norm(take.sensor.positions - wrong, axis=2))
    assert err_right < 0.1 < 1.0 < err_wrong


def test_uiprmd_lost_marker_gives_nan_reference(npz):
    z = np.load(npz)
    key = "cor_m03_s01_e02"  # RBHD (a head marker) lost for 25 Vicon frames
    lost = (z[f"vicon_{key}"][:, UIPRMD_MARKERS.index("RBHD")] == 0).all(axis=1)
    assert 0 < lost.sum() < len(lost)
    take = load_uiprmd_take(npz, key)
    sk = take.sensor.skeleton
    head = np.isfinite(take.reference[:, sk.index("HeadTip")]).all(axis=1)
    assert (~head).any() and head.any()
    u = (np.arange(take.sensor.n_frames) / take.meta["fs_hz"] + take.meta["offset_s"]) * 100.0
    inside = (u >= 0) & (u <= len(lost) - 1)
    a = np.clip(np.floor(u).astype(int), 0, len(lost) - 2)
    near_lost = lost[a] | lost[a + 1]
    assert np.array_equal(~head & inside, near_lost & inside)
    # a joint whose markers were never lost has a reference wherever the Vicon ran
    assert np.isfinite(take.reference[inside, sk.index("LShoulder")]).all()


def test_trustworthy_subset_follows_pairs_csv(paired):
    with open(paired / "uiprmd" / "pairs.csv", newline="") as fh:
        rows = {r["key"]: r for r in csv.DictReader(fh)}
    trusted = [r for r in find_takes(paired, "trustworthy") if r.dataset == "uiprmd"]
    everything = [r for r in find_takes(paired, "all") if r.dataset == "uiprmd"]
    assert 800 < len(trusted) < len(everything) and len(everything) >= len(rows)
    for ref in trusted:
        row = rows[ref.key]
        assert float(row["pos_corr"]) > 0.95 and 25 <= float(row["fs_eff"]) <= 33
    quick = find_takes(paired, "trustworthy", limit=5)
    assert sum(r.dataset == "uiprmd" for r in quick) == 5
    assert len({r.key.split("_")[1] for r in quick if r.dataset == "uiprmd"}) >= 3  # spread over movements


def test_keraal_fit_is_sane(keraal):
    m = keraal.sensor
    assert keraal.dataset == "keraal" and m.skeleton is get_skeleton("kinect_v2")
    assert m.positions.shape == keraal.reference.shape and m.n_frames > 150 and m.rate_hz == 30.0
    have = {m.skeleton.joint_names[j] for j in np.flatnonzero(keraal.referenced)}
    assert have == {j for j, _ in KERAAL_PAIRS}
    A = keraal.meta["rotation"]
    np.testing.assert_allclose(A @ A.T, np.eye(3), atol=1e-9)
    assert np.linalg.det(A) == pytest.approx(1.0)
    # targets sit within ~15 cm of the joint; the fit explains the sensor to ~2 cm
    assert np.all(np.linalg.norm(keraal.meta["offsets"], axis=1) < 0.2)
    assert keraal.meta["fit_residual_median_m"] < 0.03
    assert keraal.meta["fit_inlier_fraction"] > 0.85
    assert np.median(_upper_ref_errors(keraal, debias=True)) < 0.04


def test_keraal_gross_failures_stay_in_the_reference_error(keraal):
    """Outliers are dropped from the fit, not from the reference: the hand jump is scored."""
    err = np.linalg.norm(keraal.sensor.positions - keraal.reference, axis=2)
    assert np.nanmax(err) > 0.2 > np.nanmedian(err)


def test_bad_inputs_name_the_problem(paired, tmp_path):
    src = paired / "keraal" / "G3-Kinect-CTK-P1T1-Unknown-C-0.txt"
    lines = src.read_text().splitlines()
    bad = tmp_path / "X-Kinect-CTK-P1T1.txt"
    bad.write_text("\n".join(lines[:5] + [" ".join(lines[5].split()[:-1])] + lines[6:]) + "\n")
    vicon = paired / "keraal" / src.name.replace("Kinect", "Vicon")
    (tmp_path / "X-Vicon-CTK-P1T1.txt").write_text(vicon.read_text())
    with pytest.raises(MotionFileError, match=r"line 6: expected 175 numbers .* got 174"):
        load_keraal_take(bad)
    lonely = tmp_path / "Y-Kinect-CTK.txt"
    lonely.write_text(src.read_text())
    with pytest.raises(FileNotFoundError, match="Y-Vicon-CTK.txt"):
        load_keraal_take(lonely)
    with pytest.raises(MotionFileError, match="no_such_key"):
        load_take(TakeRef("uiprmd", str(paired / "uiprmd" / "uiprmd_s01-s06.npz"), "no_such_key"))
    with pytest.raises(ValueError, match="trustworthy, all"):
        find_takes(paired, "everything")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="no paired takes"):
        find_takes(tmp_path / "empty", "all")
