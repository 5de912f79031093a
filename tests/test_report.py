"""``streamfix report`` and ``streamfix eval --report``: figures of real cleanings, checked programmatically."""
from __future__ import annotations

import base64
import io
import re

import numpy as np
import pytest
from matplotlib.figure import Figure
from matplotlib.image import imread

from streamfix.cli import main
from streamfix.report import FIGURES, load_report_data, summarise
from streamfix.report.figures import figure_height

PAIRED = "paired/uiprmd/uiprmd_s01-s06.npz:cor_m07_s02_e01"  # shoulder abduction, a trustworthy pair


def _assert_not_blank(png: bytes | str, what: str) -> None:
    img = imread(io.BytesIO(png) if isinstance(png, bytes) else png)
    rgb = img[..., :3].astype(float)
    ink = (rgb.min(axis=2) < 0.9).mean()  # share of pixels that are not (near) white
    assert img.shape[0] > 200 and img.shape[1] > 500, f"{what}: {img.shape}"
    assert ink > 0.03 and rgb.std() > 0.05, f"{what} looks blank: ink {ink:.3f}, std {rgb.std():.3f}"
    assert len(np.unique(rgb.reshape(-1, 3).round(2), axis=0)) > 20, f"{what} has almost no colours"


def _assert_axes_labelled(fig: Figure, name: str) -> None:
    axes = [ax for ax in fig.get_axes() if ax.get_visible()]
    assert axes, f"{name}: no axes"
    for ax in axes:
        assert ax.has_data(), f"{name}: an axes with nothing drawn"
        shared_x = ax.get_subplotspec() is not None and not ax.get_subplotspec().is_last_row()
        assert ax.get_xlabel() or shared_x, f"{name}: x axis unlabelled"
        assert ax.get_ylabel() or (ax.get_shared_y_axes().get_siblings(ax) != [ax]), f"{name}: y axis unlabelled"


def test_paired_report_overlays_the_reference_and_charts_per_joint_error(tmp_path, shared_data, capsys):
    spec = str(shared_data / PAIRED)
    out = tmp_path / "paired.png"
    rc = main(["report", spec, "-o", str(out), "--joints", "RWrist,LKnee"])
    assert rc == 0, capsys.readouterr().err
    _assert_not_blank(out.read_bytes(), "paired report PNG")
    data = load_report_data(spec, joints=["RWrist", "LKnee"])
    assert data.reference is not None and np.isfinite(data.reference).all(axis=2).any(axis=0).sum() == 17
    summary = summarise(data.raw, data.clean, data.reference)
    # smoother, and no further from the optical truth once the markers' offset is removed
    assert summary["jitter_clean_mm"] < 0.7 * summary["jitter_raw_mm"], summary
    assert summary["ref_error_debiased_clean_cm"] < 1.1 * summary["ref_error_debiased_raw_cm"], summary
    assert 0.1 < summary["ref_error_debiased_raw_cm"] < 5 < summary["ref_error_raw_cm"] < 20, summary
    for name, (draw, _, _, _) in FIGURES.items():  # every figure, axes labelled and not empty
        fig = Figure(figsize=(11, figure_height(name, data)), layout="constrained")
        draw(fig, data)
        _assert_axes_labelled(fig, name)
        if name == "trajectories":
            labels = {line.get_label() for ax in fig.get_axes() for line in ax.get_lines()}
            assert {"raw", "cleaned", "reference (offset removed)"} <= labels, labels
            titles = {ax.get_title() for ax in fig.get_axes()}
            assert {"RWrist x", "LKnee z"} <= titles, titles
        if name == "reference_errors":
            bars = [p for p in fig.get_axes()[0].patches]
            assert len(bars) == 2 * 17 and all(b.get_height() > 0 for b in bars)


def test_report_cli_refuses_bad_input(tmp_path, shared_data, capsys):
    take = str(shared_data / "kinect_v2" / "Ges01_wavehand.csv")
    short = tmp_path / "short.csv"
    lines = (shared_data / "kinect_v2" / "Ges01_wavehand.csv").read_text().splitlines(keepends=True)
    short.write_text("".join(lines[:60]))
    cases = [
        ([take, "-o", str(tmp_path / "r.pdf")], 2, "expected a .html or .png"),
        ([take, str(short), "-o", str(tmp_path / "r.html")], 1, "expected the same frames"),
        ([str(shared_data / "paired/uiprmd/uiprmd_s01-s06.npz:cor_m99"), "-o", str(tmp_path / "r.png")], 1,
         "repetition 'cor_m99'"),
    ]
    for argv, code, message in cases:
        rc = main(["report", *argv])
        err = capsys.readouterr().err
        assert rc == code and message in err, (argv, rc, err)
        assert not (tmp_path / "r.html").exists()


def test_eval_report_writes_one_html_per_file(tmp_path, shared_data, capsys):
    take = shared_data / "kinect_v2" / "Ges02_balancinghands.csv"
    rc = main(["eval", str(take), "--protocol", "kinect", "--methods", "input", "--report", str(tmp_path / "rep")])
    err = capsys.readouterr().err
    assert rc == 0, err
    page = tmp_path / "rep" / "Ges02_balancinghands.html"
    assert page.is_file() and f"wrote {page}" in err
    text = page.read_text()
    pngs = re.findall(r'src="data:image/png;base64,([^"]+)"', text)
    assert len(pngs) == len(FIGURES) - 1, "every figure but the reference errors (no reference here)"
    for i, b64 in enumerate(pngs):
        _assert_not_blank(base64.b64decode(b64), f"figure {i}")
    m = re.search(r"jitter, mean \|2nd difference\| \(mm/frame\^2\)</th><td>([\d.]+) raw -&gt; ([\d.]+) cleaned", text)
    assert m and float(m.group(2)) < float(m.group(1)), "the summary states the jitter before and after"


@pytest.mark.parametrize("bad", ["x.npz", "x.npz:", "x.csv:key"])
def test_paired_spec_needs_file_npz_colon_key(bad):
    from streamfix.report._uiprmd import parse_paired_spec

    assert parse_paired_spec(bad) is None
    assert parse_paired_spec("a/b.npz:cor_m01_s01_e01") is not None
