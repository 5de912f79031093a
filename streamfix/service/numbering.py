"""Output sequence numbers and stream epochs (``protocol/SPEC.md`` section 2a).

The engine numbers a stream's output ``seq0 + k`` from the first input ``seq`` it saw.
The service owns what goes on the wire: within one **epoch** of a stream, ``seq``
increases by exactly 1 per output instant (live and clean share it) and never goes
back; a new epoch starts when the service starts the stream's engine afresh (first
frame, producer restart, skeleton change, a contained failure) or when ``seq`` would
pass the largest unsigned 64-bit value (it then wraps to 0 in the next epoch). Epochs
of one stream only increase, across service restarts too: a new epoch is the wall
clock in nanoseconds, made strictly larger than the previous epoch of the stream.

Across an engine restart within one run of the service, ``seq`` continues from the
last published value (SPEC section 1: it never goes back within a run); only the
first engine of a stream keeps the producer's numbering (output ``seq`` = input
``seq`` while nothing is dropped), as before epochs existed.
"""
from __future__ import annotations

import time

__all__ = ["SEQ_LIMIT", "Numbering"]

SEQ_LIMIT = 2**64
"""``seq`` is an unsigned 64-bit integer on the wire: values are ``0 .. SEQ_LIMIT - 1``."""


class Numbering:
    """Maps one stream's engine output ``seq`` to the wire ``(epoch, seq)``.

    Call :meth:`restart` whenever the stream gets a new engine; :meth:`wire` maps every
    output frame's engine ``seq`` (the first call after a restart fixes the offset).
    """

    def __init__(self) -> None:
        self.epoch = 0
        self.restarts = 0          # engine restarts after the first start
        self._next = None          # wire position (epoch-relative, unbounded) after the newest output
        self._offset = None        # engine seq -> unbounded wire position
        self._base_epoch = 0
        self._last_epoch = 0

    def _new_epoch(self) -> int:
        self._last_epoch = max(time.time_ns(), self._last_epoch + 1)
        return self._last_epoch

    def restart(self) -> None:
        """A new engine: a new epoch; ``seq`` continues after the last one published."""
        if self._offset is not None or self._next is not None:
            self.restarts += 1
        if self._next is not None:
            self._next %= SEQ_LIMIT  # positions are relative to the new epoch from here on
        self._base_epoch = self._new_epoch()
        self.epoch = self._base_epoch
        self._offset = None

    def wire(self, engine_seq: int) -> tuple[int, int]:
        """``(epoch, seq)`` for an output frame the engine numbered ``engine_seq``."""
        if self._offset is None:
            start = int(engine_seq) if self._next is None else self._next % SEQ_LIMIT
            self._offset = start - int(engine_seq)
        pos = int(engine_seq) + self._offset
        wraps, seq = divmod(pos, SEQ_LIMIT)
        epoch = self._base_epoch + wraps
        if epoch > self._last_epoch:  # seq wrapped: that epoch is now taken
            self._last_epoch = epoch
        self.epoch = epoch
        if self._next is None or pos + 1 > self._next:
            self._next = pos + 1
        return epoch, seq
