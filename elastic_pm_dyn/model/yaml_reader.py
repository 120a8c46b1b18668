"""Typed access to a model YAML's data, errors at the right line; the sections that
a model YAML and a URDF's closure sidecar share (branches, initial state)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from elastic_pm_dyn.model.description import ACTIVE, ELASTIC, Branch, Chain, InitialState
from elastic_pm_dyn.model.yaml_source import KeyPath, YamlSource


class YamlReader:
    """Typed access to YAML data that reports errors at the right line."""

    def __init__(self, src: YamlSource):
        self.src = src

    def node(self, path: KeyPath) -> Any:
        data = self.src.data
        for part in path:
            data = data[part]
        return data

    def require(self, path: KeyPath, what: str) -> Any:
        """The value at ``path``; an error naming the key if it is missing."""
        if not self.has(path):
            raise self.src.error(path, f"missing required {what}")
        return self.node(path)

    def has(self, path: KeyPath) -> bool:
        try:
            self.node(path)
        except (KeyError, IndexError, TypeError):
            return False
        return True

    def mapping(self, path: KeyPath, allowed: set[str] | None = None) -> dict:
        value = self.require(path, "mapping")
        if not isinstance(value, dict):
            raise self.src.error(path, f"expected a mapping, got {kind_of(value)}")
        if allowed is not None:
            for key in value:
                if key not in allowed:
                    raise self.src.error(path + (key,), f"unknown key (allowed: {name_list(sorted(allowed))})")
        return value

    def sequence(self, path: KeyPath, min_len: int = 0) -> list:
        value = self.require(path, "list")
        if not isinstance(value, list):
            raise self.src.error(path, f"expected a list, got {kind_of(value)}")
        if len(value) < min_len:
            raise self.src.error(path, f"needs at least {min_len} entries, got {len(value)}")
        return value

    def number(self, path: KeyPath, default: float | None = None, positive: bool = False,
               nonnegative: bool = False) -> float:
        if not self.has(path):
            if default is None:
                raise self.src.error(path, "missing required number")
            return default
        value = self.node(path)
        # Strictly typed: a quoted "0.6" or a YAML 1.1 spelling such as 1_000 is a string
        # in YAML 1.2, and true is no number.
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.src.error(path, f"expected a number, got {kind_of(value)}")
        try:
            x = float(value)
        except OverflowError:
            raise self.src.error(path, f"must be finite, got an integer of {len(str(value))} digits") from None
        if not math.isfinite(x):
            raise self.src.error(path, f"must be finite, got {value!r}")
        if positive and x <= 0:
            raise self.src.error(path, f"must be > 0, got {x:g}")
        if nonnegative and x < 0:
            raise self.src.error(path, f"must be >= 0, got {x:g}")
        return x

    def integer(self, path: KeyPath, default: int, low: int, high: int) -> int:
        """A whole number in [low, high]: 1.5, "2" or true are errors, not rounded or cast."""
        if not self.has(path):
            return default
        value = self.node(path)
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.src.error(path, f"expected a whole number from {low} to {high}, got {kind_of(value)}")
        if not low <= value <= high:
            raise self.src.error(path, f"must be a whole number from {low} to {high}, got {value}")
        return value

    def boolean(self, path: KeyPath, default: bool) -> bool:
        """true or false (YAML 1.2: "no", "off", 0 are not booleans)."""
        if not self.has(path):
            return default
        value = self.node(path)
        if not isinstance(value, bool):
            raise self.src.error(path, f"expected true or false, got {kind_of(value)}")
        return value

    def vector(self, path: KeyPath, n: int, default: list[float] | None = None) -> np.ndarray:
        if not self.has(path):
            if default is None:
                raise self.src.error(path, f"missing required {n}-vector")
            return np.array(default, dtype=float)
        seq = self.sequence(path)
        if len(seq) != n:
            raise self.src.error(path, f"expected {n} numbers, got {len(seq)}")
        return np.array([self.number(path + (i,)) for i in range(n)])

    def string(self, path: KeyPath, default: str | None = None, choices: tuple[str, ...] | None = None) -> str:
        if not self.has(path):
            if default is None:
                raise self.src.error(path, "missing required string")
            return default
        value = self.node(path)
        if not isinstance(value, str) or not value:
            raise self.src.error(path, f"expected a non-empty string, got {kind_of(value)}")
        if choices is not None and value not in choices:
            raise self.src.error(path, f"unknown value {shortened(value)} (expected one of: {', '.join(choices)})")
        return value


def kind_of(value: Any) -> str:
    if value is None:
        return "nothing"
    if isinstance(value, str):
        return f"the string {shortened(value)}"
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10**20:
        return f"an integer of {len(str(abs(value)))} digits"
    return {dict: "a mapping", list: "a list"}.get(type(value), repr(value))


def shortened(text: str, limit: int = 40) -> str:
    """``repr`` of a user's string, cut: a message stays one short line."""
    return repr(text if len(text) <= limit else text[:limit] + "...")


def name_list(names: list[str], limit: int = 12) -> str:
    """A comma-separated list of names, cut after ``limit``."""
    shown = ", ".join(shortened(n, 30)[1:-1] for n in names[:limit])
    return shown if len(names) <= limit else f"{shown}, ... ({len(names)} in all)"


def parse_branches(r: YamlReader, chains: list[Chain], joint_names: set[str]) -> tuple[Branch, ...]:
    elastic = [j.name for c in chains for j in c.joints if j.role == ELASTIC]
    if not r.has(("branches",)):
        return tuple(Branch(n, n) for n in elastic)
    elastic_set = set(elastic)
    out = []
    first: dict[str, int] = {}  # branch name -> index: two columns F_<name> would be ambiguous
    for i, _ in enumerate(r.sequence(("branches",))):
        p = ("branches", i)
        r.mapping(p, {"name", "joint"})
        bname = r.string(p + ("name",))
        if bname in first:
            raise r.src.error(p + ("name",), f"branch name {shortened(bname)} is used twice "
                              f"(first at branches[{first[bname]}])")
        first[bname] = i
        joint = r.string(p + ("joint",))
        if joint not in joint_names:
            raise r.src.error(p + ("joint",), f"unknown joint {shortened(joint)}")
        if joint not in elastic_set:
            raise r.src.error(p + ("joint",), f"branch joint {shortened(joint)} is not elastic")
        out.append(Branch(bname, joint))
    return tuple(out)


def parse_initial(r: YamlReader, chains: list[Chain], joint_names: set[str]) -> InitialState:
    path: KeyPath = ("initial_state",)
    if not r.has(path):
        return InitialState()
    r.mapping(path, {"active", "end_effector", "guess", "assembly_mode"})
    active_names = [j.name for c in chains for j in c.joints if j.role == ACTIVE]
    active_set = set(active_names)
    active = None
    if r.has(path + ("active",)):
        active = {}
        for key in r.mapping(path + ("active",)):
            if key not in active_set:
                raise r.src.error(path + ("active", key), f"not an active joint (active: {name_list(active_names)})")
            active[key] = r.number(path + ("active", key))
        missing = [n for n in active_names if n not in active]
        if missing:
            raise r.src.error(path + ("active",), f"missing active joints: {name_list(missing)}")
    ee = None
    if r.has(path + ("end_effector",)):
        n = len(r.sequence(path + ("end_effector",)))
        if n not in (2, 3):
            raise r.src.error(path + ("end_effector",), "expected [x, y] or [x, y, z]")
        ee = r.vector(path + ("end_effector",), n)
    if active is not None and ee is not None:
        raise r.src.error(path, "give either 'active' or 'end_effector', not both")
    guess: dict[str, float] = {}
    if r.has(path + ("guess",)):
        for key in r.mapping(path + ("guess",)):
            if key not in joint_names:
                raise r.src.error(path + ("guess", key), f"unknown joint {shortened(key)}")
            guess[key] = r.number(path + ("guess", key))
    signs: dict[str, int] = {}
    if r.has(path + ("assembly_mode",)):
        for key in r.mapping(path + ("assembly_mode",)):
            if key not in joint_names:
                raise r.src.error(path + ("assembly_mode", key), f"unknown joint {shortened(key)}")
            sign = r.string(path + ("assembly_mode", key), choices=("positive", "negative"))
            signs[key] = 1 if sign == "positive" else -1
    return InitialState(active=active, end_effector=ee, guess=guess, signs=signs)
