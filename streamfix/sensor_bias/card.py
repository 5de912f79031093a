"""The model card written beside a pose-bias model (``<model>.md``): data, licence, structure, held-out scores.

Every figure in it is computed by ``streamfix train-bias`` when it writes the model; the
card's first lines carry the model file's SHA-256 so a test can tell a stale card.
"""
from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from ..core.pose_bias import CLIP_QUANTILE, FADE_END_FACTOR, FADE_START_QUANTILE, PoseBiasModel, feature_groups
from .train import TRAINING_METHOD, TrainingTake

__all__ = ["write_card", "card_path", "file_sha256"]

LICENCES = {
    "kinect_v1_uiprmd": "UI-PRMD (Vakanski et al., Data 2018, 3(1):2), Open Data Commons PDDL 1.0: public "
                        "domain, commercial use allowed",
}


def card_path(model_path: str | Path) -> Path:
    return Path(model_path).with_suffix(".md")


def file_sha256(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


_KEYS = ("before_m", "after_m", "raw_before_m", "raw_after_m")


def _row(subject: str, region: str, n: int, v: dict) -> str:
    return (f"| {subject} | {region} | {n} | {1000 * v['before_m']:.1f} | {1000 * v['after_m']:.1f} | "
            f"{v['after_m'] / v['before_m']:.3f} | {1000 * v['raw_before_m']:.1f} | {1000 * v['raw_after_m']:.1f} |")


def _score_table(scores: list[dict]) -> list[str]:
    lines = ["| held-out subject | region | joint-frames | debiased before, mm | after, mm | after / before "
             "| raw before, mm | raw after, mm |",
             "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    lines += [_row(r["subject"], r["region"], r["joint_frames"], r) for r in scores]
    for region in sorted({r["region"] for r in scores}):
        rows = [r for r in scores if r["region"] == region]
        n = sum(r["joint_frames"] for r in rows)
        pooled = {k: sum(r[k] * r["joint_frames"] for r in rows) / n for k in _KEYS}
        lines.append(_row("all, pooled", region, n, pooled))
    return lines


def _predictor_line(model: PoseBiasModel) -> str:
    """Which segment groups each corrected joint's correction reads (its non-zero weight rows)."""
    col_group = feature_groups(model.joint_names, model.groups, model.sensor_direction)
    labels = [f"{g[0][0]}-{g[0][1]}" + (" ..." if len(g) > 1 else "") for g in model.groups]
    by: dict[tuple[int, ...], list[str]] = {}
    for k, joint in enumerate(model.corrected):
        used = model.weights[:, 3 * k:3 * k + 3].any(axis=1)
        by.setdefault(tuple(int(g) for g in np.unique(col_group[used])), []).append(joint)
    return "; ".join(f"{', '.join(joints)} from group(s) {', '.join(f'{g} ({labels[g]})' for g in groups)}"
                     for groups, joints in by.items())


def write_card(model_path: str | Path, model: PoseBiasModel, takes: list[TrainingTake], scores: list[dict] | None,
               *, data_dir: str | Path | None = None) -> Path:
    """Write ``<model>.md`` for the model file just saved; returns its path."""
    model_path = Path(model_path)
    used = [t for t in takes if t.skeleton == model.skeleton]
    frames = int(sum(len(t.output) for t in used))
    minutes = sum(len(t.output) / t.rate_hz for t in used) / 60.0
    subjects = sorted({t.subject for t in used})
    lines = [
        f"# Pose-bias model `{model_path.name}` ({model.skeleton})",
        "",
        f"model-sha256: {file_sha256(model_path)}",
        f"skeleton: {model.skeleton}",
        f"training-takes: {len(used)}",
        f"training-frames: {frames}",
        f"subjects: {', '.join(subjects)}",
        "",
        "Written by `streamfix train-bias`; what the model is: `streamfix/core/pose_bias.py`.",
        "",
        "## Data",
        f"- {LICENCES.get(model.skeleton, 'licence unknown: do not ship')}.",
        f"- Every trustworthy repetition of the paired directory ({data_dir or 'default: ../shared/data/paired'}): "
        f"{len(used)} repetitions, {frames} frames (about {minutes:.0f} minutes), subjects "
        f"{', '.join(subjects)}, 10 movements.",
        f"- Inputs: the engine's clean output without bias correction (`{TRAINING_METHOD}`, the file schedule, "
        "what `streamfix clean` writes); targets: the Vicon reference joints (marker means, "
        "`../shared/data/paired/README.md`); the average error over all frames is not learned.",
        "- What it learns is the difference between the sensor's joints and that reference as it changes with "
        "the pose. Part of it is the sensor's (legs folded in a squat, arms raised); part may be the markers' "
        "own pose-dependent offset from the joint centres (a knee marker sits on the skin beside the knee): "
        "these data cannot tell the two apart. `--sensor-bias off` keeps the sensor's own joint convention.",
        "",
        "## Structure",
        f"- Corrected joints ({len(model.corrected)}): {', '.join(model.corrected)}; the others follow them "
        f"(`follow`).",
        f"- Features: {model.weights.shape[0]} (segment directions in the body frame"
        + (", with the direction from the trunk towards the sensor in every group," if model.sensor_direction else "")
        + f" and their products within each of {len(model.groups)} groups); ridge {model.ridge:g} per frame.",
        f"- Predictors: {_predictor_line(model)}.",
        f"- Unfamiliar poses: the correction fades from the {FADE_START_QUANTILE:.0%} quantile of the training "
        f"poses' distance to the nearest of {len(model.centres)} k-means centres ({model.fade_start:.3f}) to "
        f"{FADE_END_FACTOR:g}x their largest ({model.fade_end:.3f}); each joint's correction is clipped at the "
        f"{CLIP_QUANTILE:.1%} quantile of the training ones ({1000 * float(np.min(model.max_correction_m)):.0f}-"
        f"{1000 * float(np.max(model.max_correction_m)):.0f} mm).",
        "",
    ]
    if scores:
        lines += ["## Held-out people (leave one subject out)",
                  "",
                  "Each subject's repetitions scored with a model fitted on the other subjects: mean error "
                  "against the reference before and after the correction, debiased (each joint's mean offset "
                  "over the repetition removed, the paired benchmark's measure) and raw.",
                  "",
                  *_score_table(scores),
                  ""]
    path = card_path(model_path)
    path.write_text("\n".join(lines) + "\n")
    return path
