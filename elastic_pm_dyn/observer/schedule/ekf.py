"""The names that lived here before the observer was split by job (importers of the old path keep working).

The filter itself is :mod:`elastic_pm_dyn.observer.core.ekf` (:class:`Ekf`, :class:`ObserverFault`);
the scheduler over it :mod:`.observer` (:class:`Observer`); its parts :mod:`.commands`,
:mod:`.sample_timing`, :mod:`.recovery` and :mod:`.sensor_stats`; the estimate row
:mod:`elastic_pm_dyn.observer.core.estimate`. New code imports from there.
"""

from elastic_pm_dyn.observer.core.ekf import Ekf, ObserverFault
from elastic_pm_dyn.observer.core.estimate import Estimate
from elastic_pm_dyn.observer.schedule.commands import MAX_PENDING_COMMANDS
from elastic_pm_dyn.observer.schedule.observer import Observer
from elastic_pm_dyn.observer.schedule.recovery import RECOVERY_PSD_GROWTH, RECOVERY_PSD_MAX, Recovery
from elastic_pm_dyn.observer.schedule.sample_timing import (
    TIMING_MIN_SAMPLES,
    TIMING_MODES,
    TIMING_RECHECK,
    TIMING_SWITCH_EVIDENCE,
    TIMING_TRIAL,
    TimingDecision,
)
from elastic_pm_dyn.observer.schedule.sensor_stats import (
    ERROR,
    LOG_2PI,
    OK,
    WARN,
    SensorStats,
    UpdateResult,
    nll_term,
)

__all__ = ["ERROR", "LOG_2PI", "MAX_PENDING_COMMANDS", "OK", "RECOVERY_PSD_GROWTH", "RECOVERY_PSD_MAX",
           "TIMING_MIN_SAMPLES", "TIMING_MODES", "TIMING_RECHECK", "TIMING_SWITCH_EVIDENCE", "TIMING_TRIAL", "WARN",
           "Ekf", "Estimate", "Observer", "ObserverFault", "Recovery", "SensorStats", "TimingDecision",
           "UpdateResult", "nll_term"]
