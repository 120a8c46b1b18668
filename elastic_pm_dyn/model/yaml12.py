"""The YAML dialects of the package, on PyYAML.

Parameter files (observer, ``observe --set``; :func:`load`): PyYAML's safe loader with
YAML 1.2 numbers. PyYAML implements YAML 1.1, where a float needs a dot: ``5e-5``, ``1e3``
and ``-2E+4`` are strings there, floats in YAML 1.2 (and in every other YAML library a
user writes files with). :class:`Yaml12Loader` resolves them as floats; everything else is
SafeLoader's (``.inf``, ``.nan``, ints, booleans such as ``yes``/``off``, null; quoted
scalars stay strings), as ROS reads the same parameter files.

Model files (:func:`events`, :func:`core_scalar`): strictly the YAML 1.2 core schema.
``no``, ``on``, ``1_000``, ``017`` and dates are strings there, booleans are only
true/false, and the only tags are the core ones, so a mistyped value is reported instead
of silently read as something else.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any, ClassVar

import yaml

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.text_file import TextFileError, read_text

_FLOAT_TAG = "tag:yaml.org,2002:float"

# YAML 1.2 core-schema floats (an exponent without a dot, an optional exponent sign) plus
# what YAML 1.1 resolves already (sexagesimal, .inf, .nan, underscores).
_FLOAT = re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
                    |[-+]?(?:[0-9][0-9_]*)[eE][-+]?[0-9]+
                    |[-+]?\.[0-9][0-9_]*(?:[eE][-+]?[0-9]+)?
                    |[-+]?[0-9][0-9_]*(?::[0-5]?[0-9])+\.[0-9_]*
                    |[-+]?\.(?:inf|Inf|INF)
                    |\.(?:nan|NaN|NAN))$""", re.X)


class Yaml12Loader(yaml.SafeLoader):
    """SafeLoader whose float resolver is YAML 1.2's (see the module docstring)."""

    # SafeLoader's table with YAML 1.2's float pattern in place of 1.1's (same first
    # characters, same precedence); SafeLoader's own table stays as it is.
    yaml_implicit_resolvers: ClassVar[dict] = {
        first: [(tag, _FLOAT if tag == _FLOAT_TAG else rx) for tag, rx in resolvers]
        for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()}


def load(text: str) -> Any:
    """The data of one YAML document (None if empty); ``yaml.YAMLError`` if malformed."""
    return yaml.load(text, Loader=Yaml12Loader)  # a SafeLoader subclass: no arbitrary objects


MAX_PARAMETER_BYTES = 4 * 2**20  # a parameter file has a few kB; refused before reading


def load_file(path: str | Path, what: str = "parameter file") -> Any:
    """:func:`load` of a file, every problem one ``InputError`` line naming the file (and the line
    where known): unreadable, larger than MAX_PARAMETER_BYTES, not UTF-8, malformed, or holding a
    recursive alias (``&a [*a]``), which would make every later walk over the data recurse forever."""
    p = Path(path)
    try:
        text = read_text(p, MAX_PARAMETER_BYTES, what)
    except TextFileError as exc:
        raise InputError(f"{p}{'' if exc.line is None else f':{exc.line}'}: {exc.reason}") from None
    try:
        data = load(text)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f":{mark.line + 1}" if mark is not None else ""
        raise InputError(f"{p}{where}: not valid YAML: {exc.problem or exc.context}") from None
    except (yaml.YAMLError, RecursionError, ValueError) as exc:
        raise InputError(f"{p}: not valid YAML: {' '.join(str(exc).split())[:200]}") from None
    _refuse_cycles(data, p)
    return data


def _refuse_cycles(data: Any, path: Path) -> None:
    """InputError if a list or map contains itself (a recursive alias); iterative, so any depth is fine."""
    stack: list[tuple[Any, frozenset]] = [(data, frozenset())]
    while stack:
        node, above = stack.pop()
        if not isinstance(node, (list, dict)):
            continue
        if id(node) in above:
            raise InputError(f"{path}: a recursive alias (a list or map that contains itself)")
        inner = above | {id(node)}
        stack.extend((child, inner) for child in (node.values() if isinstance(node, dict) else node))


# ---------------------------------------------------------------- model files: YAML 1.2 core schema
TAG = "tag:yaml.org,2002:"
NULL, BOOL, INT, FLOAT, STR = (TAG + k for k in ("null", "bool", "int", "float", "str"))
MAP, SEQ = TAG + "map", TAG + "seq"

_CORE_NULL = re.compile(r"^(?:~|null|Null|NULL|)$")
_CORE_BOOL = {"true": True, "True": True, "TRUE": True, "false": False, "False": False, "FALSE": False}
_CORE_INT = re.compile(r"^(?:[-+]?[0-9]+|0o[0-7]+|0x[0-9a-fA-F]+)$")
_CORE_FLOAT = re.compile(r"^(?:[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?"
                         r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$")
MAX_INT_DIGITS = 100  # no model number needs more; Python refuses > 4300 anyway


def core_scalar(value: str, tag: str | None, plain: bool) -> Any:
    """The value of a scalar under the YAML 1.2 core schema.

    ``tag``: the explicit (expanded) tag or None; ``plain``: unquoted and untagged, so
    resolved by its form. Raises ValueError with a short reason for a value that does not
    fit its explicit tag, or a tag outside the core schema.
    """
    if tag is None or tag == "!":
        if not plain or tag == "!":
            return value
        tag = _resolve(value)
    if tag == STR:
        return value
    if tag == NULL and _CORE_NULL.match(value):
        return None
    if tag == BOOL and value in _CORE_BOOL:
        return _CORE_BOOL[value]
    if tag == INT and _CORE_INT.match(value):
        if len(value) > MAX_INT_DIGITS:
            raise ValueError(f"integer with more than {MAX_INT_DIGITS} digits")
        if value.startswith(("0o", "0x")):
            return int(value[2:], 8 if value[1] == "o" else 16)
        return int(value)
    if tag == FLOAT and (_CORE_FLOAT.match(value) or _CORE_INT.match(value)):
        low = value.lower()
        if low.endswith(".inf"):
            return -math.inf if low.startswith("-") else math.inf
        if low == ".nan":
            return math.nan
        return float(int(value, 0) if value.startswith(("0o", "0x")) else value)
    if tag in (NULL, BOOL, INT, FLOAT):
        return _misfit(value, tag)
    raise ValueError(f"unsupported tag {_short(tag)} (model files use plain YAML values: "
                     "numbers, true/false, strings, lists, mappings)")


def _resolve(value: str) -> str:
    if _CORE_NULL.match(value):
        return NULL
    if value in _CORE_BOOL:
        return BOOL
    if _CORE_INT.match(value):
        return INT
    if _CORE_FLOAT.match(value):
        return FLOAT
    return STR


def _misfit(value: str, tag: str) -> Any:
    raise ValueError(f"{_short(value)} is not a valid !!{tag.removeprefix(TAG)}")


def _short(text: str, limit: int = 40) -> str:
    return repr(text if len(text) <= limit else text[:limit] + "...")


def events(text: str) -> Iterator[yaml.Event]:
    """The parser events of ``text`` (with line marks), from libyaml where PyYAML has it.

    Both parsers are iterative state machines: arbitrarily deep nesting costs no stack.
    Raises ``yaml.YAMLError`` for malformed YAML.
    """
    try:
        from yaml._yaml import CParser  # ~5x faster than the pure-Python parser
        parser: Any = CParser(text)
    except ImportError:  # PyYAML built without libyaml
        parser = yaml.SafeLoader(text)
    try:
        while True:
            event = parser.get_event()
            if event is None:
                return
            yield event
            if isinstance(event, yaml.StreamEndEvent):
                return
    finally:
        parser.dispose()
