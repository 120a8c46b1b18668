"""Parameter declaration and validation shared by the nodes.

A node lists its parameters as :class:`Param` specs; :func:`read_parameters` declares
them read-only with their descriptions, checks names, types, choices and ranges, and
returns a plain dict, or raises :class:`ParameterError` whose one-line message names the
parameter and says what is expected (the node then refuses to start with that line).
:func:`reject_unknown` refuses overrides that no spec declares (typos in a YAML file).

A spec with ``runtime=True`` may change while the node runs (``ros2 param set``):
:func:`on_runtime_change` checks a new value with the same one-line errors as at start-up and
hands it to the node, or refuses it with that line; arrays may come as lists or as
``array.array`` (the SetParameters service). The others stay read-only, their
descriptor's ``additional_constraints`` saying why (``ros2 param describe``).
"""

from __future__ import annotations

import array
import difflib
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.exceptions import InvalidParameterTypeException
from rclpy.node import Node
from rclpy.parameter import Parameter

from elastic_pm_dyn.errors import InputError

PACKAGE = "elastic_pm_dyn"
COMMAND_JOINTS = "command_joints"
# Declared by rclpy itself for every node; never "unknown".
_BUILTIN_PARAMETERS = ("use_sim_time", "start_type_description_service")

_ARRAY_TYPES = {float: Parameter.Type.DOUBLE_ARRAY, int: Parameter.Type.INTEGER_ARRAY,
                str: Parameter.Type.STRING_ARRAY}
_TYPE_WORDS = {bool: "a boolean (true/false)", int: "an integer", float: "a float (e.g. 1000.0, not 1000)",
               str: "a string"}


class ParameterError(InputError):
    """An invalid node parameter (one line: name, value, what is expected)."""


@dataclass(frozen=True)
class Param:
    name: str
    default: bool | int | float | str | list
    description: str
    choices: tuple[str, ...] = ()
    positive: bool = False  # numbers (or every list entry) > 0; list defaults must not be empty
    maximum: float | None = None  # numbers (or every list entry) <= this (e.g. a wall-clock timer's rate)
    item: type | None = None  # entry type of a list whose default is empty (unset): float, int or str
    runtime: bool = False  # may be set while the node runs (the node applies it: on_runtime_change)
    fixed: str = "fixed at start-up"  # why a read-only one cannot change (shown by ros2 param describe)


def reject_unknown(node: Node, known: Iterable[str]) -> None:
    """Refuse overrides (--params-file, -p) that the node does not declare: they are typos."""
    known = set(known)
    # rclpy has no public getter for the overrides; _parameter_overrides is stable since Foxy.
    unknown = sorted(n for n in node._parameter_overrides
                     if n not in known and n not in _BUILTIN_PARAMETERS and not n.startswith("qos_overrides."))
    if unknown:
        close = [difflib.get_close_matches(n, known, n=1) for n in unknown]
        if all(close):  # typos: name the intended parameter rather than list them all
            raise ParameterError("unknown parameter(s) " + ", ".join(
                f"{n} (did you mean {c[0]}?)" for n, c in zip(unknown, close, strict=True)))
        raise ParameterError(f"unknown parameter(s) {', '.join(unknown)} "
                             f"(known: {', '.join(sorted(known))})")


def read_parameters(node: Node, specs: Iterable[Param]) -> dict[str, Any]:
    """Declare ``specs`` on ``node`` (read-only) and return their checked values by name."""
    return {s.name: _check(s, _declare(node, s)) for s in specs}


def command_joints_param(active_names: Sequence[str]) -> Param:
    """Joint order of Float64MultiArray commands; its default depends on the model."""
    return Param(COMMAND_JOINTS, list(active_names),
                 "joint order of Float64MultiArray commands (default: the model's active joints)")


def on_runtime_change(node: Node, specs: Iterable[Param], apply: Callable[[str, Any], str | None]) -> None:
    """Accept ``ros2 param set`` of the ``runtime`` specs: each new value is checked as at start-up,
    then ``apply(name, value)`` takes it (or returns a one-line reason to refuse it). A request's
    values are all checked before any is applied; a refusal is one line, logged and returned."""
    by_name = {s.name: s for s in specs if s.runtime}

    def callback(parameters: list[Parameter]) -> SetParametersResult:
        try:
            checked = [(p.name, _check(by_name[p.name], _typed(by_name[p.name], p)))
                       for p in parameters if p.name in by_name]
        except ParameterError as err:
            return _refuse(node, str(err))
        for name, value in checked:  # validated together, applied in order
            try:
                reason = apply(name, value)
            except Exception as err:  # never die on a parameter request: refuse it, say why
                reason = f"not applied: {type(err).__name__}: {err}"
            if reason:
                return _refuse(node, f"parameter '{name}': {reason}")
            node.get_logger().info(f"parameter '{name}' set to {value!r}")
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(callback)


def _refuse(node: Node, reason: str) -> SetParametersResult:
    node.get_logger().warning(f"refused: {reason}")
    return SetParametersResult(successful=False, reason=reason)


def _typed(spec: Param, parameter: Parameter) -> Any:
    """The value of a dynamically typed (runtime) parameter if it has the spec's type, else ParameterError.
    An array arrives as a list from a node's own set_parameters, as array.array('d'/'q') through the
    SetParameters service (``ros2 param set``, AsyncParameterClient): both are lists here."""
    value = parameter.value
    if isinstance(value, array.array | tuple):
        value = list(value)
    kind = type(spec.default)
    if kind is list:
        item = spec.item or (type(spec.default[0]) if spec.default else float)
        ok = isinstance(value, list) and all(type(v) is item for v in value)
    else:
        ok = type(value) is kind
    if not ok:
        expected = f"a list of {_TYPE_WORDS[item]}" if kind is list else _TYPE_WORDS[kind]
        raise ParameterError(f"parameter '{spec.name}' must be {expected}, "
                             f"got {parameter.type_.name.lower()} {value!r}")
    return value


def _declare(node: Node, spec: Param) -> Any:
    if spec.runtime:  # typed by our own check (the same line at start-up and at run time)
        descriptor = ParameterDescriptor(description=spec.description, dynamic_typing=True,
                                         additional_constraints=_range_text(spec))
        value = node.declare_parameter(spec.name, spec.default, descriptor)
        return _typed(spec, value)
    descriptor = ParameterDescriptor(description=spec.description, read_only=True,
                                     additional_constraints="; ".join(filter(None, (f"read-only: {spec.fixed}",
                                                                                    _range_text(spec)))))
    # An empty default has no type of its own: declared by the type of its entries, unset until given.
    default = _ARRAY_TYPES[spec.item] if spec.item is not None and spec.default == [] else spec.default
    try:
        value = node.declare_parameter(spec.name, default, descriptor).value
    except InvalidParameterTypeException:
        given = node._parameter_overrides[spec.name]
        if spec.item is not None and isinstance(given.value, list | tuple) and not len(given.value):
            return []  # '-p x:=[]': unset, as if not given
        item = spec.item if spec.item is not None else (type(spec.default[0]) if isinstance(spec.default, list)
                                                        else None)
        expected = (f"a list of {_TYPE_WORDS[item]}" if isinstance(spec.default, list)
                    else _TYPE_WORDS[type(spec.default)])
        raise ParameterError(f"parameter '{spec.name}' must be {expected}, "
                             f"got {given.type_.name.lower()} {given.value!r}") from None
    if isinstance(spec.default, list):
        return list(value) if value is not None else []  # '-p x:=[]' overrides with an untyped empty list
    return value


def _check(spec: Param, value: Any) -> Any:
    if spec.choices and value not in spec.choices:
        raise ParameterError(f"parameter '{spec.name}' is {value!r}, expected one of: {', '.join(spec.choices)}")
    if spec.positive or spec.maximum is not None:
        values = np.atleast_1d(np.asarray(value, dtype=float))
        ok = np.isfinite(values) & (values > 0 if spec.positive else True)
        if spec.maximum is not None:
            ok &= values <= spec.maximum
        if not np.all(ok):
            raise ParameterError(f"parameter '{spec.name}' must be {_range_text(spec)}, got {value!r}")
    return value


def _range_text(spec: Param) -> str:
    """What ``positive`` and ``maximum`` allow, in words ("" when they allow anything)."""
    if spec.maximum is None:
        return "a positive number" if spec.positive else ""
    return f"a {'positive ' if spec.positive else ''}number at most {spec.maximum:g}"


def share_path(*parts: str) -> Path:
    """A file shipped with the package: the installed share/ (colcon) or the source tree (pip -e)."""
    try:
        candidate = Path(get_package_share_directory(PACKAGE), *parts)
        if candidate.exists():
            return candidate
    except (PackageNotFoundError, OSError):  # OSError: no AMENT_PREFIX_PATH (pip-only venv)
        pass
    return Path(__file__).resolve().parents[2].joinpath(*parts)


def observer_config_for(model: str | Path) -> Path:
    """The observer parameter file for the machine of ``model``: ``observer_<model file stem>.yaml``
    beside the model file when there is one (the shipped machines' own, tuned for them: its header
    says how), else the package's generic ``config/observer_node.yaml``. ``model`` empty: the packaged
    five-bar (as the ``model`` parameter)."""
    path = Path(model).expanduser() if str(model) else share_path("config", "five_bar.yaml")
    own = path.with_name(f"observer_{path.stem}.yaml")
    return own if own.is_file() else share_path("config", "observer_node.yaml")


def model_path(value: str) -> Path:
    """The ``model`` parameter: a file path, or empty for the packaged five-bar."""
    path = Path(value).expanduser() if value else share_path("config", "five_bar.yaml")
    if not path.is_file():
        raise ParameterError(f"parameter 'model': no such file {str(path)!r}")
    return path
