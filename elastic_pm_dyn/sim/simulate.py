"""``epd.simulate``: one call from a robot and its motor torques to a simulated run.

The same job as ``elastic-pm-dyn simulate`` (which calls this), taking its inputs in the forms
``epd.observe`` and ``epd.analyze`` take theirs: the model as a file, a loaded Model or a
Mechanism; the torques as a torque source, a CSV file, or one constant value per motor.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import fields
from pathlib import Path
from typing import Any

import numpy as np

from elastic_pm_dyn.errors import InputError, RunInterrupted, SingularConfigurationError
from elastic_pm_dyn.kinematics.mechanism import Mechanism, as_mechanism
from elastic_pm_dyn.model.description import Model
from elastic_pm_dyn.sim.result import SimulationResult
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import ConstantTorque, FunctionTorque, TorqueSource, clamped, load_torque_csv

Torques = TorqueSource | str | Path | Sequence[float] | np.ndarray | Callable[[float], np.ndarray]
_OPTION_NAMES = frozenset(f.name for f in fields(SimulationOptions))


def simulate(model: Mechanism | Model | str | Path, torques: Torques, duration: float,
             out: str | Path | None = None, *, options: SimulationOptions | None = None, hold: str = "zoh",
             q0: np.ndarray | None = None, qd0: np.ndarray | None = None, _prefix: str = "",
             **option_values: Any) -> SimulationResult:
    """Simulate ``model`` for ``duration`` seconds under ``torques``; write the result CSV to ``out``.

    ``model``: a model file (YAML, URDF, MJCF), a loaded Model or a Mechanism. ``torques``: a
    :class:`~elastic_pm_dyn.sim.torque.TorqueSource` (e.g. a TorqueTable), a CSV file with header
    ``t,<motor names>`` (read with ``hold``, as the command line reads ``--torques``), one constant
    torque per motor, or a function of time returning one per motor. Options: a
    :class:`SimulationOptions`, or its fields as keywords (``integrator="dop853", sample=1e-4``),
    not both. ``out`` given: the file ``elastic-pm-dyn simulate --out`` writes, and, when the run
    stops early (singular configuration, Ctrl-C), the samples so far before the error is raised.
    """
    if option_values:
        unknown = sorted(set(option_values) - _OPTION_NAMES)
        if unknown:
            raise InputError(f"unknown simulation option {unknown[0]!r} (expected one of: "
                             f"{', '.join(sorted(_OPTION_NAMES))})")
        if options is not None:
            raise InputError("give options= or option keywords (" + ", ".join(option_values) + "), not both")
        options = SimulationOptions(**option_values)
    mech = as_mechanism(model)
    sim = Simulator(mech, options)
    sim.check_run_size(duration, prefix=_prefix)  # before a torque file is read or anything allocated
    source = as_torque_source(torques, mech, hold)
    try:
        result = sim.run(source, duration, q0, qd0)
    except (RunInterrupted, SingularConfigurationError) as stop:  # both carry the samples so far
        if out is not None and stop.partial is not None:
            stop.partial.to_csv(out)
        raise
    if out is not None:
        result.to_csv(out)
    return result


def as_torque_source(torques: Torques, mech: Mechanism, hold: str = "zoh") -> TorqueSource:
    """``torques`` as a torque source for ``mech``'s motors, its width checked (one per motor)."""
    names = list(mech.active_names)
    if isinstance(torques, str | Path):
        return clamped(load_torque_csv(torques, names, hold), mech)  # its columns are checked against the names
    if isinstance(torques, TorqueSource):
        source = torques
    elif callable(torques):
        source = FunctionTorque(torques)
    else:
        try:
            values = np.asarray(torques, dtype=float)
        except (TypeError, ValueError):
            raise InputError(f"torques: expected a torque source, a CSV file or {len(names)} numbers, "
                             f"got {type(torques).__name__}") from None
        if values.ndim != 1:
            raise InputError(f"torques: a constant torque is {len(names)} numbers (one per motor), "
                             f"got an array of shape {values.shape}")
        source = ConstantTorque(values)
    width = _width(source)  # (a table's or a constant's: before its inputs are clamped)
    if width is not None and width != len(names):
        raise InputError(f"torques: {width} values per sample, but {mech.model.name} has {len(names)} motors "
                         f"({', '.join(names)})")
    return clamped(source, mech)  # a servo's ctrl within its ctrlrange, as MuJoCo clamps it


def _width(source: TorqueSource) -> int | None:
    """Torques per sample of a source whose width is known without calling it (tables, constants)."""
    values = getattr(source, "values", None)
    if isinstance(values, np.ndarray) and values.ndim in (1, 2):
        return values.shape[-1]
    return None
