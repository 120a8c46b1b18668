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


MAX_NESTING = 64  # levels of lists/maps, aliases expanded; a parameter file uses about 5
MAX_NODES = 100_000  # values with every alias expanded (an alias bomb of 1 kB is billions)


class YamlLimitError(yaml.YAMLError):
    """A document beyond :data:`MAX_NESTING` or :data:`MAX_NODES`, a recursive alias or a key twice."""


def load(text: str) -> Any:
    """The data of one YAML document (None if empty); ``yaml.YAMLError`` if malformed, and
    :class:`YamlLimitError` (one of them) beyond the limits, checked before any value is built:
    nesting on the parser's events (PyYAML's composer recurses), then the composed graph with
    aliases expanded, then a key given twice in one mapping."""
    _check_nesting(text)
    loader = Yaml12Loader(text)  # a SafeLoader subclass: no arbitrary objects
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        _check_expanded(node)
        _check_duplicate_keys(node)
        return loader.construct_document(node)
    finally:
        loader.dispose()


def _check_nesting(text: str) -> None:
    depth = 0
    for event in events(text):
        if isinstance(event, yaml.CollectionStartEvent):
            depth += 1
            if depth > MAX_NESTING:
                raise YamlLimitError(f"line {event.start_mark.line + 1}: nested more than {MAX_NESTING} levels deep")
        elif isinstance(event, yaml.CollectionEndEvent):
            depth -= 1


def _children(node: yaml.Node) -> list[yaml.Node]:
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    if isinstance(node, yaml.MappingNode):
        return [n for pair in node.value for n in pair]
    return []


def _check_expanded(root: yaml.Node) -> None:
    """Size and depth of the graph with every alias expanded, each node visited once (memo);
    an alias to a node still open is a recursive alias."""
    size: dict[int, int] = {}
    depth: dict[int, int] = {}
    open_ids: set[int] = set()
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    while stack:
        node, done = stack.pop()
        key = id(node)
        if done:
            kids = _children(node)
            size[key] = 1 + sum(size[id(k)] for k in kids)
            depth[key] = 1 + max((depth[id(k)] for k in kids), default=0)
            open_ids.discard(key)
            if size[key] > MAX_NODES:
                raise YamlLimitError(f"line {node.start_mark.line + 1}: more than {MAX_NODES} values once its "
                                     "aliases are expanded")
            if depth[key] > MAX_NESTING + 1:
                raise YamlLimitError(f"line {node.start_mark.line + 1}: nested more than {MAX_NESTING} levels "
                                     "deep once its aliases are expanded")
            continue
        if key in size:
            continue
        if key in open_ids:
            raise YamlLimitError(f"line {node.start_mark.line + 1}: a recursive alias (a list or map that "
                                 "contains itself)")
        open_ids.add(key)
        stack.append((node, True))
        stack.extend((k, False) for k in _children(node) if id(k) not in size)


def _check_duplicate_keys(root: yaml.Node) -> None:
    seen: set[int] = set()
    stack = [root]
    while stack:
        node = stack.pop()
        if id(node) in seen:
            continue
        seen.add(id(node))
        if isinstance(node, yaml.MappingNode):
            keys: set[str] = set()
            for k, _ in node.value:
                if isinstance(k, yaml.ScalarNode):
                    if k.value in keys:
                        raise YamlLimitError(f"line {k.start_mark.line + 1}: key {_short(k.value)} given twice "
                                             "in one mapping")
                    keys.add(k.value)
        stack.extend(_children(node))


MAX_PARAMETER_BYTES = 4 * 2**20  # a parameter file has a few kB; refused before reading


def load_file(path: str | Path, what: str = "parameter file") -> Any:
    """:func:`load` of a file, every problem one ``InputError`` line naming the file (and the line
    where known): unreadable, larger than MAX_PARAMETER_BYTES, not UTF-8, malformed, or holding a
    recursive alias (``&a [*a]``), which would make every later walk over the data recurse forever."""
    return load_file_text(path, what)[0]


def load_file_text(path: str | Path, what: str = "parameter file") -> tuple[Any, str]:
    """:func:`load_file`, and the file's text (e.g. to see whether it ends with its last line)."""
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
    except YamlLimitError as exc:
        line, _, reason = str(exc).partition(": ")
        raise InputError(f"{p}:{line.removeprefix('line ')}: {reason}") from None
    except (yaml.YAMLError, RecursionError, ValueError) as exc:
        raise InputError(f"{p}: not valid YAML: {' '.join(str(exc).split())[:200]}") from None
    _refuse_cycles(data, p)
    return data, text


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
        from yaml._yaml import CParser  # libyaml: several times faster than the pure-Python parser
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
