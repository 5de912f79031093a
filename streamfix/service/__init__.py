"""``streamfix serve``: sources, validation, per-stream engines, publisher, metrics.

Modules: :mod:`.sources` (bound ZeroMQ PULL, stdin, replay, DepthAI), :mod:`.items`
(what a source hands the loop: frames, announcements, rejections, shed counts),
:mod:`.backlog` (received input, arrival-stamped and bounded: the overload policy), :mod:`.textin` (stdin line formats), :mod:`.validate` (bad-input reasons,
limit checks), :mod:`.limits` (resource limits and their defaults), :mod:`.scope`
(skeleton layouts scoped to the announcing stream), :mod:`.numbering` (output seq and
epochs), :mod:`.engines` (streamfix / passthrough), :mod:`.publisher` (PUB, never
blocking), :mod:`.metrics` (Prometheus text over bounded HTTP), :mod:`.playback`
(drift-free timing of recordings), :mod:`.server` (the loop, containment, signals,
bounded flush on shutdown).
"""
