#!/usr/bin/env python3
"""Make ``replay_data/``: synthetic Kinect v2 sessions with a sensor model measured on real data.

    python tools/make_replay_data.py [--data ../shared/data/kinect_v2] [--out replay_data]

1. Measures the Kinect v2 recordings in ``--data`` (jitter level and colour per joint,
   inferred-joint fraction / run length / offset, dropped frames, timestamp jitter,
   outliers; see ``streamfix.sim.measure``) -- per profile (standing: Ges*.csv, seated:
   seated_joints.csv) and pooled -- and prints them.
2. Builds a ``SensorModel`` per profile from those measurements.
3. Generates each session's clean motion procedurally (``streamfix.sim.body``: a
   25-joint body with the measured median bone lengths, placed at the profile's median
   SpineBase), passes it through the sensor model with a fixed seed and writes it as a
   Kinect v2 CSV, plus ``sessions.json`` (everything needed to regenerate the clean
   ground truth without the real data) and ``README.md``.

Nothing from the real recordings is copied: only the summary statistics above are used.
Deterministic: the same data and seeds give byte-identical files.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from streamfix.io.kinect_csv import read_kinect_csv, write_kinect_csv  # noqa: E402
from streamfix.sim.body import generate_clean  # noqa: E402
from streamfix.sim.measure import measure_kinect  # noqa: E402
from streamfix.sim.sensor import SensorModel  # noqa: E402
from streamfix.skeletons import KINECT_V2  # noqa: E402

# name, activity, profile, duration (s), seed, what
SESSIONS = [
    ("standing_gestures", "standing", "standing", 30.0, 11,
     "standing ~2.7 m from the sensor: idle sway, waving the right hand, reaching forward with the left, "
     "drawing lines with both hands, beckoning, a side step"),
    ("seated_desk", "seated", "seated", 30.0, 12,
     "seated close to the sensor (~1.3 m): pointing, waving, explaining with both hands, foot tapping; "
     "legs mostly inferred as in the real seated recording"),
    ("stepping_turning", "stepping", "standing", 20.0, 13,
     "stepping in place with arm swing while turning +-25 deg and moving 0.35 m towards/away from the sensor"),
]
DECIMALS = 4  # 0.1 mm


def _fmt_mm(a) -> str:
    return " / ".join(f"{1000 * v:.2f}" for v in np.atleast_1d(a))


def print_measurements(name: str, s: dict) -> None:
    print(f"== {name}: {s['n_recordings']} recording(s), {s['n_frames']} frames, {s['rate_hz']:.3f} Hz")
    print(f"  dropped frames {100 * s['drop_rate']:.2f} % (mean gap {s['drop_mean_length']:.1f} frames), "
          f"timestamp step jitter {1e3 * s['dt_jitter_s']:.3f} ms")
    print(f"  jitter colour: power 8-11.5 Hz / 11.5-15 Hz = {s['hf_band_ratio']:.3f}")
    print(f"  outliers: {100 * s['spike_rate_total']:.2f} % of tracked joint-frames, median jump {1000 * s['spike_median_m']:.1f} mm")
    print(f"  inferred joints sit off: median |bone error| {1000 * s['inferred_bone_dev']:.1f} mm "
          f"(tracked {1000 * s['tracked_bone_dev']:.1f} mm, n={s['inferred_bone_dev_n']})")
    print(f"  {'joint':14s} {'HF sigma x/y/z mm':>22s} {'inferred %':>10s} {'run (fr)':>8s} {'spike %':>8s}")
    for j, n in enumerate(KINECT_V2.joint_names):
        print(f"  {n:14s} {_fmt_mm(s['hf_sigma'][j]):>22s} {100 * s['inferred_fraction'][j]:10.1f} "
              f"{s['inferred_run_mean'][j]:8.1f} {100 * s['spike_rate'][j]:8.2f}")


def readme(models: dict, stats: dict, manifest: list[dict]) -> str:
    pooled, stand, seat = stats["pooled"], stats["standing"], stats["seated"]
    lines = [
        "# replay_data: synthetic Kinect v2 sessions made by streamfix",
        "",
        "These recordings were **produced by the project itself** with `tools/make_replay_data.py`; no",
        "sample of `../shared/data` is in them. Each is a procedurally generated motion",
        "(`streamfix.sim.body`) passed through a Kinect v2 sensor model (`streamfix.sim.sensor`) whose",
        "parameters were measured on the real Kinect v2 recordings in `../shared/data/kinect_v2`",
        "(`streamfix.sim.measure`). Format: Kinect v2 CSV (`timestamp` in 100 ns ticks, then 25 x",
        "`x,y,z,trackingState`), one body, coordinates to 0.1 mm.",
        "",
        "Play one through the service (see the main README):",
        "",
        "    streamfix serve --source replay:replay_data/standing_gestures.csv --out tcp://127.0.0.1:5556",
        "",
        "Regenerate (byte-identical):",
        "",
        "    python tools/make_replay_data.py",
        "",
        "## Sessions",
        "",
        "| file | frames | seconds | profile | seed | what |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for s in manifest:
        lines.append(f"| {s['file']} | {s['frames']} | {s['duration_s']:.0f} | {s['profile']} | {s['seed']} | {s['what']} |")
    lines += [
        "",
        "`sessions.json` lists, per session, the activity, seed, subject scale, bone lengths and",
        "placement, so `streamfix.sim.body.generate_clean(...)` regenerates the clean ground truth",
        "(before the sensor model) without the real data; `SensorModel(**params)` the sensor.",
        "",
        "## How a session is made",
        "",
        "1. **Motion**: a 25-joint body with the median tracked bone lengths of the standing recordings",
        "   (left/right averaged, scaled by a per-session factor in [0.95, 1.05]), posed by forward",
        "   kinematics from smooth joint-angle trajectories (minimum-jerk transitions and slow",
        "   sinusoids), placed in camera space at the profile's median SpineBase, facing the sensor.",
        "2. **Tracking state**: per joint a two-state Markov chain (tracked <-> inferred) with the",
        "   measured inferred fraction and mean inferred run length of the profile.",
        "3. **Jitter**: AR(1) Gaussian noise per joint and axis. The level is matched in the 8 Hz-Nyquist",
        "   band (robust sigma of the zero-phase 4th-order Butterworth high-passed positions on tracked",
        "   runs, where human motion has little power); the AR coefficient is fitted to the measured",
        "   spectral colour (band-power ratio) and capped at 0.6, because above it the data cannot",
        "   distinguish values while the implied low-frequency noise keeps growing.",
        "4. **Inferred joints** sit off their true place by an Ornstein-Uhlenbeck bias (time constant",
        "   1 s) sized so that the median |bone-length error| of bones with an inferred child matches",
        "   the measurement, with the inferred jitter level where one was measured.",
        "5. **Outliers**: go-and-return jumps of 3 cm + Exp(mean) in a random direction, the mean matching",
        "   the measured median jump, at the measured per-joint rate (the profile's where it has 200+",
        "   tracked frames of the joint, else pooled) minus the rate at which the jitter alone already",
        "   passes the outlier test, so that measuring the output gives the measured rate back.",
        "6. **Dropped frames** with the measured rate (real gaps are single frames) and timestamp jitter.",
        "",
        "## Measured parameters",
        "",
        f"Pooled over all five recordings ({pooled['n_frames']} frames at {pooled['rate_hz']:.3f} Hz):",
        "",
        f"- frame rate {pooled['rate_hz']:.3f} Hz (median step {1e3 / pooled['rate_hz']:.2f} ms); timestamp step jitter "
        f"{1e3 * pooled['dt_jitter_s']:.3f} ms (std)",
        f"- dropped frames {100 * pooled['drop_rate']:.2f} % of sensor frames, mean gap {pooled['drop_mean_length']:.1f} frames",
        f"- outliers {100 * pooled['spike_rate_total']:.2f} % of tracked joint-frames (mostly thumbs, hand tips, feet), "
        f"median jump {1000 * pooled['spike_median_m']:.1f} mm",
        f"- jitter colour: high-passed power 8-11.5 Hz / 11.5-15 Hz = {pooled['hf_band_ratio']:.3f} "
        f"-> AR(1) coefficient {models['standing'].noise_rho:.2f}",
        f"- inferred joints: median |bone-length error| {1000 * stand['inferred_bone_dev']:.1f} mm standing, "
        f"{1000 * seat['inferred_bone_dev']:.1f} mm seated (tracked bones: {1000 * pooled['tracked_bone_dev']:.1f} mm)",
        "",
        "Per joint (standing profile = Ges01-04, seated = seated_joints): high-frequency jitter sigma",
        "(mm, x / y / z), inferred fraction (%) and mean inferred run (frames), outlier rate (% pooled).",
        "",
        "| joint | HF sigma standing | HF sigma seated | inferred % standing | run | inferred % seated | run | outliers % |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for j, n in enumerate(KINECT_V2.joint_names):
        seat_hf = _fmt_mm(seat["hf_sigma"][j]) if seat["hf_samples"][j] >= 100 else "(not tracked)"
        lines.append(
            f"| {n} | {_fmt_mm(stand['hf_sigma'][j])} | {seat_hf} | {100 * stand['inferred_fraction'][j]:.1f} | "
            f"{stand['inferred_run_mean'][j]:.1f} | {100 * seat['inferred_fraction'][j]:.1f} | {seat['inferred_run_mean'][j]:.1f} | "
            f"{100 * pooled['spike_rate'][j]:.2f} |"
        )
    lines += [
        "",
        "Bone lengths (m, median over tracked frames of the standing recordings):",
        "",
        ", ".join(f"{KINECT_V2.joint_names[p]}-{KINECT_V2.joint_names[c]} {L:.3f}" for (p, c), L in
                  zip(KINECT_V2.bones, stand["bone_length"])),
        "",
        "Limits: inferred states are drawn per joint (real occlusion tends to take a whole limb at",
        "once); noise below 8 Hz is an extrapolation of the fitted AR(1) spectrum (motion hides it in",
        "the real data); the generator's activities are smooth and free of the sensor's own",
        "skeleton-fitting errors (e.g. left/right swaps), which the model does not produce.",
        "",
    ]
    return "\n".join(lines)


def _jsonable(v):
    if isinstance(v, np.ndarray):
        return [_jsonable(x) for x in v.tolist()] if v.ndim else v.item()
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if isinstance(v, float):
        return round(v, 9)
    if isinstance(v, dict):
        return {k: _jsonable(x) for k, x in v.items()}
    if isinstance(v, (np.floating, np.integer)):
        return _jsonable(v.item())
    return v


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=ROOT / ".." / "shared" / "data" / "kinect_v2")
    ap.add_argument("--out", type=Path, default=ROOT / "replay_data")
    args = ap.parse_args(argv)
    files = sorted(args.data.glob("*.csv"))
    if not files:
        print(f"no Kinect v2 CSV files in {args.data}", file=sys.stderr)
        return 1
    recs = {f.name: read_kinect_csv(f) for f in files}
    stats = {
        "pooled": measure_kinect(list(recs.values())),
        "standing": measure_kinect([m for n, m in recs.items() if not n.startswith("seated")]),
        "seated": measure_kinect([m for n, m in recs.items() if n.startswith("seated")]),
    }
    for name, s in stats.items():
        print_measurements(name, s)
    models = {p: SensorModel.from_measurements(stats[p], stats["pooled"]) for p in ("standing", "seated")}
    for p, m in models.items():
        print(f"sensor model {p}: AR(1) rho {m.noise_rho:.2f}, noise sigma median {1000 * np.median(m.noise_sigma):.2f} mm, "
              f"inferred bias sigma {1000 * m.inferred_bias_sigma:.1f} mm, drop {100 * m.drop_rate:.2f} %")
    args.out.mkdir(parents=True, exist_ok=True)
    manifest = []
    for name, activity, profile, duration, seed, what in SESSIONS:
        model = models[profile]
        clean = generate_clean(activity, duration, model.rate_hz, stats["standing"]["bone_length"],
                               stats[profile]["spine_base"], seed=seed)
        obs = model.apply(clean, seed=seed + 1000)
        obs.timestamps[:] = obs.timestamps + 1000.0  # a sensor clock that does not start at zero
        path = args.out / f"{name}.csv"
        write_kinect_csv(obs, path, decimals=DECIMALS)
        manifest.append({
            "file": path.name, "activity": activity, "profile": profile, "duration_s": duration, "seed": seed,
            "sensor_seed": seed + 1000, "clock_offset_s": 1000.0, "frames": obs.n_frames,
            "dropped_frames": obs.meta["dropped_frames"], "subject_scale": clean.meta["subject_scale"],
            "bone_length": stats["standing"]["bone_length"], "placement": stats[profile]["spine_base"],
            "inferred_fraction": float((obs.confidence == 0.5).mean()), "what": what,
            "sensor_model": model.to_dict(),
        })
        print(f"wrote {path} ({obs.n_frames} frames, {path.stat().st_size / 1024:.0f} KiB, "
              f"{obs.meta['dropped_frames']} dropped, {100 * (obs.confidence == 0.5).mean():.1f} % inferred)")
    (args.out / "sessions.json").write_text(json.dumps(_jsonable(manifest), indent=1) + "\n")
    (args.out / "README.md").write_text(readme(models, stats, manifest))
    return 0


if __name__ == "__main__":
    sys.exit(main())
