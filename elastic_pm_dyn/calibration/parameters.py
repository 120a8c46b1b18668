"""The physical parameters a model YAML holds that calibration may fit, read and written by key path.

A parameter is one number of the model file (``stiffness.left_spring`` is
``chains[0].joints[1].stiffness``), so a fitted set is written back as the same file with those
numbers changed: every command loads it as it loads the original, flexible links, platforms and
comments' meaning included (the comments themselves are not kept). Names:

- ``stiffness.<joint or link>``: an elastic joint's spring (c; K of eq 33) as ``stiffness``, or a
  flexible link's ``axial_stiffness`` (EA) or ``bending_stiffness`` (EI);
- ``damping.<joint or link>``: its damper (d; D of eq 33), ``damping``;
- ``payload.mass``: the end effector's point mass (``end_effector.mass``) or the platform body's mass;
- ``payload.inertia``: the platform body's inertia tensor, one factor on all its entries;
- ``friction.<joint>``: the viscous ``friction`` of a joint whose file gives one.
- ``torque_scale.<motor>``: a motor's ``torque_scale`` (torque per unit command, 1 where the file
  gives none; the model's transmission column of that motor, :meth:`Model.transmission`); fitted
  only when ``--params`` asks for it.

Values are fitted as log ratios to the file's (every parameter positive, steps relative).
"""

from __future__ import annotations

import copy
import fnmatch
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.model.description import ACTIVE, ELASTIC, Model
from elastic_pm_dyn.model.formats import model_format
from elastic_pm_dyn.model.loader import parse_model
from elastic_pm_dyn.model.yaml_source import YamlSource

KeyPath = tuple[Any, ...]
# fitted when --params is not given; friction only where the file has some, inertia and torque_scale only when asked
DEFAULT_GROUPS = ("stiffness", "damping", "payload.mass", "friction")
INERTIA_KEYS = ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")


@dataclass(frozen=True)
class Parameter:
    """One fitted number: its name, where it sits in the file and the file's value (> 0)."""

    name: str
    paths: tuple[KeyPath, ...]  # every key it sets (payload.inertia: the tensor's entries)
    nominal: float

    @property
    def group(self) -> str:
        return self.name.split(".")[0]


@dataclass
class ModelFile:
    """A model YAML as data: what calibration changes and writes back."""

    path: str
    data: dict

    @classmethod
    def read(cls, path: str | Path) -> ModelFile:
        if model_format(path) != "yaml":
            raise InputError(f"{path}: calibrate reads and writes model YAML files; this is a "
                             f"{model_format(path)} file (describe the machine as a model YAML)")
        src = YamlSource.from_file(path)
        parse_model(src)  # the file's own errors, with its lines, before any work
        return cls(str(path), src.data)

    def with_values(self, params: Sequence[Parameter], values: Iterable[float]) -> dict:
        """A copy of the data with each parameter's keys set to its value (inertia: scaled)."""
        data = copy.deepcopy(self.data)
        for p, v in zip(params, values, strict=True):
            for path in p.paths:
                if p.name == "payload.inertia":
                    _set(data, path, _get(self.data, path) * float(v) / p.nominal)
                else:
                    _set(data, path, float(v))
        return data

    def model(self, params: Sequence[Parameter], values: Iterable[float]) -> Model:
        return model_of(self.with_values(params, values), self.path)


def model_of(data: dict, name: str = "<calibrated>") -> Model:
    """The Model of YAML ``data``, through the same parser as a file (so it is what a file gives)."""
    return parse_model(YamlSource(dump(data), name))


def dump(data: dict, header: str = "") -> str:
    """YAML text every reader of model files takes (floats as floats, key order kept)."""
    return header + yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=110)


def available(mf: ModelFile) -> list[Parameter]:
    """Every parameter the file offers (module docstring), in file order."""
    data = mf.data
    out: list[Parameter] = []
    for ci, chain in enumerate(data.get("chains") or []):
        for ji, entry in enumerate(chain.get("joints") or []):
            base: KeyPath = ("chains", ci, "joints", ji)
            if "flexible_link" in entry:
                link = entry["flexible_link"]
                key = "axial_stiffness" if "axial_stiffness" in link else "bending_stiffness"
                out += _positive(f"stiffness.{link['name']}", (*base, "flexible_link", key), link.get(key))
                out += _positive(f"damping.{link['name']}", (*base, "flexible_link", "damping"), link.get("damping"))
                continue
            if entry.get("role") == ELASTIC:
                out += _positive(f"stiffness.{entry['name']}", (*base, "stiffness"), entry.get("stiffness"))
                out += _positive(f"damping.{entry['name']}", (*base, "damping"), entry.get("damping"))
            out += _positive(f"friction.{entry['name']}", (*base, "friction"), entry.get("friction"))
            if entry.get("role") == ACTIVE:  # a motor's gain: 1 where the file gives none
                out += _positive(f"torque_scale.{entry['name']}", (*base, "torque_scale"),
                                 entry.get("torque_scale", 1.0))
    out += _payload(data)
    return out


def _positive(name: str, path: KeyPath, value: Any) -> list[Parameter]:
    """A parameter only where the file gives a positive value (a log ratio needs one)."""
    return [Parameter(name, (path,), float(value))] if isinstance(value, int | float) and value > 0 else []


def _payload(data: dict) -> list[Parameter]:
    closure = data.get("closure") or {}
    if closure.get("type") == "platform":
        names = [c.get("name") for c in data["chains"]]
        ci = names.index(closure["platform"])
        joints = data["chains"][ci]["joints"]
        ji = max(k for k, j in enumerate(joints) if isinstance(j.get("body"), dict))
        body: KeyPath = ("chains", ci, "joints", ji, "body")
        out = _positive("payload.mass", (*body, "mass"), joints[ji]["body"].get("mass"))
        inertia = joints[ji]["body"].get("inertia") or {}
        keys = tuple((*body, "inertia", k) for k in INERTIA_KEYS if inertia.get(k))
        if keys:
            out.append(Parameter("payload.inertia", keys, 1.0))
        return out
    return _positive("payload.mass", ("end_effector", "mass"), (data.get("end_effector") or {}).get("mass"))


def select(params: list[Parameter], asked: Sequence[str] | None) -> list[Parameter]:
    """The parameters ``asked`` names: a name, a group (``stiffness``) or a pattern
    (``stiffness.left_*``); None: :data:`DEFAULT_GROUPS`. An unknown name is one line."""
    if asked is None:
        asked = DEFAULT_GROUPS
        chosen = [p for p in params if p.group in asked or p.name in asked]
    else:
        chosen = []
        for a in asked:
            hit = [p for p in params if p.name == a or p.group == a or fnmatch.fnmatchcase(p.name, a)]
            if not hit:
                raise InputError(f"--params {a!r}: the model file has no such parameter; it has: "
                                 + ", ".join(p.name for p in params))
            chosen += [p for p in hit if p not in chosen]
        chosen = [p for p in params if p in chosen]  # file order
    if not chosen:
        raise InputError("nothing to calibrate: the model file has no elastic joint, payload or friction to fit")
    return chosen


def _get(data: Any, path: KeyPath) -> Any:
    for k in path:
        data = data[k]
    return data


def _set(data: Any, path: KeyPath, value: float) -> None:
    _get(data, path[:-1])[path[-1]] = value
