"""YAML documents that remember where every key came from.

Model files are hand-written; an error must point at the line, not just say "invalid".
PyYAML's node graph carries marks, so we convert it ourselves and keep a map from key
path to line number. Scalars resolve as YAML 1.2 (:mod:`~elastic_pm_dyn.model.yaml12`:
``stiffness: 1e5`` is a float).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from elastic_pm_dyn.errors import ModelError
from elastic_pm_dyn.model import yaml12

KeyPath = tuple[str | int, ...]


def format_path(path: KeyPath) -> str:
    """``("chains", 0, "joints", 2, "mass")`` -> ``chains[0].joints[2].mass``."""
    out = ""
    for part in path:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + part
    return out


class YamlSource:
    """Parsed YAML data plus the 1-based line of every key path."""

    def __init__(self, text: str, file: str):
        self.file = file
        self.lines: dict[KeyPath, int] = {}
        try:
            node = yaml12.compose(text)
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            line = mark.line + 1 if mark is not None else None
            problem = getattr(exc, "problem", None) or str(exc)
            raise ModelError(file, "", f"malformed YAML: {problem}", line) from None
        self.data: Any = {} if node is None else self._convert(node, ())

    @classmethod
    def from_file(cls, path: str | Path) -> YamlSource:
        p = Path(path)
        try:
            text = p.read_text()
        except OSError as exc:
            raise ModelError(str(p), "", f"cannot read file: {exc.strerror}") from None
        return cls(text, str(p))

    def _convert(self, node: yaml.Node, path: KeyPath) -> Any:
        self.lines[path] = node.start_mark.line + 1
        if isinstance(node, yaml.MappingNode):
            out: dict[str, Any] = {}
            for key_node, value_node in node.value:
                key = str(key_node.value)
                if key in out:
                    raise ModelError(self.file, format_path(path + (key,)), "duplicate key",
                                     key_node.start_mark.line + 1)
                out[key] = self._convert(value_node, path + (key,))
            return out
        if isinstance(node, yaml.SequenceNode):
            return [self._convert(v, path + (i,)) for i, v in enumerate(node.value)]
        # Scalars: the YAML 1.2 resolver picks int/float/bool/str/null.
        return yaml12.construct_scalar(node)

    def line(self, path: KeyPath) -> int | None:
        """Line of ``path``, or of its nearest ancestor that exists."""
        while path:
            if path in self.lines:
                return self.lines[path]
            path = path[:-1]
        return self.lines.get(())

    def error(self, path: KeyPath, message: str) -> ModelError:
        return ModelError(self.file, format_path(path), message, self.line(path))
