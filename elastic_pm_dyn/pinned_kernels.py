"""Compiled kernels called from Python at the cost of converting the arguments, without numba's type dispatch.

For every call from Python, numba looks up the compiled version of a kernel by the types of
its arguments, so it runs ``typeof`` over every array of every bundle passed. With the
observer's ten bundles a call takes 5.6-7.1 us before any work through the dispatcher and
2.4-4.4 us through the entry point (``bench/studies/observer_period_costs.py``, quiet), and a
live period makes five such calls.
:class:`PinnedKernel` makes its first call through numba's dispatcher and keeps the compiled
version that call used; later calls go straight to that version's entry point, which only
converts the arguments.

The entry point converts each argument to the types of its version without checking them, so
a pinned kernel must get arguments of the same types on every call. The observer satisfies
this: it builds its bundles once with fixed dtypes, and its per-call arguments are floats,
booleans and float64 vectors. With ``ELASTIC_PM_DYN_CHECK_PINNED=1`` (the test suite sets it),
the types of the first :data:`CHECK_FIRST` calls and of every :data:`CHECK_EVERY`-th call after
them are compared with the pinned ones, and a difference raises ``TypeError``. Not every call:
the comparison runs numba's ``typeof`` on every array of every bundle, which made a DOP853 run
at tight tolerances (hundreds of thousands of calls) ten times slower in the suite.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

CHECK_ENV = "ELASTIC_PM_DYN_CHECK_PINNED"
CHECK_FIRST = 100  # calls checked from the start (with the check on)
CHECK_EVERY = 64  # then one call in this many


class PinnedKernel:
    """``kernel`` (a numba dispatcher) pinned to the argument types of its first call."""

    __slots__ = ("calls", "check", "entry", "kernel", "types")

    def __init__(self, kernel: Any):
        self.kernel = kernel
        self.entry: Callable[..., Any] | None = None
        self.types: tuple | None = None
        self.check = os.environ.get(CHECK_ENV) == "1"
        self.calls = 0

    def __call__(self, *args: Any) -> Any:
        entry = self.entry
        if entry is None:
            return self._first(args)
        if self.check and self.types is not None and self._sampled():
            types = tuple(self.kernel.typeof_pyval(a) for a in args)
            if types != self.types:
                raise TypeError(f"{self.kernel.__name__}: pinned to {self.types}, called with {types}")
        return entry(*args)

    def _sampled(self) -> bool:
        self.calls += 1
        return self.calls <= CHECK_FIRST or self.calls % CHECK_EVERY == 0

    def _first(self, args: tuple) -> Any:
        result = self.kernel(*args)  # compiles or loads the version for these types
        types = tuple(self.kernel.typeof_pyval(a) for a in args)
        overload = self.kernel.overloads.get(types)
        if overload is None:  # a type numba converts on dispatch: the dispatcher stays in use
            self.entry = self.kernel
        else:
            self.types, self.entry = types, overload.entry_point
        return result


class KernelPins:
    """One :class:`PinnedKernel` per kernel, for one owner whose argument types never change."""

    __slots__ = ("_pins",)

    def __init__(self) -> None:
        self._pins: dict[Any, PinnedKernel] = {}

    def __call__(self, kernel: Any) -> PinnedKernel:
        pin = self._pins.get(kernel)
        if pin is None:
            pin = self._pins[kernel] = PinnedKernel(kernel)
        return pin
