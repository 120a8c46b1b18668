"""The items' options checked in the batch process before any worker starts: a misspelled
``-o`` option or manifest column is one line naming it and the nearest valid name, not a
failed row for every item after the pool has started.

Each distinct set of options is parsed once by the single-item command's own parser (the
one the worker will use), so what passes here is what the item runs with.
"""

from __future__ import annotations

import argparse
import difflib
from collections.abc import Sequence

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.fleet.items import Item
from elastic_pm_dyn.fleet.runners import command_parser, simulation_parser

PER_ITEM = {"model", "bag", "out", "torques"}  # set by the batch per item, not options


def _parser(kind: str) -> argparse.ArgumentParser:
    if kind == "simulate":
        return simulation_parser()
    sub = next(a for a in command_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices[kind]


def option_names(kind: str) -> list[str]:
    """The options an item of ``kind`` takes, named as in ``-o`` and manifests (``max_evaluations``)."""
    names = {s[2:].replace("-", "_") for s in _parser(kind)._option_string_actions if s.startswith("--")}
    return sorted(names - PER_ITEM - {"help"})


def check_options(items: Sequence[Item]) -> None:
    """Raise InputError (one line) for the first unknown option or unusable value of ``items``."""
    seen: set[tuple[str, tuple]] = set()
    for it in items:
        if (it.kind, it.options) in seen or not it.options:
            continue
        seen.add((it.kind, it.options))
        known = option_names(it.kind)
        for name, _ in it.options:
            if name not in known:
                near = difflib.get_close_matches(name, known, 1)
                hint = f"did you mean {near[0]!r}?" if near else f"its options: {', '.join(known)}"
                raise InputError(f"{it.kind} has no option {name!r} (an -o option or a manifest column; item "
                                 f"{it.id}): {hint}")
        try:
            _parse(it)
        except InputError as err:
            raise InputError(f"item {it.id}: {err}") from None


def _parse(it: Item) -> None:
    if it.kind == "simulate":
        simulation_parser().parse_args(it.argv_options())
    elif it.kind == "analyze":
        command_parser().parse_args(["analyze", it.source or "-", "--model", it.model, *it.argv_options()])
    else:
        command_parser().parse_args([it.kind, "--model", it.model, "--bag", it.source or "-", "--out", "-",
                                     *it.argv_options()])
