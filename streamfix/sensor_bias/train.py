"""Train a pose-bias model from paired recordings, and measure it on people it never saw.

The model learns what the engine's clean output still gets wrong against the optical
joint centres, so its training inputs are the engine's ``clean`` output with no bias
correction (``streamfix`` on the file schedule, ``sensor_bias="off"``) for every
trustworthy repetition of the paired recordings, next to their references.
``leave_one_subject_out`` fits one model per person on everyone else and scores it on
that person: the figure that says how the shipped model does on people outside the
training set (``streamfix train-bias`` writes it into the model card;
``bench_paired`` scores the ``streamfix`` method the same way).

Licence: UI-PRMD (the only paired data set with a Kinect layout enough people were
recorded in) is in the public domain (``../shared/data/paired/README.md``).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from ..core.pose_bias import PoseBiasModel, correction_gain, fit_pose_bias, remove_pose_bias
from ..core.reference_metrics import remove_mean_offset
from ..io.paired import PairedTake, TakeRef, find_takes, load_take
from .layouts import BIAS_LAYOUTS, BiasLayout

__all__ = ["TrainingTake", "engine_outputs", "fit_layout_model", "leave_one_subject_out", "subject_folds",
           "TRAINING_METHOD", "paired_takes"]

TRAINING_METHOD = "streamfix"  # the engine's clean output on the file schedule, what `clean` writes


@dataclass
class TrainingTake:
    """One repetition: the engine's clean output without bias correction and the reference (T, J, 3) m."""

    key: str
    subject: str
    skeleton: str
    joint_names: tuple[str, ...]
    output: np.ndarray
    reference: np.ndarray
    rate_hz: float
    bones: np.ndarray  # (B, 2) the skeleton's bones


def _engine_output(ref: TakeRef) -> TrainingTake:
    from ..evaluation.registry import run_method

    take: PairedTake = load_take(ref)
    m = take.sensor
    out = run_method(TRAINING_METHOD, m.positions, m.confidence, m.skeleton.bone_array, m.rate_hz,
                     skeleton=m.skeleton, sensor_bias="off")
    return TrainingTake(take.key, take.subject, m.skeleton.name, tuple(m.skeleton.joint_names),
                        out.astype(np.float32), take.reference.astype(np.float32), float(m.rate_hz),
                        m.skeleton.bone_array)


def engine_outputs(refs: list[TakeRef], *, workers: int = 1,
                   progress: Callable[[int, int], None] | None = None) -> list[TrainingTake]:
    """The engine's uncorrected clean output of every take (``workers`` processes), in ``refs`` order."""
    out: list[TrainingTake] = []
    if workers > 1 and len(refs) > 1:
        import multiprocessing

        with multiprocessing.get_context("fork").Pool(min(workers, len(refs))) as pool:
            for i, t in enumerate(pool.imap(_engine_output, refs, chunksize=8)):
                out.append(t)
                if progress is not None:
                    progress(i + 1, len(refs))
    else:
        for i, r in enumerate(refs):
            out.append(_engine_output(r))
            if progress is not None:
                progress(i + 1, len(refs))
    return out


def fit_layout_model(takes: list[TrainingTake], layout: BiasLayout | None = None, *, seed: int = 0) -> PoseBiasModel:
    """Fit the layout's model (default: the takes' skeleton's) on ``takes``."""
    if not takes:
        raise ValueError("no training takes")
    layout = layout or BIAS_LAYOUTS.get(takes[0].skeleton)
    if layout is None:
        raise ValueError(f"no pose-bias layout for skeleton {takes[0].skeleton!r}; known: {', '.join(BIAS_LAYOUTS)}")
    used = [t for t in takes if t.skeleton == layout.skeleton]
    return fit_pose_bias(
        [(t.output, t.reference) for t in used], training_subjects=tuple(sorted({t.subject for t in used})),
        skeleton=layout.skeleton, joint_names=takes[0].joint_names, frame_joints=layout.frame_joints,
        groups=layout.groups, corrected=layout.corrected, follow=layout.follow, seed=seed,
        predictors=layout.predictor_groups(), sensor_direction=layout.sensor_direction,
    )


def subject_folds(takes: list[TrainingTake], *, seed: int = 0) -> dict[str, PoseBiasModel]:
    """One model per subject, fitted on every other subject's takes."""
    subjects = sorted({t.subject for t in takes})
    if len(subjects) < 2:
        raise ValueError(f"leave-one-subject-out needs two subjects or more, got {subjects}")
    return {s: fit_layout_model([t for t in takes if t.subject != s], seed=seed) for s in subjects}


def leave_one_subject_out(takes: list[TrainingTake], *, seed: int = 0) -> list[dict]:
    """Per held-out subject and region: mean error (m) of the output before and after its fold's model,
    debiased (``before_m``, ``after_m``: each joint's mean offset over the take removed) and raw."""
    from ..evaluation.paired import region_masks

    folds = subject_folds(takes, seed=seed)
    rows = []
    for subject, model in folds.items():
        sums: dict[str, list[float]] = {}
        for t in (t for t in takes if t.subject == subject):
            ref = t.reference.astype(np.float64)
            before = t.output.astype(np.float64)
            after = remove_pose_bias(before, t.bones, model, correction_gain(t.rate_hz))[0]  # what the engine emits
            for region, joints in region_masks(t.joint_names).items():
                if region == "all":
                    continue
                errs = [np.linalg.norm(remove_mean_offset(y, ref) - ref, axis=2)[:, joints] for y in (before, after)]
                errs += [np.linalg.norm(y - ref, axis=2)[:, joints] for y in (before, after)]
                ok = np.logical_and.reduce([np.isfinite(e) for e in errs])
                s = sums.setdefault(region, [0.0] * 4 + [0])
                for i, e in enumerate(errs):
                    s[i] += float(e[ok].sum())
                s[4] += int(ok.sum())
        for region, (b, a, rb, ra, n) in sums.items():
            n1 = max(n, 1)
            rows.append({"subject": subject, "region": region, "joint_frames": n, "before_m": b / n1,
                         "after_m": a / n1, "raw_before_m": rb / n1, "raw_after_m": ra / n1})
    return rows


def paired_takes(data_dir: str | Path | None = None) -> list[TakeRef]:
    """The trustworthy UI-PRMD repetitions under the paired directory (the training set)."""
    return [r for r in find_takes(data_dir, subset="trustworthy") if r.dataset == "uiprmd"]
