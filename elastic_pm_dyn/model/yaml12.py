"""The one YAML loader of the package: PyYAML's safe loader with YAML 1.2 numbers.

PyYAML implements YAML 1.1, where a float needs a dot: ``5e-5``, ``1e3`` and ``-2E+4`` are
strings there, floats in YAML 1.2 (and in every other YAML library a user writes files
with). :class:`Yaml12Loader` resolves them as floats; everything else is SafeLoader's
(``.inf``, ``.nan``, ints, booleans, null; quoted scalars stay strings). Every YAML the
package reads goes through it: model files (with line numbers, via :func:`compose`),
observer parameter files and ``observe --set`` values (:func:`load`).
"""

from __future__ import annotations

import re
from typing import Any, ClassVar

import yaml

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


def compose(text: str) -> yaml.Node | None:
    """The node graph of one YAML document (with line marks), scalars tagged as :func:`load` does."""
    return yaml.compose(text, Loader=Yaml12Loader)


def construct_scalar(node: yaml.ScalarNode) -> Any:
    """The value of a scalar node from :func:`compose` (int/float/bool/str/null)."""
    return _SCALARS.construct_object(node, deep=True)


_SCALARS = Yaml12Loader("")
