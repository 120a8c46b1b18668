"""elastic_pm_dyn: dynamics of elastic parallel manipulators.

The numerical core (model, kinematics, dynamics, sim) never imports rclpy; the ROS
nodes in :mod:`elastic_pm_dyn.ros` are thin layers over it.

Equation numbers in docstrings refer to the seed paper, "Derivation and Calculation of
the Dynamics of Elastic Parallel Manipulators" (Stachera & Schumacher).

The names a user needs are here, ``import elastic_pm_dyn as epd``::

    mech = epd.Mechanism(epd.load_model("config/five_bar.yaml"))
    line = epd.REFERENCE_MANOEUVRE.line
    times, torques, motors = epd.line_torques(mech.model, line, rate=1000.0)
    run = epd.Simulator(mech).run(epd.TorqueTable(times, torques), line.duration)

They are loaded on first use (PEP 562): every ``import elastic_pm_dyn.<module>`` runs this
file first, and importing :mod:`elastic_pm_dyn.errors` must not cost numba, scipy and the
simulator.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from elastic_pm_dyn._numba_cache import configure as _configure_numba_cache

__version__ = "0.1.0"

_configure_numba_cache()

# Public name -> (module, name there). Grouped as a user meets them: model, machine, state,
# dynamics, simulation, torques, motions, observer, analysis, errors.
_EXPORTS: dict[str, tuple[str, str]] = {
    "load_model": ("elastic_pm_dyn.model.loader", "load_model"),
    "Mechanism": ("elastic_pm_dyn.kinematics.mechanism", "Mechanism"),
    "initial_state": ("elastic_pm_dyn.kinematics.assembly", "initial_state"),
    "random_consistent_state": ("elastic_pm_dyn.kinematics.assembly", "random_consistent_state"),
    "Dynamics": ("elastic_pm_dyn.dynamics.direct", "Dynamics"),
    "FORMULATIONS": ("elastic_pm_dyn.dynamics.direct", "FORMULATIONS"),
    "elastic_modes": ("elastic_pm_dyn.dynamics.linear", "elastic_modes"),
    "Simulator": ("elastic_pm_dyn.sim.simulator", "Simulator"),
    "SimulationOptions": ("elastic_pm_dyn.sim.simulator", "SimulationOptions"),
    "simulate": ("elastic_pm_dyn.sim.simulate", "simulate"),
    "ConstantTorque": ("elastic_pm_dyn.sim.torque", "ConstantTorque"),
    "FunctionTorque": ("elastic_pm_dyn.sim.torque", "FunctionTorque"),
    "TorqueTable": ("elastic_pm_dyn.sim.torque", "TorqueTable"),
    "load_torque_csv": ("elastic_pm_dyn.sim.torque", "load_torque_csv"),
    "QuinticLine": ("elastic_pm_dyn.motion.trajectory", "QuinticLine"),
    "line_torques": ("elastic_pm_dyn.motion.feedforward", "line_torques"),
    "rigid_feedforward": ("elastic_pm_dyn.motion.feedforward", "rigid_feedforward"),
    "feedforward_table": ("elastic_pm_dyn.sim.held_feedforward", "feedforward_table"),
    "LineReference": ("elastic_pm_dyn.motion.references", "LineReference"),
    "REFERENCE_MANOEUVRE": ("elastic_pm_dyn.motion.manoeuvre", "REFERENCE_MANOEUVRE"),
    "observe": ("elastic_pm_dyn.observer.offline", "observe_bag"),
    "load_observer_config": ("elastic_pm_dyn.observer.config", "load_config"),
    "ObserveSummary": ("elastic_pm_dyn.observer.drivers.results", "ObserveSummary"),
    "analyze": ("elastic_pm_dyn.analysis.report", "analyze"),
    "AnalysisReport": ("elastic_pm_dyn.analysis.report_types", "AnalysisReport"),
    "batch": ("elastic_pm_dyn.fleet.api", "batch"),
    "calibrate": ("elastic_pm_dyn.calibration.api", "calibrate"),
    "Calibration": ("elastic_pm_dyn.calibration.api", "Calibration"),
    "excitation": ("elastic_pm_dyn.calibration.excitation", "excitation"),
    "ElasticPmDynError": ("elastic_pm_dyn.errors", "ElasticPmDynError"),
    "ModelError": ("elastic_pm_dyn.errors", "ModelError"),
    "InputError": ("elastic_pm_dyn.errors", "InputError"),
    "AssemblyError": ("elastic_pm_dyn.errors", "AssemblyError"),
    "SingularConfigurationError": ("elastic_pm_dyn.errors", "SingularConfigurationError"),
}

__all__ = [  # written out, not derived from _EXPORTS: static tools read it literally (a test keeps them equal)
    "FORMULATIONS",
    "REFERENCE_MANOEUVRE",
    "AnalysisReport",
    "AssemblyError",
    "Calibration",
    "ConstantTorque",
    "Dynamics",
    "ElasticPmDynError",
    "FunctionTorque",
    "InputError",
    "LineReference",
    "Mechanism",
    "ModelError",
    "ObserveSummary",
    "QuinticLine",
    "SimulationOptions",
    "Simulator",
    "SingularConfigurationError",
    "TorqueTable",
    "analyze",
    "batch",
    "calibrate",
    "elastic_modes",
    "excitation",
    "feedforward_table",
    "initial_state",
    "line_torques",
    "load_model",
    "load_observer_config",
    "load_torque_csv",
    "observe",
    "random_consistent_state",
    "rigid_feedforward",
    "simulate",
]

if TYPE_CHECKING:  # what type checkers and IDEs see; at run time __getattr__ below loads them
    from elastic_pm_dyn.analysis.report import analyze
    from elastic_pm_dyn.analysis.report_types import AnalysisReport
    from elastic_pm_dyn.calibration.api import Calibration, calibrate
    from elastic_pm_dyn.calibration.excitation import excitation
    from elastic_pm_dyn.dynamics.direct import FORMULATIONS, Dynamics
    from elastic_pm_dyn.dynamics.linear import elastic_modes
    from elastic_pm_dyn.errors import (
        AssemblyError,
        ElasticPmDynError,
        InputError,
        ModelError,
        SingularConfigurationError,
    )
    from elastic_pm_dyn.fleet.api import batch
    from elastic_pm_dyn.kinematics.assembly import initial_state, random_consistent_state
    from elastic_pm_dyn.kinematics.mechanism import Mechanism
    from elastic_pm_dyn.model.loader import load_model
    from elastic_pm_dyn.motion.feedforward import line_torques, rigid_feedforward
    from elastic_pm_dyn.motion.manoeuvre import REFERENCE_MANOEUVRE
    from elastic_pm_dyn.motion.references import LineReference
    from elastic_pm_dyn.motion.trajectory import QuinticLine
    from elastic_pm_dyn.observer.config import load_config as load_observer_config
    from elastic_pm_dyn.observer.drivers.results import ObserveSummary
    from elastic_pm_dyn.observer.offline import observe_bag as observe
    from elastic_pm_dyn.sim.held_feedforward import feedforward_table
    from elastic_pm_dyn.sim.simulate import simulate
    from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
    from elastic_pm_dyn.sim.torque import ConstantTorque, FunctionTorque, TorqueTable, load_torque_csv


def __getattr__(name: str) -> Any:
    try:
        module, attribute = _EXPORTS[name]
    except KeyError:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None
    value = getattr(importlib.import_module(module), attribute)
    globals()[name] = value  # later look-ups are plain module attributes
    return value


def __dir__() -> list[str]:
    """The public names and the dunders (``__version__``, ``__doc__``...): what a user completes
    ``epd.`` to. Not what this file imports for itself (``Any``, ``importlib``...) nor the
    submodules loaded so far (``errors``, ``small_linalg``, ``pinned_kernels``...), which
    Python binds here as a side effect of importing them and which would make the list depend
    on what ran before; they stay reachable as ``elastic_pm_dyn.<module>``."""
    return sorted({name for name in globals() if name.startswith("__")} | set(__all__))
