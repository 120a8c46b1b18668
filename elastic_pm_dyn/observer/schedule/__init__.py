"""The scheduler around the core: :class:`~.ekf.Observer` owns command delays, sample timing,
gating, recovery, faults and statistics, and takes the messages a compiled step does not
(:mod:`~elastic_pm_dyn.observer.core.period`); :mod:`.consistency` reads its NIS statistics."""
