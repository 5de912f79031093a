"""Streaming layer: per-body ring buffers, windowed solving with overlap-add, the live fast path. No socket code."""
