"""A simulate study: a grid or a random sample over model parameters, the move and the
integrator settings, one simulate item per point.

The study file (YAML; paths relative to it)::

    model: ../config/five_bar.yaml
    line: [-0.05, 0.35, 0.05, 0.45]   # start and end point (default: the reference manoeuvre's)
    rate: 1000                        # [Hz] torque samples (default: the reference manoeuvre's)
    fixed: {integrator: etd2, sample: 1.0e-3}
    grid:                             # every combination ...
      stiffness_scale: [0.5, 1.0, 2.0]
      move: [0.15, 0.2, 0.3]
    sample:                           # ... or a seeded random sample
      n: 200
      seed: 1
      ranges:
        stiffness_scale: {low: 0.5, high: 2.0, log: true}
        payload: [0.0, 0.5]           # uniform in [low, high]
        integrator: {choices: [rk4, etd2]}

Each point moves the end effector along the line with the rigid feedforward of its own
model (quintic law, sampled at ``rate`` and held), then holds; :mod:`~elastic_pm_dyn.fleet.runners`
simulates it and reports peak branch forces, the closure gap and the residual vibration.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.fleet.items import Item

# parameter -> (type, what it does); see runners.study_model for the model ones
MODEL_PARAMETERS = {
    "stiffness_scale": (float, "every elastic joint's stiffness times this"),
    "damping_scale": (float, "every elastic joint's damping times this"),
    "mass_scale": (float, "every body's mass and inertia times this (the end effector's share included)"),
    "payload": (float, "a point mass [kg] added at the end effector (split over the chain ends it joins)"),
    "elastic_dof_per_chain": (int, "discretisation of flexible links (models with flexible_link only)"),
}
MOTION_PARAMETERS = {"move": (float, "move time [s]"), "hold": (float, "hold time after the move [s]")}
SIMULATION_PARAMETERS = {"method": (str, "formulation"), "integrator": (str, "rk4 | etd2 | dop853"),
                         "dt": (float, "fixed step [s]"), "rtol": (float, "dop853"), "atol": (float, "dop853"),
                         "stabilization": (str, "none | baumgarte | projection | both"),
                         "sample": (float, "output interval [s]")}
PARAMETERS = {**MODEL_PARAMETERS, **MOTION_PARAMETERS, **SIMULATION_PARAMETERS}
STUDY_KEYS = {"model", "line", "rate", "fixed", "grid", "sample", "closures"}
MAX_POINTS = 1_000_000


def _value(name: str, value: object, where: str) -> object:
    if name not in PARAMETERS:
        raise InputError(f"{where}: unknown study parameter {name!r} (known: {', '.join(PARAMETERS)})")
    kind = PARAMETERS[name][0]
    try:
        if kind is int:
            if isinstance(value, float) and not value.is_integer():
                raise ValueError
            return int(value)
        if kind is float:
            out = float(value)
            if not np.isfinite(out) or out < 0:
                raise ValueError
            return out
        return str(value)
    except (TypeError, ValueError):
        what = "finite number >= 0" if kind is float else kind.__name__
        raise InputError(f"{where}: {name} = {value!r} is not a {what}") from None


def _grid_points(grid: Mapping, where: str) -> list[dict]:
    if not isinstance(grid, Mapping) or not grid:
        raise InputError(f"{where}: 'grid' maps each parameter to a list of values")
    axes = []
    for name, values in grid.items():
        values = values if isinstance(values, list) else [values]
        if not values:
            raise InputError(f"{where}: grid {name}: no values")
        axes.append([(name, _value(name, v, f"{where}: grid")) for v in values])
    count = int(np.prod([len(a) for a in axes]))
    if count > MAX_POINTS:
        raise InputError(f"{where}: the grid has {count} points, more than {MAX_POINTS}")
    return [dict(combo) for combo in itertools.product(*axes)]


def _sample_points(spec: Mapping, where: str) -> list[dict]:
    if not isinstance(spec, Mapping) or not isinstance(spec.get("ranges"), Mapping):
        raise InputError(f"{where}: 'sample' needs n, seed and ranges")
    n, seed = spec.get("n"), spec.get("seed", 0)
    if not isinstance(n, int) or not 1 <= n <= MAX_POINTS or not isinstance(seed, int):
        raise InputError(f"{where}: sample n must be 1 to {MAX_POINTS} and seed an integer")
    rng = np.random.default_rng(seed)
    columns: dict[str, list] = {}
    for name, r in spec["ranges"].items():  # drawn column by column in the file's order: reproducible
        here = f"{where}: sample {name}"
        if isinstance(r, Mapping) and "choices" in r:
            choices = [_value(name, c, here) for c in r["choices"]]
            columns[name] = [choices[k] for k in rng.integers(0, len(choices), n)]
            continue
        low, high, log = (r.get("low"), r.get("high"), bool(r.get("log", False))) if isinstance(r, Mapping) else \
            (r[0], r[1], False) if isinstance(r, list) and len(r) == 2 else (None, None, False)
        if low is None or high is None:
            raise InputError(f"{here}: give [low, high], {{low, high, log}} or {{choices: [...]}}")
        lo, hi = float(_value(name, low, here)), float(_value(name, high, here))
        if not lo <= hi or (log and lo <= 0):
            raise InputError(f"{here}: need low <= high (and low > 0 with log)")
        u = rng.random(n)
        values = np.exp(np.log(lo) + u * (np.log(hi) - np.log(lo))) if log else lo + u * (hi - lo)
        columns[name] = [_value(name, round(v) if PARAMETERS[name][0] is int else float(v), here) for v in values]
    return [{name: columns[name][k] for name in columns} for k in range(n)]


def study_items(path: str | Path) -> list[Item]:
    """The study file's points as simulate items ``p00000`` ... (see the module docstring)."""
    from elastic_pm_dyn.model import yaml12
    path = Path(path)
    where = str(path)
    try:
        spec = yaml12.load_file(path)
    except OSError as err:
        raise InputError(f"{path}: cannot read the study: {err.strerror or err}") from None
    except Exception as err:  # YAML syntax: one line naming the file
        raise InputError(f"{path}: not a valid study file: {' '.join(str(err).split())[:200]}") from None
    if not isinstance(spec, Mapping):
        raise InputError(f"{where}: a study file is a mapping (model, grid or sample, ...)")
    unknown = set(spec) - STUDY_KEYS
    if unknown:
        raise InputError(f"{where}: unknown keys {sorted(unknown)} (known: {sorted(STUDY_KEYS)})")
    if ("grid" in spec) == ("sample" in spec):
        raise InputError(f"{where}: give either 'grid' or 'sample'")
    if "model" not in spec:
        raise InputError(f"{where}: no 'model'")
    model = (path.parent / str(spec["model"])).resolve()
    if not model.is_file():
        raise InputError(f"{where}: model {spec['model']}: no such file")
    fixed = {k: _value(k, v, f"{where}: fixed") for k, v in (spec.get("fixed") or {}).items()}
    setting: dict[str, object] = {}
    if "line" in spec:
        line = spec["line"]
        if not isinstance(line, list) or len(line) not in (4, 6):
            raise InputError(f"{where}: line is 4 numbers (planar) or 6 (spatial): start then end")
        setting["line"] = tuple(float(x) for x in line)
    if "rate" in spec:
        setting["rate"] = _value("dt", spec["rate"], f"{where}: rate")
    if "closures" in spec:
        setting["closures"] = str((path.parent / str(spec["closures"])).resolve())
    points = _grid_points(spec["grid"], where) if "grid" in spec else _sample_points(spec["sample"], where)
    width = max(5, len(str(len(points) - 1)))
    return [Item("simulate", f"p{k:0{width}d}", str(model), "", (), (),
                 tuple(sorted({**setting, **fixed, **point}.items())))
            for k, point in enumerate(points)]
