"""``streamfix serve``: sources, validation, per-stream engines, publisher, metrics.

Modules: :mod:`.sources` (bound ZeroMQ PULL, stdin, replay), :mod:`.textin` (stdin
line formats), :mod:`.validate` (bad-input reasons), :mod:`.engines` (streamfix /
passthrough), :mod:`.publisher` (PUB, never blocking), :mod:`.metrics` (Prometheus
text over HTTP), :mod:`.playback` (drift-free timing of recordings), :mod:`.server`
(the loop, signals, flush on shutdown).
"""
