"""Estimate the sensor error model's parameters from real recordings and write them down.

Sources (read from ``../shared/data/`` beside the repository, never copied):

* ``paired/uiprmd/`` -- UI-PRMD, Kinect v1 and Vicon recorded together (see its README):
  the Kinect joints are compared with reference joints built from the Vicon markers,
  in the **Kinect camera frame** (``R.T @ (v - t)``, so z is depth), on the trustworthy
  repetitions (``pos_corr > 0.95``, ``25 <= fs_eff <= 33`` in ``pairs.csv``). Each
  joint's error is debiased by its median over the repetition (marker-versus-joint-centre
  offset). From it: the per-axis noise level (robust std) and lag-1 autocorrelation on
  frames without a gross failure; gross failures (debiased error > 15 cm): the fraction
  of joint-frames, their episodes' rate and length, and the size of the error when it
  sets in (the first frame of an episode: a *jump*); left/right swaps (a left joint
  nearer the right reference than the left one, debiased).
* ``kinect_v2/*.csv`` -- Kinect v2 body tracking with the SDK's tracking state: inferred
  stretches (length in seconds, how fast inferred joints move, the share that stay
  still), single-frame outliers (:func:`streamfix.sim.measure.measure_kinect`) and
  how far bone lengths wander when the child joint is inferred (stretch).

Writes ``streamfix/sim/sensor_errors.json`` (the defaults of
:class:`streamfix.sim.sensor_errors.SensorErrorParams`: the one source of truth) and the
parameter table between the ``BEGIN/END PARAMETERS`` markers of ``docs/SENSOR_ERRORS.md``.

    python3 -m tools.estimate_sensor_errors            # from the repository root
    python3 -m tools.estimate_sensor_errors --check    # exit 1 if the files are stale
"""
from __future__ import annotations

import argparse
import csv
import json
import sys
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
JSON_OUT = ROOT / "streamfix" / "sim" / "sensor_errors.json"
DOC = ROOT / "docs" / "SENSOR_ERRORS.md"
BEGIN, END = "<!-- BEGIN PARAMETERS (tools/estimate_sensor_errors.py) -->", "<!-- END PARAMETERS -->"

GROSS_M = 0.15  # a gross failure: debiased error above 15 cm
VICON_UNIT_M = 1e-4
NOMINAL_HZ = 30.0

# UI-PRMD Kinect v1 joint index -> Vicon Plug-in-Gait marker indices (paired/README.md).
_MARKERS = ("LFHD RFHD LBHD RBHD C7 T10 CLAV STRN RBAK LSHO LUPA LELB LFRM LWRA LWRB LFIN RSHO RUPA RELB "
            "RFRM RWRA RWRB RFIN LASI RASI LPSI RPSI LTHI LKNE LTIB LANK LHEE LTOE RTHI RKNE RTIB RANK RHEE RTOE").split()
_KJ = ("Waist Spine Chest Neck Head HeadTip LCollar LShoulder LElbow LWrist RCollar RShoulder RElbow RWrist "
       "LHip LKnee LAnkle LFoot RHip RKnee RAnkle RFoot").split()
_REF = {
    "HeadTip": "LFHD RFHD LBHD RBHD", "Neck": "C7 CLAV", "LShoulder": "LSHO", "RShoulder": "RSHO",
    "LElbow": "LELB", "RElbow": "RELB", "LWrist": "LWRA LWRB", "RWrist": "RWRA RWRB",
    "Waist": "LASI RASI LPSI RPSI", "LHip": "LASI LPSI", "RHip": "RASI RPSI", "LKnee": "LKNE",
    "RKnee": "RKNE", "LAnkle": "LANK", "RAnkle": "RANK", "LFoot": "LTOE", "RFoot": "RTOE",
}
REF_JOINTS = [_KJ.index(k) for k in _REF]
REF_MARKERS = [[_MARKERS.index(m) for m in v.split()] for v in _REF.values()]
REF_NAMES = list(_REF)
_SIDES = ("Shoulder", "Elbow", "Wrist", "Hip", "Knee", "Ankle", "Foot")
SWAP_PAIRS = [(REF_NAMES.index("L" + s), REF_NAMES.index("R" + s)) for s in _SIDES]
SWAP_LIMBS = {
    "arm": [(REF_NAMES.index("L" + s), REF_NAMES.index("R" + s)) for s in ("Elbow", "Wrist")],
    "leg": [(REF_NAMES.index("L" + s), REF_NAMES.index("R" + s)) for s in ("Knee", "Ankle", "Foot")],
}
# trunk joints: their marker-versus-joint-centre offset hardly changes with pose, so what
# is left after debiasing is the sensor's error (on limbs, pose-dependent offsets dominate)
TRUNK_REFS = [REF_NAMES.index(n) for n in ("HeadTip", "Neck", "LShoulder", "RShoulder", "Waist", "LHip", "RHip")]
UPPER_REFS = [REF_NAMES.index(n) for n in ("HeadTip", "LShoulder", "RShoulder", "LElbow", "RElbow", "LWrist", "RWrist")]
MIN_JUMP_FRAMES = 3  # a gross error that persists; 1-2 frames are spikes
MIN_SWAP_FRAMES = 5  # shorter "swaps" are indistinguishable from noise near the crossing
# Kinect v2: limbs as the error model sees them; a stretch is a long bone > 10 % off its
# median tracked length for at least 3 frames; a freeze candidate an inferred limb for >= 0.5 s
LIMB_JOINTS = {
    "left_arm": [5, 6, 7, 21, 22], "right_arm": [9, 10, 11, 23, 24],
    "left_leg": [13, 14, 15], "right_leg": [17, 18, 19],
}
LONG_BONE_CHILDREN = ("ElbowLeft", "WristLeft", "ElbowRight", "WristRight", "KneeLeft", "AnkleLeft", "KneeRight", "AnkleRight")
STRETCH_MIN = 0.10
MIN_STRETCH_FRAMES = 3
MIN_FREEZE_FRAMES = 15
STILL_M_S = 0.02


def _runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(starts, lengths) of the True runs of a 1-D bool array."""
    from streamfix.sim.measure import _runs as start_stop

    r = np.asarray(start_stop(mask), dtype=np.intp).reshape(-1, 2)
    return r[:, 0], r[:, 1] - r[:, 0]


# ----------------------------------------------------------------------------- UI-PRMD
def _trusted_keys(pairs_csv: Path) -> list[str]:
    with open(pairs_csv, newline="") as fh:
        rows = list(csv.DictReader(fh))
    return [r["key"] for r in rows if float(r["pos_corr"]) > 0.95 and 25.0 <= float(r["fs_eff"]) <= 33.0]


def _uiprmd_pair(z, key: str) -> tuple[np.ndarray, np.ndarray]:
    """(sensor, reference) joints (T, 17, 3) m in the Kinect camera frame, reference NaN where lost."""
    k = np.asarray(z[f"kinect_{key}"], dtype=np.float64)[:, REF_JOINTS]
    v = np.asarray(z[f"vicon_{key}"], dtype=np.float64)
    lost = (v == 0).all(axis=2)
    v = np.where(lost[..., None], np.nan, v * VICON_UNIT_M)
    ref_v = np.stack([v[:, m].mean(axis=1) for m in REF_MARKERS], axis=1)  # (Tv, 17, 3), NaN if a marker is lost
    fs, off = float(z[f"fs_{key}"]), float(z[f"off_{key}"])
    R, t = np.asarray(z[f"R_{key}"], dtype=np.float64), np.asarray(z[f"t_{key}"], dtype=np.float64)
    tv = np.arange(ref_v.shape[0]) / 100.0
    tk = np.arange(k.shape[0]) / fs + off
    flat = ref_v.reshape(len(tv), -1)
    ref = np.full((len(tk), flat.shape[1]), np.nan)
    inside = (tk >= tv[0]) & (tk <= tv[-1])
    for c in range(flat.shape[1]):  # 51 coordinate series, not frames
        ok = np.isfinite(flat[:, c])
        if ok.sum() > 1:
            ref[inside, c] = np.interp(tk[inside], tv[ok], flat[ok, c])
    ref = ref.reshape(len(tk), -1, 3)
    ref_k = (ref - t) @ R  # R.T @ (v - t), row-vector form
    return k, ref_k


def estimate_uiprmd(folder: Path) -> dict:
    """Noise, gross failures, jumps and swaps of Kinect v1 against Vicon (module doc)."""
    z = np.load(folder / "uiprmd_s01-s06.npz")
    keys = _trusted_keys(folder / "pairs.csv")
    trunk_noise: list[np.ndarray] = []
    lag1_num, lag1_den = np.zeros(3), np.zeros(3)
    seconds = 0.0
    jump_onsets = 0
    jump_sizes: list[float] = []
    jump_frames: list[int] = []
    swap_runs = {"arm": [], "leg": []}
    for key in keys:
        k, ref = _uiprmd_pair(z, key)
        ok = np.isfinite(ref).all(axis=2)
        if ok.sum(axis=0).min() < 20:
            continue
        err = k - ref
        bias = np.stack([np.median(err[ok[:, j], j], axis=0) for j in range(err.shape[1])])
        e = np.where(ok[..., None], err - bias, np.nan)
        size = np.linalg.norm(e, axis=2)
        gross = size > GROSS_M
        good = ok & ~gross
        seconds += len(k) / NOMINAL_HZ
        for j in TRUNK_REFS:
            trunk_noise.append(e[good[:, j], j])
        # lag-1 autocorrelation per axis, on consecutive good frames of every joint
        pair_ok = good[1:] & good[:-1]
        with warnings.catch_warnings():  # a joint with no good frame: its column stays NaN
            warnings.simplefilter("ignore", RuntimeWarning)
            centred = e - np.nanmean(np.where(good[..., None], e, np.nan), axis=0)
        a, b = centred[1:][pair_ok], centred[:-1][pair_ok]
        lag1_num += (a * b).sum(axis=0)
        lag1_den += (0.5 * (a * a + b * b)).sum(axis=0)
        for j in UPPER_REFS:  # jumps: gross episodes of the upper body (legs fail as freezes)
            s, n = _runs(gross[:, j])
            keep = n >= MIN_JUMP_FRAMES  # shorter ones are spikes
            jump_onsets += int(keep.sum())
            jump_sizes += size[s[keep], j].tolist()
            jump_frames += n[keep].tolist()
        kd = k - bias
        for limb, pairs in SWAP_LIMBS.items():
            swapped = np.zeros(len(k), bool)
            for li, ri in pairs:
                d_own = np.linalg.norm(kd[:, li] - ref[:, li], axis=1)
                d_mirror = np.linalg.norm(kd[:, li] - ref[:, ri], axis=1)
                swapped |= ok[:, li] & ok[:, ri] & (d_mirror < d_own)
            swap_runs[limb] += _runs(swapped)[1].tolist()
    noise = np.concatenate(trunk_noise)
    sigma = 1.4826 * np.median(np.abs(noise - np.median(noise, axis=0)), axis=0)
    long_swaps = {k: np.asarray([n for n in v if n >= MIN_SWAP_FRAMES]) for k, v in swap_runs.items()}
    all_long = np.concatenate(list(long_swaps.values()))
    jf = np.asarray(jump_frames)
    return {
        "repetitions": len(keys),
        "seconds": seconds,
        "noise_sigma_m": sigma.tolist(),
        "noise_lag1": (lag1_num / lag1_den).tolist(),
        "jump_rate_hz": jump_onsets / (seconds * len(UPPER_REFS)),
        "jump_size_median_m": float(np.median(jump_sizes)),
        "jump_frames_median": float(np.median(jf)),
        "swap_rate_hz": {k: len(v) / (seconds * 1.0) for k, v in long_swaps.items()},
        "swap_frames_median": float(np.median(all_long)),
    }


def _kinect_v2_motions(folder: Path):
    from streamfix.io.kinect_csv import read_kinect_csv

    return [read_kinect_csv(p) for p in sorted(folder.glob("*.csv"))]


def estimate_kinect_v2(folder: Path) -> dict:
    """Inferred stretches, their motion, spikes and bone stretch of Kinect v2 CSVs (module doc)."""
    from streamfix.motion import CONFIDENCE_INFERRED, CONFIDENCE_TRACKED
    from streamfix.sim.measure import measure_kinect
    from streamfix.skeletons import KINECT_V2

    motions = _kinect_v2_motions(folder)
    m = measure_kinect(motions)
    bones = KINECT_V2.bone_array
    long_bones = [k for k, (p, c) in enumerate(KINECT_V2.bones) if KINECT_V2.joint_names[c] in LONG_BONE_CHILDREN]
    seconds = 0.0
    inferred_runs: list[int] = []
    speeds_inf: list[np.ndarray] = []
    stretch_runs: list[int] = []
    stretch_peaks: list[float] = []
    n_missing = n_total = 0
    for mo in motions:
        c, X = mo.confidence, mo.positions
        seconds += mo.n_frames / mo.rate_hz
        n_missing += int((c == 0).sum())
        n_total += c.size
        inf = np.isclose(c, CONFIDENCE_INFERRED)
        trk = np.isclose(c, CONFIDENCE_TRACKED)
        for limb in LIMB_JOINTS.values():  # a limb is inferred where any of its joints is
            s, n = _runs(inf[:, limb].any(axis=1))
            inferred_runs += n.tolist()
        both = inf[1:] & inf[:-1]
        v = np.linalg.norm(np.diff(X, axis=0), axis=2) * mo.rate_hz
        speeds_inf.append(v[both])
        L = np.linalg.norm(X[:, bones[:, 0]] - X[:, bones[:, 1]], axis=2)
        tracked_len = np.where(trk[:, bones[:, 0]] & trk[:, bones[:, 1]], L, np.nan)
        with np.errstate(invalid="ignore"):
            rel = L / np.nanmedian(tracked_len, axis=0) - 1.0
        for k in long_bones:
            if not np.isfinite(rel[:, k]).any():
                continue
            s, n = _runs(np.nan_to_num(rel[:, k]) > STRETCH_MIN)
            keep = n >= MIN_STRETCH_FRAMES
            stretch_runs += n[keep].tolist()
            stretch_peaks += [float(np.max(rel[a:a + b, k])) for a, b in zip(s[keep], n[keep])]
    runs = np.asarray(inferred_runs)
    long_runs = runs[runs >= MIN_FREEZE_FRAMES]
    v = np.concatenate(speeds_inf)
    return {
        "recordings": len(motions),
        "seconds": seconds,
        "missing_fraction": n_missing / max(n_total, 1),
        "inferred_stretches_ge_0_5s": int(long_runs.size),
        "inferred_stretch_s_median": float(np.median(long_runs) / NOMINAL_HZ) if long_runs.size else float("nan"),
        "freeze_rate_hz": long_runs.size / (seconds * len(LIMB_JOINTS)),
        "inferred_speed_median_m_s": float(np.median(v)),
        "inferred_still_fraction": float((v < STILL_M_S).mean()),
        "spike_rate": float(m["spike_rate_total"]),
        "spike_size_median_m": float(m["spike_median_m"]),
        "inferred_bone_dev_m": float(m["inferred_bone_dev"]),
        "stretch_rate_hz": len(stretch_runs) / (seconds * len(LIMB_JOINTS)),
        "stretch_frames_median": float(np.median(stretch_runs)) if stretch_runs else float("nan"),
        "stretch_peak_median": float(np.median(stretch_peaks)) if stretch_peaks else float("nan"),
    }


def _range(lo: float, median: float, hi: float | None = None) -> list[float]:
    """[lo, 2 median - lo] (a uniform draw with that median), capped at ``hi``."""
    top = max(2.0 * median - lo, lo)
    return [round(float(lo), 3), round(float(min(top, hi) if hi is not None else top), 3)]


def derive(est: dict) -> list[dict]:
    """The model's parameters from the estimates: rows of (name, value, unit, source)."""
    u, k = est["uiprmd"], est["kinect_v2"]
    U = f"UI-PRMD Kinect v1 vs Vicon, {u['repetitions']} trusted repetitions ({u['seconds'] / 60:.0f} min)"
    K = f"Kinect v2 CSVs ({k['recordings']} recordings, {k['seconds']:.0f} s)"
    r = lambda x, n=4: round(float(x), n)  # noqa: E731
    return [
        {"name": "noise_sigma_m", "value": [r(v) for v in u["noise_sigma_m"]], "unit": "m (x, y, z camera; z = depth)",
         "source": f"{U}: robust std of the debiased error of trunk joints (head, neck, shoulders, pelvis, hips), per axis"},
        {"name": "noise_rho", "value": r(np.mean(u["noise_lag1"]), 3), "unit": "per frame at 30 Hz",
         "source": f"{U}: lag-1 autocorrelation of the debiased error (all joints, no gross failure), mean of x {u['noise_lag1'][0]:.3f}, y {u['noise_lag1'][1]:.3f}, z {u['noise_lag1'][2]:.3f}"},
        {"name": "swap_rate_arm_hz", "value": r(u["swap_rate_hz"]["arm"], 4), "unit": "1/s per left/right arm pair",
         "source": f"{U}: runs of >= {MIN_SWAP_FRAMES} frames with a left elbow/wrist nearer the right reference than its own"},
        {"name": "swap_rate_leg_hz", "value": r(u["swap_rate_hz"]["leg"], 4), "unit": "1/s per left/right leg pair",
         "source": f"{U}: the same for knee/ankle/foot"},
        {"name": "swap_frames", "value": _range(MIN_SWAP_FRAMES, u["swap_frames_median"]), "unit": "frames (uniform)",
         "source": f"{U}: median swap run {u['swap_frames_median']:.0f} frames"},
        {"name": "freeze_rate_hz", "value": r(k["freeze_rate_hz"], 4), "unit": "1/s per limb",
         "source": f"{K}: {k['inferred_stretches_ge_0_5s']} stretches of >= 0.5 s with an inferred joint in a limb"},
        {"name": "freeze_s", "value": _range(0.5, k["inferred_stretch_s_median"], 3.0), "unit": "s (uniform)",
         "source": f"{K}: median inferred stretch {k['inferred_stretch_s_median']:.1f} s; capped at 3 s (issue 8)"},
        {"name": "freeze_still_fraction", "value": r(k["inferred_still_fraction"], 3), "unit": "fraction of stretches",
         "source": f"{K}: share of inferred joint-frames moving < {STILL_M_S * 100:.0f} cm/s (the rest drift)"},
        {"name": "drift_speed_m_s", "value": r(k["inferred_speed_median_m_s"], 3), "unit": "m/s",
         "source": f"{K}: median speed of inferred joints"},
        {"name": "freeze_missing_fraction", "value": r(k["missing_fraction"], 4), "unit": "fraction of stretches",
         "source": f"{K}: share of NotTracked joint-frames (the rest of a failing limb is flagged inferred)"},
        {"name": "spike_rate", "value": r(k["spike_rate"], 5), "unit": "per joint-frame",
         "source": f"{K}: tracked samples > 3 cm off both neighbours' mean and farther than they are apart (streamfix.sim.measure)"},
        {"name": "spike_size_m", "value": r(k["spike_size_median_m"], 4), "unit": "m (median; 3 cm + exponential)",
         "source": f"{K}: median size of those spikes"},
        {"name": "stretch_rate_hz", "value": r(k["stretch_rate_hz"], 4), "unit": "1/s per limb",
         "source": f"{K}: runs of >= {MIN_STRETCH_FRAMES} frames with a long limb bone > {STRETCH_MIN:.0%} longer than its median tracked length"},
        {"name": "stretch_frames", "value": _range(MIN_STRETCH_FRAMES, k["stretch_frames_median"]), "unit": "frames (uniform)",
         "source": f"{K}: median stretch run {k['stretch_frames_median']:.0f} frames"},
        {"name": "stretch_fraction", "value": _range(STRETCH_MIN, k["stretch_peak_median"]), "unit": "of the bone's length (uniform)",
         "source": f"{K}: median peak lengthening {k['stretch_peak_median']:.2f} (inferred-child bones sit {k['inferred_bone_dev_m'] * 100:.1f} cm off, median)"},
        {"name": "jump_rate_hz", "value": r(u["jump_rate_hz"], 4), "unit": "1/s per joint",
         "source": f"{U}: onsets of gross failures (debiased error > {GROSS_M * 100:.0f} cm for >= {MIN_JUMP_FRAMES} frames) of upper-body joints"},
        {"name": "jump_size_m", "value": r(u["jump_size_median_m"], 3), "unit": "m",
         "source": f"{U}: median error at the onset of those failures"},
        {"name": "jump_frames", "value": _range(MIN_JUMP_FRAMES, u["jump_frames_median"]), "unit": "frames (uniform)",
         "source": f"{U}: median failure length {u['jump_frames_median']:.0f} frames"},
    ]


def _fmt(v) -> str:
    return ", ".join(f"{x:g}" for x in v) if isinstance(v, list) else f"{v:g}"


def doc_table(rows: list[dict]) -> str:
    lines = ["| parameter | value | unit | source |", "| --- | --- | --- | --- |"]
    lines += [f"| `{r['name']}` | {_fmt(r['value'])} | {r['unit']} | {r['source']} |" for r in rows]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", type=Path, default=DATA, help="the shared data folder (default: ../shared/data)")
    p.add_argument("--check", action="store_true", help="exit 1 if the JSON or the doc table is stale; write nothing")
    args = p.parse_args(argv)
    for sub in ("paired/uiprmd", "kinect_v2"):
        if not (args.data / sub).is_dir():
            print(f"estimate_sensor_errors: {args.data / sub} not found (expected the shared recordings)", file=sys.stderr)
            return 1
    est = {"uiprmd": estimate_uiprmd(args.data / "paired" / "uiprmd"),
           "kinect_v2": estimate_kinect_v2(args.data / "kinect_v2")}
    rows = derive(est)
    payload = json.dumps({"parameters": {r["name"]: r["value"] for r in rows}, "rows": rows, "estimates": est},
                         indent=1) + "\n"
    doc = DOC.read_text()
    if BEGIN not in doc or END not in doc:
        print(f"estimate_sensor_errors: {DOC} lacks the markers {BEGIN} ... {END}", file=sys.stderr)
        return 1
    head, rest = doc.split(BEGIN, 1)
    new_doc = head + BEGIN + "\n" + doc_table(rows) + "\n" + END + rest.split(END, 1)[1]
    if args.check:
        stale = [str(f) for f, new in ((JSON_OUT, payload), (DOC, new_doc)) if not f.exists() or f.read_text() != new]
        if stale:
            print(f"estimate_sensor_errors: stale: {', '.join(stale)}", file=sys.stderr)
            return 1
        return 0
    JSON_OUT.write_text(payload)
    DOC.write_text(new_doc)
    print(doc_table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
