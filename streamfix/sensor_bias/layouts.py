"""What a pose-bias model of each joint layout looks at and corrects (see :mod:`streamfix.core.pose_bias`).

A layout is here only where paired recordings (the sensor with optical motion capture at
once) exist to train it: today Kinect v1 in UI-PRMD's layout (``../shared/data/paired``).
The corrected joints are those the optical reference has; the others follow a neighbour.
"""
from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["BiasLayout", "BIAS_LAYOUTS"]


@dataclass(frozen=True)
class BiasLayout:
    """Joint names of one layout: the body frame, the segment groups, the corrected joints, who follows whom."""

    skeleton: str
    frame_joints: tuple[str, str, str, str]  # left shoulder, right shoulder, pelvis, neck
    groups: tuple[tuple[tuple[str, str], ...], ...]
    corrected: tuple[str, ...]
    follow: dict[str, dict[str, float]] = field(default_factory=dict)
    # corrected joints predicted from some groups only (indices into ``groups``); the others from all
    predictors: dict[str, tuple[int, ...]] = field(default_factory=dict)
    # the direction towards the sensor joins every group (camera-space coordinates: the sensor at the origin)
    sensor_direction: bool = False

    def predictor_groups(self) -> tuple[tuple[int, ...] | None, ...]:
        """Per corrected joint, the groups whose features predict it (None = every group)."""
        return tuple(self.predictors.get(j) for j in self.corrected)


def _sides(*stems: tuple[str, str]) -> tuple[tuple[str, str], ...]:
    return tuple((f"{s}{a}", f"{s}{b}") for s in ("L", "R") for a, b in stems)


_KINECT_V1_UIPRMD = BiasLayout(
    skeleton="kinect_v1_uiprmd",
    frame_joints=("LShoulder", "RShoulder", "Waist", "Neck"),
    groups=(
        # arms and head: the upper body's joints depend on how the arms are raised and bent
        _sides(("Shoulder", "Elbow"), ("Elbow", "Wrist")) + (("Neck", "HeadTip"),),
        # legs and pelvis: the lower body's on how the legs fold
        _sides(("Hip", "Knee"), ("Knee", "Ankle"), ("Ankle", "Foot")) + (("LHip", "RHip"),),
        (("Waist", "Neck"),),  # the trunk's lean against the shoulder line
    ),
    corrected=("Waist", "Neck", "HeadTip", "LShoulder", "LElbow", "LWrist", "RShoulder", "RElbow", "RWrist",
               "LHip", "LKnee", "LAnkle", "LFoot", "RHip", "RKnee", "RAnkle", "RFoot"),
    follow={"Spine": {"Waist": 0.5, "Neck": 0.5}, "Chest": {"Neck": 1.0}, "Head": {"HeadTip": 1.0},
            "LCollar": {"Neck": 0.5, "LShoulder": 0.5}, "RCollar": {"Neck": 0.5, "RShoulder": 0.5}},
    # the lower body from the legs and the trunk only: with the arms' features free, a standing
    # person's legs moved with every arm raise (the training squats hold the arms forward), and
    # held-out people's legs ended further from Vicon than the sensor had them in the shoulder
    # exercises (the model card's leave-one-subject-out scores). The upper body keeps every
    # group: the legs' fold tells it how the trunk leans
    predictors={j: (1, 2) for j in ("Waist", "LHip", "LKnee", "LAnkle", "LFoot", "RHip", "RKnee", "RAnkle", "RFoot")},
    # the sensor sees each limb from one side: the same bent arm is placed differently turned towards
    # it or away (streamfix.core.pose_bias). Held out one person at a time, it lowered the upper body's
    # error for each of the six people (the model card's leave-one-subject-out table)
    sensor_direction=True,
)

#: Layouts with a pose-bias model definition, by skeleton name.
BIAS_LAYOUTS: dict[str, BiasLayout] = {l.skeleton: l for l in (_KINECT_V1_UIPRMD,)}
