"""Warm a batch worker before its first item: the imports and the compiled kernels of the job.

A fresh process pays the package's imports and numba's cache loading (seconds on a loaded
machine) the first time each kernel runs; done once per worker here, every item's time is
its own work. The warm-up runs the batch's first item's own code on a tiny input (a few
milliseconds of the same simulation; the item's observer over the first events of its bag),
so it loads the kernels that item's kind needs. It changes nothing the
items compute, and whatever fails here is ignored: the item fails again with its reason.
"""

from __future__ import annotations

import contextlib
import io
import tempfile
import warnings
from dataclasses import replace
from pathlib import Path

from elastic_pm_dyn.fleet.items import Item


def warm_up(item: Item) -> None:
    """Load what running ``item`` needs (never raises; prints nothing)."""
    quiet = io.StringIO()
    with contextlib.redirect_stdout(quiet), contextlib.redirect_stderr(quiet), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            if item.kind == "simulate":
                _simulate(item)
            elif item.kind in ("observe", "tune"):
                _observer(item)
            else:
                from elastic_pm_dyn.fleet.runners import _command
                _command(["analyze", item.source or ".", "--model", item.model, *item.argv_options()])
                _mechanism(item.model)
        except Exception:  # a warm-up is an extra: the item itself reports the fault
            pass


def _mechanism(model: str, closures: str | None = None):
    from elastic_pm_dyn.kinematics.mechanism import Mechanism
    from elastic_pm_dyn.model.loader import load_model
    return Mechanism(load_model(model, closures=closures))


def _simulate(item: Item) -> None:
    """The item's simulation, cut to a few milliseconds, into a scratch folder."""
    from elastic_pm_dyn.fleet.runners import _figures, simulation_parser
    if item.study:
        p = dict(item.study)
        dt = float(p.get("dt", 1e-4))
        short = {**p, "move": max(20 * dt, 5e-3), "hold": 2e-3}
        tiny = replace(item, study=tuple(sorted(short.items())))
    else:
        a = simulation_parser().parse_args(item.argv_options())
        tiny = replace(item, options=(*item.options, ("duration", repr(max(20 * a.dt, 2 * a.sample)))))
    with tempfile.TemporaryDirectory(prefix="epd-warm-") as scratch:
        _figures(tiny, Path(scratch), io.StringIO())


def _observer(item: Item) -> None:
    """The offline filter of the item's configuration over the first events of its own bag
    (read lazily: a day-long bag costs no more), and its CSV written to a scratch folder."""
    from elastic_pm_dyn.fleet.runners import _command
    from elastic_pm_dyn.observer.cli import _config
    from elastic_pm_dyn.observer.drivers import event_filter
    from elastic_pm_dyn.observer.drivers.bag_input import Topics, iter_events
    from elastic_pm_dyn.observer.drivers.bag_output import write_outputs
    args = _command([item.kind, "--model", item.model, "--bag", item.source, "--out", "-", *item.argv_options()])
    cfg = _config(args)
    mech = _mechanism(item.model, args.closures)
    events = next(iter(iter_events(Path(item.source), Topics.from_config(cfg), cfg, {}, EVENTS)), [])
    run = event_filter.filter_all(mech, cfg, events, getattr(args, "order", "stamp"), lambda s: None)
    with tempfile.TemporaryDirectory(prefix="epd-warm-") as scratch:
        write_outputs(Path(scratch), run.obs, run.rows, False, "mcap", None)


EVENTS = 300  # the first events of the bag a warm-up filters: every kernel of a pass runs on them
