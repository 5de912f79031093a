"""Assemble a report: load and clean the input, then write HTML (PNGs embedded) or one PNG.

``load_report_data`` reads the input (any file ``streamfix.io.read_motion`` reads, or a
UI-PRMD repetition ``uiprmd_s01-s06.npz:KEY`` that brings its optical reference),
takes the cleaned motion from a file or cleans it with the streaming engine
(:func:`streamfix.streaming.offline.clean_motion` on the file schedule, what ``streamfix clean`` writes),
and picks the joints to plot. ``write_report`` renders :data:`.figures.FIGURES`.
"""
from __future__ import annotations

import base64
import html
import io
from pathlib import Path

import numpy as np

from ..motion import Motion
from .figures import FIGURES, ReportData, choose_joints, figure_height
from .summary import summarise

__all__ = ["load_report_data", "report_from_motions", "write_report", "render_png", "write_file_reports"]

WIDTH_IN = 11.0
DPI = 100


def _joint_indices(motion: Motion, names: list[str] | None) -> list[int] | None:
    if not names:
        return None
    out = []
    for n in names:
        try:
            out.append(motion.skeleton.index(n))
        except KeyError:
            raise ValueError(f"joint {n!r} is not in skeleton {motion.skeleton.name!r}; "
                             f"expected one of: {', '.join(motion.skeleton.joint_names)}") from None
    return out


def report_from_motions(name: str, raw: Motion, clean: Motion | None = None, *,
                        reference: np.ndarray | None = None, joints: list[str] | None = None) -> ReportData:
    """A :class:`ReportData` from motions in memory; ``clean`` None = clean ``raw`` with the engine."""
    if clean is None:
        from ..streaming.engine import EngineConfig
        from ..streaming.offline import clean_motion

        clean, _ = clean_motion(raw, EngineConfig.for_files(raw.rate_hz))
    if clean.positions.shape != raw.positions.shape:
        raise ValueError(f"{name}: the cleaned motion has shape {clean.positions.shape}, the input "
                         f"{raw.positions.shape}; expected the same frames and joints")
    if reference is not None and reference.shape != raw.positions.shape:
        raise ValueError(f"{name}: the reference has shape {reference.shape}, expected {raw.positions.shape}")
    picked = _joint_indices(raw, joints) or choose_joints(raw, clean, reference)
    return ReportData(name, raw, clean, reference, picked)


def load_report_data(source: str, cleaned: str | None = None, *, reference: str | None = None,
                     joints: list[str] | None = None, rate_hz: float | None = None) -> ReportData:
    """Read ``source`` (a motion file or ``FILE.npz:KEY``), the cleaned file if given, and a reference.

    ``reference``: a UI-PRMD ``FILE.npz:KEY`` whose optical reference is overlaid (a
    UI-PRMD ``source`` brings its own). ``rate_hz`` resamples a motion file first.
    """
    from ._uiprmd import parse_paired_spec, read_paired

    ref = None
    spec = parse_paired_spec(source)
    if spec is not None:
        raw, ref = read_paired(*spec)
    else:
        from ..evaluation.registry import load_motion

        raw = load_motion(source, rate_hz)
    if reference is not None:
        rspec = parse_paired_spec(reference)
        if rspec is None:
            raise ValueError(f"--reference {reference!r}: expected FILE.npz:KEY (a UI-PRMD repetition)")
        ref_motion, ref = read_paired(*rspec)
        if ref.shape != raw.positions.shape:
            raise ValueError(f"--reference {reference}: {ref.shape} does not match the input {raw.positions.shape}")
    clean = None
    if cleaned is not None:
        from ..io import read_motion

        clean = read_motion(cleaned)
        if clean.n_joints != raw.n_joints:
            raise ValueError(f"{cleaned}: {clean.n_joints} joints, the input {source} has {raw.n_joints}")
        if clean.recovered is None:  # a file format without the flag: recovered = missing in, present out
            observed = np.isfinite(raw.positions).all(axis=2) & (raw.confidence > 0)
            if clean.n_frames == raw.n_frames:
                clean.recovered = ~observed & np.isfinite(clean.positions).all(axis=2)
    return report_from_motions(Path(source).name, raw, clean, reference=ref, joints=joints)


def _figure_names(d: ReportData) -> list[str]:
    return [n for n, (_, _, needs_ref, _) in FIGURES.items() if d.reference is not None or not needs_ref]


def _png_bytes(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    return buf.getvalue()


def render_figures(d: ReportData) -> dict[str, bytes]:
    """Each figure of the report as PNG bytes, by name."""
    from matplotlib.figure import Figure

    out = {}
    for name in _figure_names(d):
        fig = Figure(figsize=(WIDTH_IN, figure_height(name, d)), layout="constrained")
        FIGURES[name][0](fig, d)
        out[name] = _png_bytes(fig)
    return out


def _summary_rows(summary: dict, d: ReportData) -> list[tuple[str, str]]:
    def f(key, fmt="{:.2f}"):
        v = summary.get(key)
        return "-" if v is None or not np.isfinite(v) else fmt.format(v)

    rows = [
        ("frames, rate, duration", f"{summary['frames']} frames at {summary['rate_hz']:g} Hz ({summary['duration_s']:.1f} s), "
                                   f"{summary['joints']} joints"),
        ("input: missing / inferred", f"{f('missing_pct', '{:.1f}')} % / {f('inferred_pct', '{:.1f}')} % of joint samples"),
        ("recovered by the cleaner", f"{f('recovered_pct', '{:.1f}')} % of joint samples"),
        ("jitter, mean |2nd difference| (mm/frame^2)", f"{f('jitter_raw_mm', '{:.3f}')} raw -> {f('jitter_clean_mm', '{:.3f}')} cleaned"),
        ("bone-length CV (%)", f"{f('bone_cv_raw_pct')} raw -> {f('bone_cv_clean_pct')} cleaned"),
        ("joints plotted", ", ".join(d.raw.skeleton.joint_names[j] for j in d.joints)),
    ]
    if "ref_error_raw_cm" in summary:
        rows += [
            ("error vs reference (cm)", f"{f('ref_error_raw_cm')} raw -> {f('ref_error_clean_cm')} cleaned"),
            ("offset removed (cm)", f"{f('ref_error_debiased_raw_cm')} raw -> {f('ref_error_debiased_clean_cm')} cleaned"),
        ]
    return rows


def render_png(d: ReportData, summary: dict) -> bytes:
    """The whole report as one tall PNG: summary text, then every figure."""
    from matplotlib.figure import Figure

    names = _figure_names(d)
    text_h = 0.35 + 0.22 * len(_summary_rows(summary, d))
    heights = [text_h] + [figure_height(n, d) for n in names]
    fig = Figure(figsize=(WIDTH_IN, sum(heights)), layout="constrained")
    subs = fig.subfigures(len(heights), 1, height_ratios=heights)
    lines = [f"streamfix report: {d.name}"] + [f"{k}: {v}" for k, v in _summary_rows(summary, d)]
    subs[0].text(0.01, 0.95, "\n".join(lines), va="top", ha="left", family="monospace", fontsize=9)
    for sub, name in zip(subs[1:], names):
        FIGURES[name][0](sub, d)
    return _png_bytes(fig)


def render_html(d: ReportData, summary: dict) -> str:
    pngs = render_figures(d)
    rows = "".join(f"<tr><th>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>" for k, v in _summary_rows(summary, d))
    blocks = "".join(
        f'<figure><img alt="{name}" src="data:image/png;base64,{base64.b64encode(png).decode()}">'
        f"<figcaption>{html.escape(FIGURES[name][3])}</figcaption></figure>"
        for name, png in pngs.items()
    )
    title = html.escape(f"streamfix report: {d.name}")
    return (
        f"<!doctype html><html lang='en'><head><meta charset='utf-8'><title>{title}</title>"
        "<style>body{font:14px system-ui,sans-serif;max-width:1150px;margin:1em auto;color:#222}"
        "table{border-collapse:collapse}th,td{text-align:left;padding:2px 12px 2px 0}"
        "figure{margin:1.5em 0}img{max-width:100%}figcaption{color:#555}</style></head><body>"
        f"<h1>{title}</h1><table>{rows}</table>{blocks}</body></html>\n"
    )


def write_report(d: ReportData, out: str | Path) -> dict:
    """Write ``out`` (``.html`` with embedded PNGs, or ``.png``); returns the summary numbers."""
    out = Path(out)
    suffix = out.suffix.lower()
    if suffix not in (".html", ".htm", ".png"):
        raise ValueError(f"report {out}: expected a .html or .png file name, got {out.suffix or 'no suffix'!r}")
    summary = summarise(d.raw, d.clean, d.reference)
    if suffix == ".png":
        out.write_bytes(render_png(d, summary))
    else:
        out.write_text(render_html(d, summary), encoding="utf-8")
    return summary


def write_file_reports(files: list[str], out_dir: str | Path, rate_hz: float | None = None) -> list[Path]:
    """One ``<stem>.html`` report per input file in ``out_dir`` (``streamfix eval --report DIR``)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for f in files:
        d = load_report_data(str(f), rate_hz=rate_hz)
        stem = Path(str(f)).name.replace(".npz:", "_").rsplit(".", 1)[0] if ".npz:" in str(f) else Path(f).stem
        path = out_dir / f"{stem}.html"
        write_report(d, path)
        written.append(path)
    return written
