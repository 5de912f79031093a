"""Is a body in metres? A plausibility test of the units positions arrive in.

Every stage is tuned in metres (noise floors of millimetres, gates of centimetres, bone
lengths of decimetres). A body given in millimetres by mistake is 1000 times too big: each
sample then looks like an outlier and the output is metres off, with no error. A person's
bones are at most about 0.6 m (the thigh) and a whole body spans at most about 2.5 m, so a
median bone over :data:`MAX_MEDIAN_BONE_M`, or a median body extent over
:data:`MAX_MEDIAN_EXTENT_M` for a marker set without bones, is not metres. Absolute
coordinates are not looked at: a world origin 1000 m away is fine.
"""
from __future__ import annotations

import warnings

import numpy as np

__all__ = ["MAX_MEDIAN_BONE_M", "MAX_MEDIAN_EXTENT_M", "units_problem"]

MAX_MEDIAN_BONE_M = 3.0
MAX_MEDIAN_EXTENT_M = 10.0
SAMPLE_FRAMES = 2000  # at most this many frames looked at, evenly spaced: the medians are far from the limits


def units_problem(positions: np.ndarray, bones: np.ndarray) -> str | None:
    """Why ``positions`` ``(T, J, 3)`` cannot be metres (a sentence naming the measured size), or None.

    ``bones`` ``(B, 2)``: the skeleton's (parent, child) joints; without bones the median
    over frames of each frame's extent (bounding-box diagonal of its finite joints) is used.
    A long take is judged on at most :data:`SAMPLE_FRAMES` evenly spaced frames (the whole check had a
    measurable cost on a long file; people's bones are 10x under the limit, millimetres 300x over).
    """
    x = np.asarray(positions, dtype=np.float64)
    x = x[:: max(1, -(-len(x) // SAMPLE_FRAMES))]  # the step rounded up: never more than SAMPLE_FRAMES
    b = np.asarray(bones, dtype=np.intp).reshape(-1, 2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN frames or joints
        if len(b):
            lengths = np.linalg.norm(x[:, b[:, 1]] - x[:, b[:, 0]], axis=2)
            lengths = lengths[np.isfinite(lengths)]
            if lengths.size and np.median(lengths) > MAX_MEDIAN_BONE_M:
                return (f"the median bone is {np.median(lengths):.4g} long, a person's are at most about "
                        "0.6 m: positions look like millimetres or centimetres, not metres")
            return None
        extent = np.linalg.norm(np.nanmax(x, axis=1) - np.nanmin(x, axis=1), axis=1)
        extent = extent[np.isfinite(extent)]
        if extent.size and np.median(extent) > MAX_MEDIAN_EXTENT_M:
            return (f"the median body extent is {np.median(extent):.4g}, a person spans at most about 2.5 m: "
                    "positions look like millimetres or centimetres, not metres")
    return None
