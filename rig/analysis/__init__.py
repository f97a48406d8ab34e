"""Analysis of recorded sessions: reference sideslip, VSC estimate scoring, steering reconstruction, rollover.

Pure functions over numpy arrays on one time base; ``rig/dataset`` reads sessions into such arrays
and the ``rig validate`` / ``rig rollover`` commands call these modules:

- :mod:`rig.analysis.reference` — dual-antenna GNSS and optical reference sideslip, tyre slip angles;
- :mod:`rig.analysis.smoothing` — wavelet denoising and the RTS smoother behind the reference;
- :mod:`rig.analysis.metrics` — error statistics, lag, a_y bins, pass/fail;
- :mod:`rig.analysis.manoeuvres` — manoeuvre segmentation and per-manoeuvre scoring;
- :mod:`rig.analysis.scoring` — the ``rig validate`` computation, offline estimators;
- :mod:`rig.analysis.steering` — road-wheel angle from speed and lateral acceleration, its error model;
- :mod:`rig.analysis.rollover` — load-transfer ratio and its autoregressive prediction.
"""
