"""The scheduler around the filter: :class:`~.observer.Observer` takes time-stamped messages and
decides what the filter (:mod:`~elastic_pm_dyn.observer.core.ekf`) predicts and corrects, with its
parts: the commands (:mod:`.commands`), the accelerometer's sample timing (:mod:`.sample_timing`),
the fall-back from divergence (:mod:`.recovery`) and the sensors' statistics (:mod:`.sensor_stats`,
:mod:`.consistency`). :mod:`.ekf` keeps the old import path's names."""
