"""The one in-memory type for a captured motion.

Conventions, relied on everywhere:

* ``positions`` is ``(T, J, 3)`` float64 in **metres**. A sample that was not
  observed holds NaN, so no code can mistake it for data by accident.
* ``confidence`` is ``(T, J)`` float in [0, 1]: 1 = tracked, 0.5 = inferred by the
  sensor (Kinect tracking state 1; the joint was guessed, usually occluded),
  0 = missing. A sample is *observed* when its confidence is > 0 and its
  position finite.
* ``timestamps`` is ``(T,)`` float64 in **seconds** (sensor clock), strictly
  increasing; ``rate_hz`` is the nominal frame rate.
* ``recovered`` is an optional ``(T, J)`` bool mask set by cleaning: True where
  the output value was recovered rather than observed.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .core.points import finite_points
from .skeletons import Skeleton

__all__ = [
    "Motion",
    "CONFIDENCE_TRACKED",
    "CONFIDENCE_INFERRED",
    "CONFIDENCE_MISSING",
]

CONFIDENCE_TRACKED = 1.0
CONFIDENCE_INFERRED = 0.5
CONFIDENCE_MISSING = 0.0


@dataclass
class Motion:
    """A skeleton sequence: positions (m), per-joint confidence, timestamps (s)."""

    positions: np.ndarray
    confidence: np.ndarray
    timestamps: np.ndarray
    rate_hz: float
    skeleton: Skeleton
    recovered: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.positions = np.asarray(self.positions, dtype=np.float64)
        if self.positions.ndim != 3 or self.positions.shape[2] != 3:
            raise ValueError(f"positions must be (T, J, 3), got {self.positions.shape}")
        n_frames, n_joints, _ = self.positions.shape
        if n_joints != self.skeleton.n_joints:
            raise ValueError(
                f"skeleton {self.skeleton.name!r} expects {self.skeleton.n_joints} joints, "
                f"positions have {n_joints}"
            )
        self.confidence = np.asarray(self.confidence, dtype=np.float64)
        if self.confidence.shape != (n_frames, n_joints):
            raise ValueError(
                f"confidence must be {(n_frames, n_joints)}, got {self.confidence.shape}"
            )
        self.timestamps = np.asarray(self.timestamps, dtype=np.float64)
        if self.timestamps.shape != (n_frames,):
            raise ValueError(f"timestamps must be ({n_frames},), got {self.timestamps.shape}")
        if not (np.isfinite(self.rate_hz) and self.rate_hz > 0):
            raise ValueError(f"rate_hz must be a positive number, got {self.rate_hz}")
        self.rate_hz = float(self.rate_hz)
        if self.recovered is not None:
            self.recovered = np.asarray(self.recovered, dtype=bool)
            if self.recovered.shape != (n_frames, n_joints):
                raise ValueError(
                    f"recovered must be {(n_frames, n_joints)}, got {self.recovered.shape}"
                )
        # A NaN/inf coordinate is a missing joint, whatever its stated confidence.
        bad = ~finite_points(self.positions)
        if bad.any():
            self.positions[bad] = np.nan
            self.confidence[bad] = CONFIDENCE_MISSING
        self.positions[self.confidence <= 0] = np.nan

    @property
    def n_frames(self) -> int:
        return self.positions.shape[0]

    @property
    def n_joints(self) -> int:
        return self.positions.shape[1]

    @property
    def observed(self) -> np.ndarray:
        """``(T, J)`` bool: the joint was seen (tracked or inferred) in that frame."""
        return self.confidence > 0

    @property
    def duration_s(self) -> float:
        return float(self.timestamps[-1] - self.timestamps[0]) if self.n_frames else 0.0

    def copy(self) -> "Motion":
        return replace(
            self,
            positions=self.positions.copy(),
            confidence=self.confidence.copy(),
            timestamps=self.timestamps.copy(),
            recovered=None if self.recovered is None else self.recovered.copy(),
            meta=dict(self.meta),
        )

    def slice(self, start: int, stop: int) -> "Motion":
        """Frames ``start:stop`` as a new motion (copies)."""
        return replace(
            self,
            positions=self.positions[start:stop].copy(),
            confidence=self.confidence[start:stop].copy(),
            timestamps=self.timestamps[start:stop].copy(),
            recovered=None if self.recovered is None else self.recovered[start:stop].copy(),
            meta=dict(self.meta),
        )

    @classmethod
    def from_positions(
        cls,
        positions: np.ndarray,
        skeleton: Skeleton,
        rate_hz: float,
        confidence: np.ndarray | None = None,
        t0: float = 0.0,
    ) -> "Motion":
        """A motion with uniform timestamps; every finite sample observed unless told."""
        positions = np.asarray(positions, dtype=np.float64)
        if confidence is None:
            confidence = finite_points(positions).astype(np.float64)
        timestamps = t0 + np.arange(positions.shape[0]) / float(rate_hz)
        return cls(positions.copy(), np.array(confidence, dtype=np.float64), timestamps, rate_hz, skeleton)
