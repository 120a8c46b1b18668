"""``elastic-pm-dyn observe``: the observer over a recorded bag, as fast as possible.

Reads the events of a bag (:mod:`~elastic_pm_dyn.observer.drivers.bag_input`), feeds them through
the filter (:mod:`~elastic_pm_dyn.observer.drivers.event_filter`: the same
:class:`~elastic_pm_dyn.observer.drivers.stream.ObserverStream` as the live node, ordinary periods
many at once in one compiled call) and writes (:mod:`~elastic_pm_dyn.observer.drivers.bag_output`)
``estimates.csv``, ``estimates/`` (a bag of estimates) and ``summary.json`` (counts,
rejections, mean NIS, speed, the observability report; :mod:`~elastic_pm_dyn.observer.drivers.results`);
with wrench states also ``contacts.csv`` (:mod:`~elastic_pm_dyn.observer.drivers.contacts`).

``smoother="rts"`` (``observe --smoother rts``): after the filter pass, a backward
Rauch-Tung-Striebel pass over its rows (:mod:`~elastic_pm_dyn.observer.tuning.smoother`);
``estimates.csv`` and the ``estimates/`` bag then hold the smoothed estimates (each from
every sample of the bag), ``filtered.csv`` the filter's (the same columns), and summary.json
``"smoother": "rts"`` with the numbers of ``"smoothing"``. Without it, ``"smoother": null``
and no ``filtered.csv``.

Message order: by header stamp, ties in bag order (``order="stamp"``, the best offline
estimate), or the bag's own order (``order="arrival"``: what a live node saw, late samples
dropped alike). One estimate row per distinct stamp once the filter runs.

Reading, filtering and writing run at once (``observe_bag(pipeline=True)``, the default; the
compiled filter kernel releases the GIL), with the same results and files as one after the
other; see :mod:`~elastic_pm_dyn.observer.drivers.pipeline` for how the stamp order is kept with a
bag read in chunks. The smoother needs the whole filter pass first: with it, reading,
filtering and writing run one after the other.
"""

from __future__ import annotations

import time
from pathlib import Path

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.kinematics.mechanism import Mechanism, as_mechanism
from elastic_pm_dyn.model.description import Model
from elastic_pm_dyn.observer.config import ObserverConfig, load_config
from elastic_pm_dyn.observer.drivers import event_filter, results
from elastic_pm_dyn.observer.drivers.bag_input import Topics, read_events
from elastic_pm_dyn.observer.drivers.bag_output import write_outputs
from elastic_pm_dyn.observer.drivers.pipeline import observe_pipelined
from elastic_pm_dyn.observer.drivers.results import OfflineResult
from elastic_pm_dyn.observer.tuning.smoother import SMOOTHERS, smooth


def observe_bag(model: Mechanism | Model | str | Path, cfg: ObserverConfig | str | Path | None, bag: str | Path,
                out: str | Path | None = None,
                topics: Topics | None = None, order: str = "stamp", storage: str = "mcap",
                write_estimates_bag: bool = True, log=print, pipeline: bool = True,
                smoother: str | None = None) -> OfflineResult:
    """Run the observer over ``bag``; write CSV, bag and summary into ``out`` (if given).

    ``pipeline``: read, filter and write at once (a reading thread, a writing thread, the filter
    here; the compiled filter kernel releases the GIL), with the same results, files and
    summary keys as one after the other (``pipeline=False``); see
    :mod:`~elastic_pm_dyn.observer.drivers.pipeline` for how, and what the summary's wall times mean
    then.

    ``smoother``: None, or "rts" to smooth the filter's rows (module docstring; the pass then
    runs one stage after the other); the result's ``rows`` are then the smoothed ones and its
    ``filtered`` the filter's.

    ``model`` first, as ``epd.simulate`` and ``epd.analyze`` take it: a model file, a loaded Model or
    a Mechanism; ``cfg``: an :class:`ObserverConfig`, a parameter YAML file, or None for the
    defaults; then the input (``bag``) and the output folder (``out``), as they take theirs."""
    mech = as_mechanism(model)
    if not isinstance(cfg, ObserverConfig):
        cfg = load_config(cfg)
    if smoother is not None and smoother not in SMOOTHERS:
        raise InputError(f"unknown smoother {smoother!r} (expected one of {', '.join(SMOOTHERS)})")
    topics = topics or Topics.from_config(cfg)
    wall0 = time.perf_counter()
    if pipeline and smoother is None and order in ("stamp", "arrival"):
        return observe_pipelined(mech, cfg, Path(bag), out, topics, order, storage, write_estimates_bag, log, wall0)
    events, counts = read_events(Path(bag), topics, cfg)
    if not events:
        raise InputError(f"{bag}: no messages on the observer's topics")
    wall_read = time.perf_counter() - wall0
    run = event_filter.filter_all(mech, cfg, events, order, log)
    summary = results.summary(bag, topics, counts, order, events, run, wall_read)
    summary.smoother = smoother
    rows, filtered = run.rows, None
    if smoother is not None:
        smoothed = smooth(mech, cfg, run.obs, events, order, run.rows)
        rows, filtered = smoothed.rows, run.rows
        summary.smoothing = smoothed.stats
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        wall2 = time.perf_counter()
        write_outputs(out, rows, write_estimates_bag, storage, filtered)
        summary.wall_write_s = time.perf_counter() - wall2
    return results.finish(summary, out, wall0, rows, run.obs, filtered)
