"""Paired protocol: clean a real sensor's skeleton and score it against optical motion capture.

``streamfix eval --protocol paired [DIR]`` loads the paired recordings
(:mod:`streamfix.io.paired`: UI-PRMD Kinect v1 + Vicon, KERAAL Kinect v2 + Vicon; default
``../shared/data/paired``), runs every method on each take's sensor skeleton (the
sensor's own rate and skeleton; nothing of the reference is given to a method) and
scores the output against the reference, per dataset and per body region (``all``,
``upper``, ``lower``: :func:`body_region`). One record per (dataset, method, region)::

    {file, rate_hz, protocol: "paired", level: 0, method, dataset, region, subset,
     n_takes, n_frames, n_joints,
     aje_m = mean_error_m,        # mean |output - reference| (m), joints with a reference
     coverage,                    # fraction of reference joint-frames the output has a value for
                                  #   (errors are over these: a method leaving NaN scores fewer)
     debiased_mean_m,             # the same after removing each joint's mean offset over the
     debiased_p95_m,              #   take (per method): marker-vs-joint-centre bias is not the
                                  #   cleaner's to fix; p95 over all joint-frames
     debiased_slow_m,             # mean of the debiased error's part below 3 Hz
                                  #   (reference_metrics.slow_error_norm): on ``input``, the
                                  #   floor a temporal filter cannot go below
     jitter, jitter_reference,    # mean |second difference| (m/frame^2) on the same joint-frames
     jitter_ratio,                # output / reference
     bone_cv,                     # bone-length CV of the output (bones ending in the region)
     lag_frames,                  # argmax of the velocity cross-correlation against the
     lag_frames_median,           #   reference, pooled over takes / median of per-take argmax
     seam_ratio,                  # mean |second difference| on frames next to an engine window
                                  #   hand-over / on the other frames within a hop of them
                                  #   (every method: ~1 = no seam; None when no take had one)
     seam_frames,                 # joint-frames next to a hand-over behind seam_ratio
     move_m,                      # mean |output - input| (m) on the sensor's tracked joint-frames
                                  #   (the real-Kinect bar's "tracked joints moved", here with the truth)
     move_bar_scale,              # engine methods, when median_savgol ran too (else None): the factor
                                  #   each take's move is scaled by to meet TRACKED_MOVE_BAR x
                                  #   median_savgol's move (frame-weighted mean over takes), and
     debiased_at_move_bar_m,      #   the debiased mean error of that scaled output: what meeting
                                  #   that bar by moving less costs
     abe_m: None, time_s}

Aggregation over takes: means are frame-weighted (pooled over joint-frames), p95 is over
all joint-frames, bone CV is the frame-weighted mean of each take's CV.

Lag: per take, the ``FAST_JOINTS`` joints of the region whose reference moves fastest;
:func:`streamfix.core.reference_metrics.velocity_xcorr` over +-``MAX_LAG_FRAMES``.

Seam: the two frames around each window hand-over, where the engine's blend passes a
frame to the newer window (:func:`streamfix.evaluation.registry.handover_frames`), on the
schedule the method ran at the take's rate (the file schedule for ``streamfix``, ``serve``'s
for every other method), each against the same joint's other frames within one hop
(:func:`streamfix.core.metrics.seam_sums`: a body's first window has more hand-overs).

Move against the truth: issue 8 bars the engine's output on real Kinect files (no truth there)
from moving tracked joints more than :data:`~streamfix.evaluation.kinect.TRACKED_MOVE_BAR` x what
median+Savitzky-Golay moves them. Here the same move is measured where the truth is known, and
the engine's output is also scored with each take's move scaled down to that bar
(``output' = input + a (output - input)`` on tracked joint-frames, one ``a`` per take, as the bar
is per file): if the truth prefers the full move, that bar asks for a less accurate output.

Methods come from :mod:`streamfix.evaluation.registry`; names it does not know are
skipped with a warning (:data:`DEFAULT_METHODS` names the baselines users pick).

Held-out people: the engine methods remove a learned pose-dependent sensor bias
(:mod:`streamfix.sensor_bias`) whose shipped model was fitted on paired recordings of
some people. A take of one of those people is scored with a model fitted on every other
person's trustworthy takes of the same source instead (:func:`held_out_bias_models`), so no
take is scored by a model that saw its person; takes of anyone else get the engine's
default (``auto``: the model shipped for the skeleton, if any). The records say which
(``sensor_bias``). ``by_person=True`` adds the same records pooled per person (``person``).
"""
from __future__ import annotations

import functools
import inspect
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from ..core import metrics
from ..core.reference_metrics import remove_mean_offset, second_difference_norm, slow_error_norm, velocity_xcorr
from ..io.paired import PairedTake, TakeRef, default_paired_dir, find_takes, load_take
from . import registry
from .kinect import TRACKED_MOVE_BAR
from .registry import handover_frames

__all__ = ["run_paired", "score_take", "move_scaled_to", "held_out_bias_models", "person_of", "region_masks", "aggregate", "body_region", "handover_frames", "print_paired_table",
           "DEFAULT_METHODS", "REGIONS", "PROTOCOLS"]

DEFAULT_METHODS = ("input", "median_savgol", "savgol", "one_euro", "one_euro_tuned", "holt", "butterworth", "streamfix",
                   "streamfix_serve", "streamfix_live")
REGIONS = ("all", "upper", "lower")
MAX_LAG_FRAMES = 10
FAST_JOINTS = 3
_LOWER_WORDS = ("hip", "knee", "ankle", "foot", "toe", "heel", "waist", "pelvis", "spinebase")


def body_region(joint_name: str) -> str:
    """``'lower'`` for the pelvis and legs (hip, knee, ankle, foot, waist, ...), else ``'upper'``."""
    name = joint_name.lower()
    return "lower" if any(w in name for w in _LOWER_WORDS) else "upper"


def _run_method(name: str, take: PairedTake, sensor_bias=None) -> np.ndarray:
    """``registry.run_method`` on the take's sensor skeleton (passing ``skeleton=`` where accepted;
    ``sensor_bias`` to the engine methods, None = their default)."""
    m = take.sensor
    kwargs = {"skeleton": m.skeleton} if _takes_skeleton() else {}
    if sensor_bias is not None and name in registry.ENGINE_SCHEDULES:
        kwargs["sensor_bias"] = sensor_bias
    return registry.run_method(name, m.positions, m.confidence, m.skeleton.bone_array, m.rate_hz, **kwargs)


@functools.lru_cache(maxsize=1)
def _takes_skeleton() -> bool:
    return "skeleton" in inspect.signature(registry.run_method).parameters


def region_masks(joint_names) -> dict[str, np.ndarray]:
    """``{region: (J,) bool}`` for :data:`REGIONS` (:func:`body_region` of each joint name)."""
    lower = np.array([body_region(n) == "lower" for n in joint_names])
    everything = np.ones(len(lower), dtype=bool)
    return {"all": everything, "upper": ~lower, "lower": lower}


def score_take(take: PairedTake, methods: list[str], sensor_bias=None) -> dict:
    """Partial sums of every measure for one take: ``{(method, region): {...}}`` (see :func:`aggregate`);
    ``sensor_bias``: the engine methods' pose-bias model (None = their default)."""
    ref = take.reference
    T = ref.shape[0]
    has_ref = np.isfinite(ref).all(axis=2)  # (T, J)
    d2_ref = second_difference_norm(ref)
    bones = take.sensor.skeleton.bone_array
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # joints without a reference: NaN speed
        speed = np.nanmean(np.linalg.norm(np.diff(ref, axis=0), axis=2), axis=0)
    regions = region_masks(take.sensor.skeleton.joint_names)
    x = take.sensor.positions
    tracked = take.sensor.observed & (take.sensor.confidence >= 1.0)
    out: dict = {}
    outputs: dict[str, np.ndarray] = {}  # the ones the move-bar scoring reads (_score_at_move_bar)
    for name in methods:
        t0 = time.perf_counter()
        y = _run_method(name, take, sensor_bias)
        dt = time.perf_counter() - t0
        if name == "median_savgol" or name in registry.ENGINE_SCHEDULES:
            outputs[name] = y
        err = np.linalg.norm(y - ref, axis=2)
        deb = np.linalg.norm(remove_mean_offset(y, ref) - ref, axis=2)
        slow = slow_error_norm(y, ref, take.sensor.rate_hz)
        d2 = second_difference_norm(y)
        schedule = registry.engine_config(name, take.sensor.rate_hz)
        seam = schedule.handover_frames(T)
        move = np.linalg.norm(y - x, axis=2)
        for region, joints in regions.items():
            jm = joints[None, :]
            m_ok = tracked & jm & np.isfinite(move)
            e_ok = has_ref & jm & np.isfinite(err)
            j_ok = np.isfinite(d2_ref) & np.isfinite(d2) & jm
            region_bones = bones[joints[bones[:, 1]]]
            cv = metrics.bone_length_cv(y, region_bones) if len(region_bones) else float("nan")
            ref_joints = np.flatnonzero(joints & take.referenced)
            fast = ref_joints[np.argsort(-np.nan_to_num(speed[ref_joints]))[:FAST_JOINTS]]
            lags, xc = velocity_xcorr(y[:, fast], ref[:, fast], MAX_LAG_FRAMES)
            seam_sum, seam_n, other_sum, other_n = metrics.seam_sums(np.where(jm, d2, np.nan), seam, schedule.hop)
            out[(name, region)] = {
                "frames": T,
                "err_sum": float(err[e_ok].sum()), "err_n": int(e_ok.sum()), "ref_n": int((has_ref & jm).sum()),
                "deb": deb[e_ok & np.isfinite(deb)].astype(np.float32),
                "slow_sum": float(np.nansum(slow[e_ok])), "slow_n": int((e_ok & np.isfinite(slow)).sum()),
                "jit_sum": float(d2[j_ok].sum()), "jit_ref_sum": float(d2_ref[j_ok].sum()), "jit_n": int(j_ok.sum()),
                "cv": cv,
                "xcorr": xc, "lag": int(lags[np.nanargmax(xc)]) if np.isfinite(xc).any() else None,
                "seam_sum": seam_sum, "seam_n": seam_n, "other_sum": other_sum, "other_n": other_n,
                "move_sum": float(move[m_ok].sum()), "move_n": int(m_ok.sum()),
                "time_s": dt,
                "rate_hz": take.sensor.rate_hz,
                "n_joints": int((joints & take.referenced).sum()),
            }
    if "median_savgol" in outputs:
        _score_at_move_bar(out, outputs, x, tracked, ref, has_ref, regions)
    return out


def move_scaled_to(y: np.ndarray, x: np.ndarray, tracked: np.ndarray, move_m: float) -> tuple[np.ndarray, float]:
    """``(output, a)``: ``y`` with its move on the ``tracked`` joint-frames scaled by one factor
    ``a`` <= 1 so that its mean move (:func:`streamfix.core.metrics.mean_move`) is at most ``move_m`` metres
    (``a = 1``, ``y`` unchanged, when it already is). Other joint-frames keep ``y``'s values."""
    now = metrics.mean_move(y, x, tracked)
    a = min(1.0, move_m / now) if now > 0 else 1.0
    if a >= 1.0:
        return y, 1.0
    return np.where(tracked[..., None], x + a * (y - x), y), a


def _score_at_move_bar(out: dict, outputs: dict[str, np.ndarray], x: np.ndarray, tracked: np.ndarray,
                       ref: np.ndarray, has_ref: np.ndarray, regions: dict[str, np.ndarray]) -> None:
    """Add ``deb_bar`` (debiased errors) and ``bar_scale`` to the engine methods' partials of
    :func:`score_take`: their output with the take's move scaled to TRACKED_MOVE_BAR x median_savgol's."""
    allowed = TRACKED_MOVE_BAR * metrics.mean_move(outputs["median_savgol"], x, tracked)
    if not np.isfinite(allowed):
        return
    for name, y in outputs.items():
        if name not in registry.ENGINE_SCHEDULES:
            continue
        capped, a = move_scaled_to(y, x, tracked, allowed)
        deb = np.linalg.norm(remove_mean_offset(capped, ref) - ref, axis=2)
        for region, joints in regions.items():
            ok = has_ref & joints[None, :] & np.isfinite(deb)
            out[(name, region)].update(deb_bar=deb[ok].astype(np.float32), bar_scale=a)


def _ratio(a: float, b: float) -> float | None:
    return a / b if b > 0 else None


_SUMMED = ("frames", "err_sum", "err_n", "ref_n", "jit_sum", "jit_ref_sum", "jit_n",
           "seam_sum", "seam_n", "other_sum", "other_n", "slow_sum", "slow_n", "move_sum", "move_n", "time_s")  # partial sums pooled over takes


def aggregate(partials: list[tuple[str, dict]]) -> list[dict]:
    """Pool :func:`score_take` results ``[(dataset, partial), ...]`` into one record per
    (dataset, method, region), in first-seen order."""
    pooled: dict[tuple, list[dict]] = {}
    for dataset, part in partials:
        for (method, region), p in part.items():
            pooled.setdefault((dataset, method, region), []).append(p)
    records = []
    for (dataset, method, region), ps in pooled.items():
        s = {k: sum(p[k] for p in ps) for k in _SUMMED}
        deb = np.concatenate([p["deb"] for p in ps]).astype(np.float64)
        cvs = np.array([p["cv"] for p in ps], dtype=np.float64)
        w = np.array([p["frames"] for p in ps], dtype=np.float64)
        ok = np.isfinite(cvs)
        xcs = np.array([p["xcorr"] for p in ps])
        xc = np.nansum(xcs * w[:, None], axis=0) if np.isfinite(xcs).any() else None
        lags = [p["lag"] for p in ps if p["lag"] is not None]
        mean_err = s["err_sum"] / s["err_n"] if s["err_n"] else None
        jit = s["jit_sum"] / s["jit_n"] if s["jit_n"] else None
        jit_ref = s["jit_ref_sum"] / s["jit_n"] if s["jit_n"] else None
        other = s["other_sum"] / s["other_n"] if s["other_n"] else None
        at_bar = all("deb_bar" in p for p in ps)
        deb_bar = np.concatenate([p["deb_bar"] for p in ps]).astype(np.float64) if at_bar else None
        records.append({
            "rate_hz": float(np.average([p["rate_hz"] for p in ps], weights=w)),
            "protocol": "paired",
            "level": 0.0,
            "method": method,
            "dataset": dataset,
            "region": region,
            "n_takes": len(ps),
            "n_frames": int(s["frames"]),
            "n_joints": max(p["n_joints"] for p in ps),
            "aje_m": mean_err,
            "abe_m": None,
            "gap_mae_m": None,
            "mean_error_m": mean_err,
            "coverage": s["err_n"] / s["ref_n"] if s["ref_n"] else None,
            "debiased_mean_m": float(deb.mean()) if deb.size else None,
            "debiased_p95_m": float(np.percentile(deb, 95)) if deb.size else None,
            "debiased_slow_m": s["slow_sum"] / s["slow_n"] if s["slow_n"] else None,
            "jitter": jit,
            "jitter_reference": jit_ref,
            "jitter_ratio": _ratio(jit, jit_ref) if jit is not None else None,
            "bone_cv": float(np.average(cvs[ok], weights=w[ok])) if ok.any() else None,
            "lag_frames": int(np.nanargmax(xc) - MAX_LAG_FRAMES) if xc is not None else None,
            "lag_frames_median": float(np.median(lags)) if lags else None,
            "seam_ratio": _ratio(s["seam_sum"] / s["seam_n"], other) if s["seam_n"] and other else None,
            "seam_frames": s["seam_n"],  # joint-frames next to a hand-over (0: every take was one window)
            "move_m": s["move_sum"] / s["move_n"] if s["move_n"] else None,
            "move_bar_scale": float(np.average([p["bar_scale"] for p in ps], weights=w)) if at_bar else None,
            "debiased_at_move_bar_m": float(deb_bar.mean()) if at_bar and deb_bar.size else None,
            "time_s": s["time_s"],
        })
    return records


def _score_ref(args: tuple) -> tuple[str, dict]:
    ref, methods, sensor_bias = args
    return ref.dataset, score_take(load_take(ref), methods, sensor_bias)


def held_out_bias_models(refs: list[TakeRef], *, workers: int = 1) -> dict[str, object]:
    """``{take key: pose-bias model}`` for the takes whose person the shipped model was fitted on.

    Each such person gets a model fitted on the engine's uncorrected output of every other
    person's trustworthy takes in the same source files (all of them, whatever ``limit``
    chose to score). Empty when no take's skeleton has a shipped model or none of their
    people trained it. ``ValueError`` when a person cannot be held out (no other person's takes).
    """
    from ..sensor_bias.shipped import shipped_model
    from ..sensor_bias.train import engine_outputs, subject_folds

    by_source: dict[str, list[TakeRef]] = {}
    for r in refs:
        if r.dataset == "uiprmd":
            by_source.setdefault(r.source, []).append(r)
    models: dict[str, object] = {}
    for source, scored in by_source.items():
        takes = engine_outputs(find_takes(source, subset="trustworthy"), workers=workers)
        shipped = shipped_model(takes[0].skeleton) if takes else None
        if shipped is None:
            continue
        seen = set(shipped.training_subjects) & {t.subject for t in takes}
        if not seen:
            continue
        folds = subject_folds(takes)
        for r in scored:
            subject = _uiprmd_subject(r.key)
            if subject in seen:
                models[r.key] = folds[subject]
    return models


def _uiprmd_subject(key: str) -> str:
    """``s01`` of a UI-PRMD key ``cor_m01_s01_e08``."""
    return next((p for p in key.split("_") if p.startswith("s") and p[1:].isdigit()), "")


def person_of(ref: TakeRef) -> str:
    """The person a take records (UI-PRMD's ``s01`` ...); "" where the data does not say."""
    return _uiprmd_subject(ref.key) if ref.dataset == "uiprmd" else ""


def known_methods(methods) -> list[str]:
    """The requested methods (None = :data:`DEFAULT_METHODS`) the registry knows; others
    are skipped with a warning."""
    wanted = list(DEFAULT_METHODS if methods is None else methods)
    known = [m for m in wanted if m in registry.METHODS]
    skipped = [m for m in wanted if m not in registry.METHODS]
    if skipped:
        warnings.warn(f"paired protocol: skipping method(s) the registry does not know: {', '.join(skipped)}",
                      stacklevel=2)
    if not known:
        raise ValueError(f"no method to run: {', '.join(wanted)} unknown; expected some of: "
                         f"{', '.join(registry.METHODS)}")
    return known


def run_paired(paths=(), *, rate_hz=None, levels=None, seed=0, methods=None, subset: str = "trustworthy",
               limit: int | None = None, workers: int = 1, progress=None, by_person: bool = False) -> list[dict]:
    """Score methods on the paired recordings (see the module doc for the records).

    ``paths``: paired directories or files (:func:`streamfix.io.paired.find_takes`;
    empty = the default directory). ``subset`` ``trustworthy`` | ``all`` (UI-PRMD);
    ``limit``: at most N repetitions per dataset, spread over the list. ``workers``:
    processes (takes are independent). ``levels`` and ``seed`` do not apply (real data,
    no corruption); ``rate_hz`` must be None: every take runs at its sensor's rate.
    ``by_person``: also one record per (dataset, person, method, region), pooled over that
    person's takes only, with ``person`` set (UI-PRMD's subjects; the pooled records have no
    ``person`` key). Why: the same checks run on people kept back, and how far each person
    of the shared data sits from a bar says how much room the pooled figure leaves.
    """
    if rate_hz is not None:
        raise ValueError(f"the paired protocol runs each take at its sensor's own rate; got --rate {rate_hz:g}")
    if levels is not None:
        raise ValueError(f"the paired protocol scores real sensor errors, it has no corruption levels; got {levels}")
    methods = known_methods(methods)
    sources = [Path(p) for p in paths] or [default_paired_dir()]
    records: list[dict] = []
    for src in sources:
        refs = find_takes(src, subset=subset, limit=limit)
        held_out = held_out_bias_models(refs, workers=workers) if set(methods) & set(registry.ENGINE_SCHEDULES) else {}
        jobs = [(r, methods, held_out.get(r.key)) for r in refs]
        if workers > 1 and len(jobs) > 1:
            import multiprocessing

            with multiprocessing.get_context("fork").Pool(min(workers, len(jobs))) as pool:
                part = []
                for i, res in enumerate(pool.imap(_score_ref, jobs, chunksize=4)):
                    part.append(res)
                    if progress is not None:
                        progress(i + 1, len(jobs))
        else:
            part = []
            for i, job in enumerate(jobs):
                part.append(_score_ref(job))
                if progress is not None:
                    progress(i + 1, len(jobs))
        held_datasets = {r.dataset for r in refs if r.key in held_out}
        groups = [(None, part)]
        if by_person:
            people = [person_of(r) for r in refs]
            groups += [(p, [pt for pt, q in zip(part, people) if q == p]) for p in sorted(set(people) - {""})]
        for person, partials in groups:
            for rec in aggregate(partials):
                rec["file"] = str(src)
                rec["subset"] = subset
                if person is not None:
                    rec["person"] = person
                if rec["method"] in registry.ENGINE_SCHEDULES:
                    rec["sensor_bias"] = "held-out person" if rec["dataset"] in held_datasets else "auto"
                records.append(rec)
    return records


def _mm(v) -> str:
    return "-" if v is None else f"{v * 1000:.1f}"


def _num(v, digits=2) -> str:
    return "-" if v is None else f"{v:.{digits}f}"


def print_paired_table(records: list[dict], out=None) -> None:
    """One table per (dataset, region): errors in mm, ratios against ``input``."""
    out = sys.stdout if out is None else out
    groups: dict[tuple, list[dict]] = {}
    for r in records:
        groups.setdefault((r["file"], r["dataset"], r["region"]), []).append(r)
    cols = ("mean mm", "debiased mm", "x input", "<3 Hz mm", "p95 mm", "x input", "jitter/ref", "bone CV", "lag fr",
            "seam")
    for (file, dataset, region), recs in groups.items():
        base = next((r for r in recs if r["method"] == "input"), None)
        bias = sorted({r["sensor_bias"] for r in recs if r.get("sensor_bias")})
        print(f"\n{dataset} ({recs[0]['n_takes']} takes, {recs[0]['n_frames']} frames, {recs[0].get('subset', '')}), "
              f"region {region}: {file}" + (f" (engine's sensor-bias model: {', '.join(bias)})" if bias else ""),
              file=out)
        print(f"{'method':<16}" + "".join(f"{c:>12}" for c in cols), file=out)
        for r in recs:
            rel = [None, None]
            if base is not None:
                for i, k in enumerate(("debiased_mean_m", "debiased_p95_m")):
                    if r[k] is not None and base[k]:
                        rel[i] = r[k] / base[k]
            row = [_mm(r["mean_error_m"]), _mm(r["debiased_mean_m"]), _num(rel[0]), _mm(r.get("debiased_slow_m")),
                   _mm(r["debiased_p95_m"]),
                   _num(rel[1]), _num(r["jitter_ratio"]), _num(r["bone_cv"], 4),
                   "-" if r["lag_frames"] is None else str(r["lag_frames"]), _num(r["seam_ratio"])]
            print(f"{r['method']:<16}" + "".join(f"{c:>12}" for c in row), file=out)


run_paired.print_table = print_paired_table  # `streamfix eval` prints these records with it
PROTOCOLS = {"paired": run_paired}
