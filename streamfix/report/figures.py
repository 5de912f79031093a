"""The report's figures, each drawn into a matplotlib (sub)figure given by the caller.

The figures the paper argues with, for one offline cleaning: chosen joints' trajectories
before/after (Yang et al. Figs. 6 and 11) with the optical reference when there is one;
every bone's length over time before/after; the jitter spectrum; where joints were
missing, inferred or recovered; and, against a reference, each joint's error
before/after. Uses matplotlib's object API only (no pyplot state), so figures can be
made on any thread and with no display.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.interpolate import interpolate_linear
from ..core.metrics import bone_lengths
from ..motion import Motion
from .summary import joint_reference_errors

__all__ = ["ReportData", "FIGURES", "choose_joints"]

RAW, CLEAN, REF, REC = "#e08a1e", "#1f6fc5", "#222222", "#d62728"


@dataclass
class ReportData:
    """One cleaning to report: input, output, optional reference ``(T, J, 3)`` and joints to plot."""

    name: str
    raw: Motion
    clean: Motion
    reference: np.ndarray | None
    joints: list[int]

    @property
    def time(self) -> np.ndarray:
        return np.asarray(self.raw.timestamps) - float(self.raw.timestamps[0])


def choose_joints(raw: Motion, clean: Motion, reference: np.ndarray | None, n: int = 2) -> list[int]:
    """The ``n`` joints that move most (path length of the cleaned trajectory), no two joined by a bone.

    With a reference, only joints that have one. Skipping a moving joint's bone neighbours
    (a hand next to its wrist, a thumb next to its hand) shows ``n`` different limbs.
    """
    path = np.nansum(np.linalg.norm(np.diff(clean.positions, axis=0), axis=2), axis=0)
    if reference is not None:
        path = np.where(np.isfinite(reference).all(axis=2).any(axis=0), path, -1.0)
    neighbours = {frozenset(b) for b in raw.skeleton.bones}
    picked: list[int] = []
    for j in np.argsort(-path):
        if not any(frozenset((int(j), k)) in neighbours for k in picked):
            picked.append(int(j))
        if len(picked) == n:
            break
    return picked


def _debiased_reference(d: ReportData, j: int) -> np.ndarray:
    """Joint ``j``'s reference shifted by its mean offset to the raw joint (markers sit off-centre)."""
    ref = d.reference[:, j]
    with np.errstate(invalid="ignore"):
        offset = np.nanmean(ref - d.raw.positions[:, j], axis=0)
    return ref - offset


def trajectories(fig, d: ReportData) -> None:
    """Chosen joints, x/y/z (m) over time: raw, cleaned (recovered samples marked), reference."""
    names = d.raw.skeleton.joint_names
    axes = fig.subplots(len(d.joints), 3, squeeze=False, sharex=True)
    t = d.time
    for r, j in enumerate(d.joints):
        rec = d.clean.recovered[:, j] if d.clean.recovered is not None else np.zeros(len(t), bool)
        ref = _debiased_reference(d, j) if d.reference is not None else None
        for c, axis in enumerate("xyz"):
            ax = axes[r, c]
            ax.plot(t, d.raw.positions[:, j, c], color=RAW, lw=1.0, label="raw")
            ax.plot(t, d.clean.positions[:, j, c], color=CLEAN, lw=1.4, label="cleaned")
            if rec.any():
                ax.plot(t[rec], d.clean.positions[rec, j, c], "o", ms=3, color=REC, label="recovered")
            if ref is not None and np.isfinite(ref[:, c]).any():
                ax.plot(t, ref[:, c], "--", color=REF, lw=1.0, label="reference (offset removed)")
            ax.set_title(f"{names[j]} {axis}", fontsize=9)
            ax.set_ylabel(f"{axis} (m)")
            if r == len(d.joints) - 1:
                ax.set_xlabel("time (s)")
    axes[0, 0].legend(fontsize=7, loc="best")
    fig.suptitle("Joint trajectories before and after cleaning")


def bone_length_series(fig, d: ReportData) -> None:
    """Every bone's length minus its median over the take (cm), before and after."""
    bones = d.raw.skeleton.bone_array
    raw_l, clean_l = bone_lengths(d.raw.positions, bones), bone_lengths(d.clean.positions, bones)
    with np.errstate(invalid="ignore"):
        ref_len = np.nanmedian(np.where(np.isfinite(clean_l), clean_l, raw_l), axis=0)
    axes = fig.subplots(1, 2, sharey=True)
    for ax, lengths, title in ((axes[0], raw_l, "before (raw)"), (axes[1], clean_l, "after (cleaned)")):
        dev = 100.0 * (lengths - ref_len)
        ax.plot(d.time, dev, lw=0.8)
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("time (s)")
        ax.axhline(0.0, color="#888888", lw=0.6)
    axes[0].set_ylabel("bone length - median (cm)")
    lim = np.nanpercentile(np.abs(100.0 * (raw_l - ref_len)), 99.5) if np.isfinite(raw_l).any() else 1.0
    axes[0].set_ylim(-1.1 * max(lim, 0.5), 1.1 * max(lim, 0.5))
    fig.suptitle(f"Length of each of the {len(bones)} bones over time")


def _psd(x: np.ndarray, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Mean power spectral density over joints and axes of linearly gap-filled, detrended positions."""
    from scipy.signal import welch

    filled, _ = interpolate_linear(x)
    cols = filled.reshape(filled.shape[0], -1)
    cols = cols[:, np.isfinite(cols).all(axis=0)]
    nper = int(min(128, cols.shape[0]))
    f, p = welch(cols, fs=rate_hz, nperseg=nper, detrend="linear", axis=0)
    return f, p.mean(axis=1)


def jitter_spectrum(fig, d: ReportData) -> None:
    """Power spectral density of joint positions (m^2/Hz, log) raw vs cleaned (vs reference)."""
    ax = fig.subplots()
    rate = d.raw.rate_hz
    for x, color, label in ((d.raw.positions, RAW, "raw"), (d.clean.positions, CLEAN, "cleaned"),
                            (d.reference, REF, "reference")):
        if x is None or not np.isfinite(x).any():
            continue
        f, p = _psd(x, rate)
        ax.semilogy(f, p, color=color, label=label, ls="--" if x is d.reference else "-")
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("PSD (m$^2$/Hz), mean over joints")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    fig.suptitle("Jitter spectrum: motion lives below a few Hz, sensor jitter above")


def recovery_map(fig, d: ReportData) -> None:
    """Per joint and frame: tracked, inferred by the sensor, missing, or recovered by the cleaner."""
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch

    raw = d.raw
    observed = np.isfinite(raw.positions).all(axis=2) & (raw.confidence > 0)
    state = np.where(observed, np.where(raw.confidence < 1, 1, 0), 2)
    if d.clean.recovered is not None:
        state = np.where(d.clean.recovered & observed, 3, state)  # observed but replaced
        state = np.where(d.clean.recovered & ~observed, 4, state)  # missing and filled
    colors = ["#dfe7ef", "#f2c14e", "#555555", "#e377c2", REC]
    labels = ["tracked", "inferred by sensor", "missing (not recovered)", "replaced by cleaner", "missing, recovered"]
    ax = fig.subplots()
    t = d.time
    ax.imshow(state.T, aspect="auto", interpolation="nearest", cmap=ListedColormap(colors), vmin=-0.5, vmax=4.5,
              extent=(t[0], t[-1] if len(t) > 1 else 1.0, raw.n_joints - 0.5, -0.5))
    ax.set_yticks(range(raw.n_joints))
    ax.set_yticklabels(raw.skeleton.joint_names, fontsize=6)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("joint")
    present = sorted(set(np.unique(state).tolist()))
    ax.legend(handles=[Patch(color=colors[k], label=labels[k]) for k in present], fontsize=7,
              loc="upper left", bbox_to_anchor=(1.0, 1.0))
    fig.suptitle("Where joints were missing, inferred and recovered")


def reference_errors(fig, d: ReportData) -> None:
    """Per joint with a reference: mean debiased error (cm) before and after cleaning."""
    raw_e, raw_deb = joint_reference_errors(d.raw.positions, d.reference)
    _, clean_deb = joint_reference_errors(d.clean.positions, d.reference)
    keep = np.flatnonzero(np.isfinite(raw_e))
    ax = fig.subplots()
    x = np.arange(len(keep))
    ax.bar(x - 0.2, 100 * raw_deb[keep], 0.4, color=RAW, label="raw")
    ax.bar(x + 0.2, 100 * clean_deb[keep], 0.4, color=CLEAN, label="cleaned")
    ax.set_xticks(x)
    ax.set_xticklabels([d.raw.skeleton.joint_names[j] for j in keep], rotation=45, ha="right", fontsize=8)
    ax.set_ylabel("mean error, offset removed (cm)")
    ax.set_xlabel("joint")
    ax.legend(fontsize=8)
    fig.suptitle("Error against the optical reference, per joint")


# name -> (draw, height in inches, needs a reference, caption)
FIGURES = {
    "trajectories": (trajectories, None, False, "Chosen joints before (raw) and after cleaning; red dots are recovered samples."),
    "bone_lengths": (bone_length_series, 3.2, False, "Each bone's length minus its median over the take."),
    "jitter_spectrum": (jitter_spectrum, 3.2, False, "Welch power spectral density of the positions, mean over joints and axes."),
    "recovery": (recovery_map, None, False, "Joint state per frame in the input and what the cleaner recovered."),
    "reference_errors": (reference_errors, 3.4, True, "Mean joint error against the optical reference after removing each joint's mean offset."),
}


def figure_height(name: str, d: ReportData) -> float:
    """Height (inches) of figure ``name`` for this report."""
    height = FIGURES[name][1]
    if height is not None:
        return height
    if name == "trajectories":
        return 1.0 + 2.0 * len(d.joints)
    return 1.2 + 0.13 * d.raw.n_joints  # recovery map: one row per joint
