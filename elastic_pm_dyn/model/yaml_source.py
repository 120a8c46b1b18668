"""YAML documents that remember where every key came from.

Model files are hand-written; an error must point at the line, not just say "invalid".
We build the data from the parser's events ourselves and keep a map from key path to line
number. Scalars follow the YAML 1.2 core schema (:mod:`~elastic_pm_dyn.model.yaml12`:
``stiffness: 1e5`` is a float, ``planar: no`` a string).

Whatever the file holds, reading it ends in data or in one :class:`ModelError` line, in
time linear in its size: the size is checked before reading, the builder is iterative (no
recursion however deep the nesting), and an alias shares the anchored value instead of
copying it (no exponential "billion laughs" expansion; a recursive alias is an error).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from elastic_pm_dyn.errors import ModelError
from elastic_pm_dyn.model import yaml12
from elastic_pm_dyn.text_file import TextFileError, read_text

KeyPath = tuple[str | int, ...]

MAX_MODEL_BYTES = 4 * 2**20  # hexa.yaml, the largest shipped model, has 10 kB
MAX_DEPTH = 64  # levels of nested lists/mappings; a model uses about 8


def format_path(path: KeyPath) -> str:
    """``("chains", 0, "joints", 2, "mass")`` -> ``chains[0].joints[2].mass``."""
    out = ""
    for part in path:
        if isinstance(part, int):
            out += f"[{part}]"
        elif part.isidentifier() and len(part) <= 40:
            out += ("." if out else "") + part
        else:  # a key no model has: quoted and cut, so the message stays one short line
            out += f"[{yaml12._short(part)}]"
    return out


class YamlSource:
    """Parsed YAML data plus the 1-based line of every key path."""

    def __init__(self, text: str, file: str):
        self.file = file
        self.lines: dict[KeyPath, int] = {}
        if len(text) > MAX_MODEL_BYTES:
            raise ModelError(file, "", f"{len(text)} characters, more than the {_size(MAX_MODEL_BYTES)} "
                             "a model file may have")
        try:
            self.data: Any = _Builder(self).build(text)
        except yaml.MarkedYAMLError as exc:
            mark = exc.problem_mark or exc.context_mark
            line = mark.line + 1 if mark is not None else None
            problem = exc.problem or exc.context or "malformed"
            raise ModelError(file, "", f"malformed YAML: {problem}", line) from None
        except yaml.reader.ReaderError as exc:
            line = text.count("\n", 0, exc.position) + 1 if isinstance(exc.position, int) else None
            raise ModelError(file, "", f"malformed YAML: {exc.reason} (character #x{exc.character:04x})"
                             if isinstance(exc.character, int) else f"malformed YAML: {exc.reason}", line) from None
        except yaml.YAMLError as exc:
            raise ModelError(file, "", f"malformed YAML: {' '.join(str(exc).split())[:200]}") from None

    @classmethod
    def from_file(cls, path: str | Path) -> YamlSource:
        try:
            text = read_text(path, MAX_MODEL_BYTES, "model file")
        except TextFileError as exc:
            raise ModelError(str(path), "", exc.reason, exc.line) from None
        return cls(text, str(path))

    def line(self, path: KeyPath) -> int | None:
        """Line of ``path``, or of its nearest ancestor that exists."""
        while path:
            if path in self.lines:
                return self.lines[path]
            path = path[:-1]
        return self.lines.get(())

    def error(self, path: KeyPath, message: str) -> ModelError:
        return ModelError(self.file, format_path(path), message, self.line(path))


def _size(n: int) -> str:
    return f"{n / 2**20:.3g} MiB" if n >= 2**20 else f"{n / 1024:.3g} kiB"


class _Open:
    """A list or mapping being filled; ``key`` is the mapping key waiting for its value."""

    __slots__ = ("anchor", "key", "key_line", "path", "value")

    def __init__(self, value: list | dict, path: KeyPath, anchor: str | None):
        self.value, self.path, self.anchor = value, path, anchor
        self.key: str | None = None
        self.key_line = 0


class _Builder:
    """Parser events -> plain data (dict/list/scalars), lines recorded per key path."""

    def __init__(self, src: YamlSource):
        self.src = src
        self.anchors: dict[str, Any] = {}
        self.open_anchors: set[str] = set()

    def fail(self, path: KeyPath, line: int, message: str) -> ModelError:
        return ModelError(self.src.file, format_path(path), message, line)

    def build(self, text: str) -> Any:
        stack: list[_Open] = []
        root: Any = {}
        documents = 0
        for event in yaml12.events(text):
            if isinstance(event, yaml.DocumentStartEvent):
                documents += 1
                if documents > 1:
                    raise self.fail((), event.start_mark.line + 1, "a model file holds one YAML document, "
                                    "this is a second one")
                continue
            if not isinstance(event, yaml.NodeEvent | yaml.CollectionEndEvent):
                continue
            line = event.start_mark.line + 1
            top = stack[-1] if stack else None
            if isinstance(event, yaml.CollectionEndEvent):
                done = stack.pop()
                if done.anchor is not None:
                    self.open_anchors.discard(done.anchor)
                continue
            if top is not None and isinstance(top.value, dict) and top.key is None:
                top.key = self._key(event, top.path, line)
                top.key_line = line
                if top.key in top.value:
                    raise self.fail(top.path + (top.key,), line, "duplicate key")
                continue
            path = self._child_path(top)
            value = self._value(event, path, line, stack)
            if top is None:
                root = value
            elif isinstance(top.value, dict):
                top.value[top.key] = value
                top.key = None
            else:
                top.value.append(value)
        return root

    def _child_path(self, top: _Open | None) -> KeyPath:
        if top is None:
            return ()
        if isinstance(top.value, dict):
            return top.path + (top.key,)
        return top.path + (len(top.value),)

    def _key(self, event: yaml.Event, path: KeyPath, line: int) -> str:
        if not isinstance(event, yaml.ScalarEvent):
            raise self.fail(path, line, "a key must be a plain name, not a list, mapping or alias")
        return event.value

    def _value(self, event: yaml.Event, path: KeyPath, line: int, stack: list[_Open]) -> Any:
        self.src.lines[path] = line
        if isinstance(event, yaml.AliasEvent):
            name = event.anchor
            if name in self.open_anchors:
                raise self.fail(path, line, f"recursive alias *{name} (it refers to the value that contains it)")
            if name not in self.anchors:
                raise self.fail(path, line, f"undefined alias *{name}")
            return self.anchors[name]  # shared, not copied: lines below it fall back to this one
        anchor = event.anchor
        if isinstance(event, yaml.ScalarEvent):
            try:
                value = yaml12.core_scalar(event.value, event.tag, event.implicit[0])
            except ValueError as exc:
                raise self.fail(path, line, str(exc)) from None
        else:
            is_map = isinstance(event, yaml.MappingStartEvent)
            if event.tag not in (None, "!", yaml12.MAP if is_map else yaml12.SEQ):
                raise self.fail(path, line, f"unsupported tag {yaml12._short(event.tag)} (model files use "
                                "plain YAML lists and mappings)")
            if len(stack) >= MAX_DEPTH:
                raise self.fail(path, line, f"nested more than {MAX_DEPTH} levels deep")
            value = {} if is_map else []
            stack.append(_Open(value, path, anchor))
            if anchor is not None:
                self.open_anchors.add(anchor)
        if anchor is not None:
            self.anchors[anchor] = value
        return value
