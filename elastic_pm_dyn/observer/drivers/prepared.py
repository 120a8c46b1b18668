"""A recording prepared once for many filter passes (``tune``: one pass per candidate configuration).

What a pass over the same events needs whatever the noise levels and the disturbance model:
the fixed :class:`~elastic_pm_dyn.observer.core.observer_model.ObserverModel` and the offline fast
path's runs (:class:`~elastic_pm_dyn.observer.drivers.event_filter.FastRuns`: the stamp groups and the
decoded encoder, accelerometer and command arrays). Both depend only on the mechanism, the
events, :func:`~elastic_pm_dyn.observer.core.observer_model.model_key` and ``timing.max_future``, so
each candidate builds only its cheap part (its disturbance model, noise levels and filter
state). Read only once made: passes may share it from several threads.
"""

from __future__ import annotations

from dataclasses import dataclass

from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.observer.config import ObserverConfig
from elastic_pm_dyn.observer.core.observer_model import ObserverModel
from elastic_pm_dyn.observer.drivers.bag_input import Event
from elastic_pm_dyn.observer.drivers.event_filter import FastRuns, fast_runs
from elastic_pm_dyn.observer.schedule.observer import Observer


@dataclass(frozen=True, eq=False)
class PreparedRecording:
    """The shared part of filter passes over ``events`` in their given order, from ``origin_ns``."""

    model: ObserverModel
    runs: FastRuns
    origin_ns: int


def prepare(mech: Mechanism, cfg: ObserverConfig, events: list[Event]) -> PreparedRecording:
    """The :class:`PreparedRecording` of ``events`` (fed in this order, time origin the first
    stamp) for configurations of ``cfg``'s model key (an Observer refuses any other)."""
    model = ObserverModel.build(mech, cfg)
    origin = events[0].stamp_ns
    return PreparedRecording(model, fast_runs(Observer(model, cfg, t0=0.0), events, origin), origin)
