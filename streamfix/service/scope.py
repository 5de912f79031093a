"""Skeleton layouts announced on the service's input, scoped to the stream that sent them.

A producer's skeleton message describes *its own* stream's frames. Keeping the layouts
per stream means one producer cannot change how another stream's frames decode (a
skeleton message redefining ``kinect_v2`` as 3 joints once broke every Kinect stream),
and built-in names (SPEC section 5) cannot be redefined at all
(:func:`~streamfix.service.validate.check_announcement`). Streams that announce a
layout but never send a frame are remembered only up to ``Limits.max_announcements``
(oldest forgotten first), and a stream's layouts are forgotten when the service
reclaims the stream.
"""
from __future__ import annotations

from collections import OrderedDict
from typing import Mapping

from ..skeletons import Skeleton
from .limits import Limits
from .validate import check_announcement

__all__ = ["SkeletonScope"]


class SkeletonScope:
    """Per-stream skeleton tables: ``announce`` checks and stores, ``table`` looks up."""

    def __init__(self, limits: Limits | None = None) -> None:
        self.limits = limits or Limits()
        self._tables: "OrderedDict[str, dict[str, Skeleton]]" = OrderedDict()
        self._rates: dict[str, tuple[str, float]] = {}
        self._active: set[str] = set()  # streams with an engine: never forgotten for space
        self.forgotten = 0  # announcements dropped for space (the ``announcements`` limit)

    def announce(self, stream_id: str, skeleton: Skeleton, rate_hz: float) -> None:
        """Store a stream's layout and rate; LimitHit (nothing stored) if it may not be used."""
        check_announcement(stream_id, skeleton, rate_hz, self.limits)
        table = self._tables.pop(stream_id, None) or {}
        table[skeleton.name] = skeleton
        if len(table) > 4:  # a stream switching layouts keeps its newest few
            table.pop(next(iter(table)))
        self._tables[stream_id] = table
        self._rates[stream_id] = (skeleton.name, float(rate_hz))
        while len(self._tables) - len(self._active & self._tables.keys()) > self.limits.max_announcements:
            for old in self._tables:
                if old not in self._active:
                    self.forget(old)
                    self.forgotten += 1
                    break

    def table(self, stream_id: str) -> Mapping[str, Skeleton]:
        """The layouts ``stream_id`` announced (empty if none): the decoder's lookup."""
        return self._tables.get(stream_id, {})

    def rate(self, stream_id: str, skeleton_name: str) -> float | None:
        """The rate the stream announced with this skeleton, or None."""
        got = self._rates.get(stream_id)
        return got[1] if got is not None and got[0] == skeleton_name else None

    def activate(self, stream_id: str) -> None:
        """The stream has an engine now: keep its layouts until :meth:`forget`."""
        self._active.add(stream_id)

    def forget(self, stream_id: str) -> None:
        """Drop everything about a stream (it ended or was reclaimed)."""
        self._tables.pop(stream_id, None)
        self._rates.pop(stream_id, None)
        self._active.discard(stream_id)

    def __len__(self) -> int:
        return len(self._tables)
