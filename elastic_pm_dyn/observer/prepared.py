"""A recording prepared once for many filter passes (``tuning.evaluate``: one per candidate configuration).

What a pass over the same events needs whatever the noise levels and the disturbance model:
the fixed :class:`~elastic_pm_dyn.observer.observer_model.ObserverModel` and the offline fast
path's runs (:class:`~elastic_pm_dyn.observer.event_filter.FastRuns`: the stamp groups and the
decoded encoder, accelerometer and command arrays). Both depend only on the mechanism, the
events, :func:`~elastic_pm_dyn.observer.observer_model.model_key` and ``timing.max_future``; a
small cache keeps the last few, so that each candidate builds only its cheap part (its
disturbance model, noise levels and filter state). Thread-safe (``tune`` runs two passes at once);
what it hands out is read only.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass

from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.observer.bag_input import Event
from elastic_pm_dyn.observer.config import ObserverConfig
from elastic_pm_dyn.observer.ekf import Observer
from elastic_pm_dyn.observer.event_filter import FastRuns, fast_runs
from elastic_pm_dyn.observer.observer_model import ObserverModel, model_key

CACHED = 4  # recordings (with their configuration keys) kept


@dataclass(frozen=True, eq=False)
class PreparedRecording:
    """The shared part of filter passes over ``events`` in their given order, from ``origin_ns``."""

    model: ObserverModel
    runs: FastRuns
    origin_ns: int


_cache: OrderedDict[tuple, tuple[Mechanism, list[Event], PreparedRecording]] = OrderedDict()
_lock = threading.Lock()


def prepare(mech: Mechanism, cfg: ObserverConfig, events: list[Event]) -> PreparedRecording:
    """The :class:`PreparedRecording` of ``events`` (fed in this order, time origin the first
    stamp) for configurations like ``cfg``; made once per (mechanism, events, key), then cached."""
    key = (id(mech), id(events), len(events), model_key(cfg), cfg.timing.max_future)
    with _lock:
        hit = _cache.get(key)
        if hit is not None and hit[0] is mech and hit[1] is events:  # the objects themselves (ids are reused)
            _cache.move_to_end(key)
            return hit[2]
        model = ObserverModel.build(mech, cfg)
        origin = events[0].stamp_ns
        prepared = PreparedRecording(model, fast_runs(Observer(model, cfg, t0=0.0), events, origin), origin)
        _cache[key] = (mech, events, prepared)
        while len(_cache) > CACHED:
            _cache.popitem(last=False)
        return prepared
