"""Motor torque sources for simulation.

Every source answers two questions for the integrator: where the torque is not smooth
(``breakpoints``: a step never straddles one) and what polynomial in time it follows over
a step (``coefficients``).
"""

from __future__ import annotations

import csv
import io
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.output_files import atomic_file
from elastic_pm_dyn.text_file import TextFileError, read_text

MAX_TORQUE_FILE_BYTES = 2**30  # 1 GiB: ~2.5e7 rows of two motors; refused before reading

HOLDS = ("zoh", "linear")


class TorqueSource:
    """Base: motor torques for the active joints, in the mechanism's active order."""

    smooth = False  # True: arbitrary function, needs a fit per step

    def breakpoints(self) -> np.ndarray:
        return np.zeros(0)

    def value(self, t: float) -> np.ndarray:
        raise NotImplementedError

    def coefficients(self, t: float, h: float) -> np.ndarray:
        """(3, n_a): tau(t + s) = c0 + c1 s + c2 s^2 for s in [0, h], h within one piece."""
        raise NotImplementedError

    def coefficients_many(self, t: np.ndarray, h: np.ndarray) -> np.ndarray:
        """(len(t), 3, n_a): :meth:`coefficients` of each (t[k], h[k]); tables answer in one
        vectorised pass with the same values."""
        return np.array([self.coefficients(tk, hk) for tk, hk in zip(t, h, strict=True)])

    def values_at(self, t: np.ndarray) -> np.ndarray:
        """(len(t), n_a): :meth:`value` at each t[k]."""
        return np.array([self.value(tk) for tk in t])


class ConstantTorque(TorqueSource):
    def __init__(self, values: np.ndarray):
        self.values = _finite(np.atleast_1d(np.asarray(values, dtype=float)), "constant torque")

    def value(self, t: float) -> np.ndarray:
        return self.values.copy()

    def coefficients(self, t: float, h: float) -> np.ndarray:
        return np.vstack([self.values, np.zeros_like(self.values), np.zeros_like(self.values)])

    def coefficients_many(self, t: np.ndarray, h: np.ndarray) -> np.ndarray:
        out = np.zeros((len(t), 3, len(self.values)))
        out[:, 0] = self.values
        return out

    def values_at(self, t: np.ndarray) -> np.ndarray:
        return np.tile(self.values, (len(t), 1))


class FunctionTorque(TorqueSource):
    """tau = f(t) for a Python callable (e.g. continuous feedforward)."""

    smooth = True

    def __init__(self, function: Callable[[float], np.ndarray]):
        self.function = function

    def value(self, t: float) -> np.ndarray:
        return _finite(np.asarray(self.function(t), dtype=float), f"torque function at t = {t:g} s")

    def coefficients(self, t: float, h: float) -> np.ndarray:
        # The quadratic through RK4's three stage times reproduces f exactly there.
        f0, f1, f2 = self.value(t), self.value(t + 0.5 * h), self.value(t + h)
        return np.vstack([f0, (4 * f1 - 3 * f0 - f2) / h, 2 * (f0 - 2 * f1 + f2) / h**2])


class HeldPlusSmooth(TorqueSource):
    """A command held over one control period plus a smooth function of time (an unknown
    disturbance torque), refitted per step as :class:`FunctionTorque` is: the plant's and the
    offline recordings' way to integrate a disturbance without holding it per period."""

    smooth = True

    def __init__(self, held: np.ndarray, func: Callable[[float], np.ndarray] | None):
        self.held = held
        self.func = func

    def value(self, t: float) -> np.ndarray:
        return self.held + (self.func(t) if self.func is not None else 0.0)

    def coefficients(self, t: float, h: float) -> np.ndarray:
        f0, f1, f2 = self.value(t), self.value(t + 0.5 * h), self.value(t + h)
        return np.vstack([f0, (4 * f1 - 3 * f0 - f2) / h, 2 * (f0 - 2 * f1 + f2) / h ** 2])


class ClampedInputs(TorqueSource):
    """Another source's inputs clamped to [low, high] per motor (an MJCF servo's ctrlrange, as
    MuJoCo clamps ctrl). Exact for held (ZOH) and constant inputs, which stay constant per step;
    a ramp or a function that crosses a bound inside a step is fitted through its clamped values."""

    def __init__(self, source: TorqueSource, low: np.ndarray, high: np.ndarray):
        self.source, self.low, self.high = source, np.asarray(low, dtype=float), np.asarray(high, dtype=float)
        self.smooth = source.smooth or (isinstance(source, TorqueTable) and source.hold == "linear")

    def breakpoints(self) -> np.ndarray:
        return self.source.breakpoints()

    def value(self, t: float) -> np.ndarray:
        return np.clip(self.source.value(t), self.low, self.high)

    def coefficients(self, t: float, h: float) -> np.ndarray:
        if not self.smooth:
            c = self.source.coefficients(t, h)  # constant over the step: its clamped value
            return np.vstack([np.clip(c[0], self.low, self.high), np.zeros_like(c[0]), np.zeros_like(c[0])])
        f0, f1, f2 = self.value(t), self.value(t + 0.5 * h), self.value(t + h)
        return np.vstack([f0, (4 * f1 - 3 * f0 - f2) / h, 2 * (f0 - 2 * f1 + f2) / h ** 2])

    def coefficients_many(self, t: np.ndarray, h: np.ndarray) -> np.ndarray:
        if self.smooth:
            return super().coefficients_many(t, h)
        out = self.source.coefficients_many(t, h).copy()
        out[:, 0] = np.clip(out[:, 0], self.low, self.high)
        out[:, 1:] = 0.0
        return out


def input_bounds(mech) -> tuple[np.ndarray, np.ndarray] | None:
    """(low, high) per motor (active order) from the model's input ranges; None if it has none."""
    ranges = {name: (low, high) for name, low, high in mech.model.input_ranges}
    if not ranges:
        return None
    low = np.array([ranges.get(n, (-np.inf, np.inf))[0] for n in mech.active_names])
    high = np.array([ranges.get(n, (-np.inf, np.inf))[1] for n in mech.active_names])
    return low, high


def clamped(source: TorqueSource, mech) -> TorqueSource:
    """``source`` with ``mech``'s input ranges applied (itself where it has none)."""
    bounds = input_bounds(mech)
    return source if bounds is None else ClampedInputs(source, *bounds)


class TorqueTable(TorqueSource):
    """Sampled torques. ``zoh``: sample k acts on [t_k, t_k+1), as a digital controller
    applies it; ``linear``: interpolated. After the last sample the last value holds."""

    def __init__(self, times: np.ndarray, values: np.ndarray, hold: str = "zoh"):
        if hold not in HOLDS:
            raise InputError(f"unknown hold {hold!r} (expected zoh or linear)")
        self.times = np.asarray(times, dtype=float)
        self.values = np.atleast_2d(np.asarray(values, dtype=float))
        if self.times.ndim != 1 or len(self.times) == 0 or len(self.times) != len(self.values):
            raise InputError("a torque table needs one row of values per time")
        if np.any(np.diff(self.times) <= 0):
            k = int(np.argmax(np.diff(self.times) <= 0)) + 1
            raise InputError(f"torque table times must increase strictly (row {k + 1}: t = {self.times[k]:g})")
        _finite(self.values, "torque table")
        self.hold = hold

    def breakpoints(self) -> np.ndarray:
        return self.times

    def value(self, t: float) -> np.ndarray:
        if t < self.times[0] - 1e-12:
            raise InputError(f"no torque before the table's first sample ({self.times[0]:g} s) at t = {t:g} s")
        if self.hold == "zoh":
            k = int(np.searchsorted(self.times, t + 1e-12, side="right")) - 1
            return self.values[max(k, 0)].copy()
        return np.array([np.interp(t, self.times, col) for col in self.values.T])

    def coefficients(self, t: float, h: float) -> np.ndarray:
        if self.hold == "zoh":
            # The midpoint is unambiguous: a step never crosses a sample time.
            v = self.value(t + 0.5 * h)
            return np.vstack([v, np.zeros_like(v), np.zeros_like(v)])
        v0, v1 = self.value(t), self.value(t + h)
        return np.vstack([v0, (v1 - v0) / h, np.zeros_like(v0)])

    def values_at(self, t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        if len(t) and t.min() < self.times[0] - 1e-12:
            self.value(float(t.min()))  # its error
        if self.hold == "zoh":
            k = np.searchsorted(self.times, t + 1e-12, side="right") - 1
            return self.values[np.maximum(k, 0)]
        return np.column_stack([np.interp(t, self.times, col) for col in self.values.T]).reshape(len(t), -1)

    def coefficients_many(self, t: np.ndarray, h: np.ndarray) -> np.ndarray:
        t, h = np.asarray(t, dtype=float), np.asarray(h, dtype=float)
        out = np.zeros((len(t), 3, self.values.shape[1]))
        if self.hold == "zoh":
            out[:, 0] = self.values_at(t + 0.5 * h)  # the midpoint: a step never crosses a sample time
            return out
        v0, v1 = self.values_at(t), self.values_at(t + h)
        out[:, 0] = v0
        out[:, 1] = (v1 - v0) / h[:, None]
        return out


def _finite(values: np.ndarray, what: str) -> np.ndarray:
    if not np.all(np.isfinite(values)):
        raise InputError(f"{what}: NaN or Inf torque")
    return values


def load_torque_csv(path: str | Path, active_names: list[str], hold: str = "zoh") -> TorqueTable:
    """Read ``t,<active joint names>`` (any column order); every active joint is required.

    Errors name the file and its line (blank and ``#`` comment lines count): a column
    named twice, times that do not increase, a cell that is no number, bytes that are no
    UTF-8 text.
    """
    p = Path(path)
    try:
        text = read_text(p, MAX_TORQUE_FILE_BYTES, "torque file")
    except TextFileError as exc:
        where = "" if exc.line is None else f" line {exc.line}:"
        hint = "; a torque file is a CSV table" if exc.line is not None else ""
        raise InputError(f"{p}:{where} {exc.reason}{hint}") from None
    return _read_table(p, csv.reader(io.StringIO(text, newline="")), active_names, hold)


def _read_table(p: Path, reader: Iterator[list[str]], active_names: list[str], hold: str) -> TorqueTable:
    header: list[str] | None = None
    order: list[int] = []
    times: list[float] = []
    values: list[list[float]] = []
    line = 0
    try:
        for row in reader:
            line = reader.line_num  # type: ignore[attr-defined]
            if not row or row[0].lstrip().startswith("#"):
                continue
            if header is None:
                header = [h.strip() for h in row]
                order = _columns(p, line, header, active_names)
                continue
            if len(row) != len(header):
                raise InputError(f"{p}: line {line}: expected {len(header)} values, got {len(row)}")
            nums = []
            for i, cell in enumerate(row):
                try:
                    nums.append(float(cell))
                except ValueError:
                    raise InputError(f"{p}: line {line}: column {_short(header[i])}: not a number: {_short(cell)}") \
                        from None
            bad = [header[i] for i, x in enumerate(nums) if not np.isfinite(x)]
            if bad:
                raise InputError(f"{p}: line {line}: NaN or Inf in column(s) {', '.join(bad)}")
            if times and not nums[0] > times[-1]:
                raise InputError(f"{p}: line {line}: t = {nums[0]:g} does not come after the previous "
                                 f"sample's {times[-1]:g} (torque table times must increase strictly)")
            times.append(nums[0])
            values.append([nums[i] for i in order])
    except csv.Error as exc:
        raise InputError(f"{p}: line {line + 1}: not a CSV table ({_short(str(exc))})") from None
    if header is None:
        raise InputError(f"{p}: empty torque file")
    if not times:
        raise InputError(f"{p}: no torque samples after the header")
    return TorqueTable(np.array(times), np.array(values), hold)


def _columns(p: Path, line: int, header: list[str], active_names: list[str]) -> list[int]:
    """Column of each active joint in ``header``; errors for a wrong, unknown, repeated or missing column."""
    if header[0] != "t":
        raise InputError(f"{p}: line {line}: the first column must be 't', got {_short(header[0])}")
    first: dict[str, int] = {}
    for i, name in enumerate(header):
        if name in first:  # which of the two would drive the motor is a guess: refuse
            raise InputError(f"{p}: line {line}: column {_short(name)} appears twice "
                             f"(columns {first[name] + 1} and {i + 1})")
        first[name] = i
    unknown = [h for h in header[1:] if h not in active_names]
    if unknown:
        raise InputError(f"{p}: line {line}: unknown joint(s) {', '.join(_short(h)[1:-1] for h in unknown[:8])} "
                         f"(active joints: {', '.join(active_names)})")
    missing = [n for n in active_names if n not in first]
    if missing:
        raise InputError(f"{p}: line {line}: missing column(s) for active joint(s) {', '.join(missing)}")
    return [first[n] for n in active_names]


def _short(text: str, limit: int = 60) -> str:
    """``repr`` of a user's text, cut: a message stays one short line."""
    return repr(text if len(text) <= limit else text[:limit] + "...")


def write_torque_csv(path: str | Path, times: np.ndarray, values: np.ndarray, names: list[str]) -> None:
    """Write a table that :func:`load_torque_csv` reads back exactly (17 digits); complete or not at all."""
    data = np.column_stack([times, values])
    with atomic_file(path) as tmp:
        # numpy encodes a file's header as Latin-1 unless told: names are UTF-8 as the reader reads them
        np.savetxt(tmp, data, delimiter=",", header=",".join(["t", *names]), comments="", fmt="%.17g",
                   encoding="utf-8")
