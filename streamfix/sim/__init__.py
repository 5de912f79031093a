"""Synthetic Kinect v2 sessions: a procedural body, and a sensor model measured on real recordings.

* :mod:`streamfix.sim.measure` -- statistics of a Kinect v2 recording: high-frequency
  jitter level and colour per joint, inferred-joint fraction and run lengths, how far
  inferred joints sit from plausible, dropped frames, outlier (spike) rate.
* :mod:`streamfix.sim.sensor` -- :class:`SensorModel`, built from those measurements,
  turns a clean motion into what a Kinect v2 would report.
* :mod:`streamfix.sim.body` -- a parametric 25-joint Kinect v2 body doing smooth
  activities (waving, reaching, drawing, beckoning, stepping, seated gesturing).

``tools/make_replay_data.py`` ties them together to write ``replay_data/``.
"""
